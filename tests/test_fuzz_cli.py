"""tools/fuzz_cli.py: a small sample of its attempts (the full run is `python -m tools.fuzz_cli`), and
its oracles themselves (a FIFO replaced, a traceback, a hang are each seen)."""

from __future__ import annotations

import os
import stat
import sys

import pytest

from tools import fuzz_cli


def test_every_subcommand_has_flags_of_each_kind_read_from_its_parser():
    kinds = {name: {f.kind for f in fuzz_cli.flags_of(cmd)} for name, cmd in fuzz_cli.COMMANDS.items()}
    assert set(kinds) == {"benchmark", "train sampler", "train rl", "critical generate-data", "critical train",
                          "critical evaluate"}
    assert all("number" in k and "path" in k for k in kinds.values()), kinds
    options = {f.option for f in fuzz_cli.flags_of(fuzz_cli.COMMANDS["benchmark"])}
    assert {"--json", "--plot", "--problems", "--workers", "--checkpoint", "--task"} <= options
    chosen = fuzz_cli.choose(fuzz_cli.all_attempts(list(fuzz_cli.COMMANDS)), 200, 0)
    assert len(chosen) == 200 and len(set(chosen)) == 200


def test_a_sample_of_bad_values_is_one_line_each(tmp_path):
    """Output paths that are a FIFO, a device node or a symlink, huge and NaN counts, an unknown task:
    no traceback, no hang, no node replaced."""
    attempts = [fuzz_cli.Attempt("benchmark", "--json", "fifo", "{fifo}"),
                fuzz_cli.Attempt("benchmark", "--plot", "char device", "{chardev}"),
                fuzz_cli.Attempt("benchmark", "--json", "symlink", "{symlink}"),
                fuzz_cli.Attempt("benchmark", "--problems", "huge", fuzz_cli.HUGE),
                fuzz_cli.Attempt("train rl", "--hyperparams", "fifo", "{fifo}"),
                fuzz_cli.Attempt("train rl", "--candidates", "nan", "nan"),
                fuzz_cli.Attempt("train sampler", "--workers", "huge", fuzz_cli.HUGE),
                fuzz_cli.Attempt("benchmark", "--task", "unknown", "no-such-value"),
                # what the full run found (each fixed): a figure through a symlink to a .txt, a port past
                # the C long, a learning rate that makes the policy NaN
                fuzz_cli.Attempt("benchmark", "--plot", "symlink", "{symlink}"),
                fuzz_cli.Attempt("train sampler", "--ray", "huge", fuzz_cli.HUGE),
                fuzz_cli.Attempt("train rl", "--lr", "huge", fuzz_cli.HUGE),
                fuzz_cli.Attempt("train rl", "--log-std-init", "inf", "inf")]
    outcomes = fuzz_cli.fuzz(attempts, jobs=2, timeout=120, workdir=tmp_path, progress=False)
    summary = fuzz_cli.counts(outcomes)
    assert summary["attempts"] == len(attempts)
    assert (summary["tracebacks"], summary["hangs"], summary["non_regular_files_replaced"]) == (0, 0, 0), \
        [(o.attempt, o.last_line) for o in fuzz_cli.findings(outcomes)]
    assert all(o.returncode == (0 if o.attempt.label == "symlink" else 2) for o in outcomes), \
        [(o.attempt, o.returncode, o.last_line) for o in outcomes]


def test_the_oracles_see_a_replaced_fifo_a_traceback_and_a_hang(tmp_path, monkeypatch):
    """A stand-in subcommand that replaces its output FIFO, one that raises, one that sleeps."""
    scripts = {"replace": "import os, sys; p = sys.argv[-1]; os.remove(p); open(p, 'w').write('x')",
               "raise": "raise KeyError('boom')",
               "sleep": "import time; time.sleep(60)"}
    for name, code in scripts.items():
        monkeypatch.setitem(fuzz_cli.COMMANDS, name, fuzz_cli.Command(name, (name,), lambda: None, ()))
    monkeypatch.setattr(fuzz_cli, "ENTRY", "import sys; exec({'replace': %r, 'raise': %r, 'sleep': %r}[sys.argv[1]])"
                        % (scripts["replace"], scripts["raise"], scripts["sleep"]))
    attempts = [fuzz_cli.Attempt("replace", "--out", "fifo", "{fifo}"), fuzz_cli.Attempt("raise", "--x", "nan", "nan"),
                fuzz_cli.Attempt("sleep", "--x", "nan", "nan")]
    outcomes = fuzz_cli.fuzz(attempts, jobs=2, timeout=5, workdir=tmp_path, progress=False)
    assert [o.replaced for o in outcomes] == [["fifo"], [], []]
    assert [o.traceback for o in outcomes] == [False, True, False]
    assert [o.hang for o in outcomes] == [False, False, True]
    assert fuzz_cli.counts(outcomes)["hangs"] == 1 and len(fuzz_cli.findings(outcomes)) == 3


@pytest.mark.parametrize("flag,value", [("--ks", fuzz_cli.HUGE), ("--ks", "1,100000"), ("--samples", "100000")])
def test_critical_evaluate_bounds_its_sample_counts(flag, value, capsys):
    """Found by the fuzz run of seed 1: `--ks 10**30` was numpy's 'Maximum allowed dimension exceeded'."""
    from train.critical.cli import main
    with pytest.raises(SystemExit) as info:
        main(["evaluate", "--models", "gnn", flag, value])
    err = capsys.readouterr().err.strip().splitlines()
    assert info.value.code == 2 and len(err) == 1 and flag in err[0] and "4,096" in err[0], err


def test_the_fuzzer_never_names_a_device_of_the_machine(tmp_path, monkeypatch):
    """Every attempt's command line, with the attempt's own device node and without one (mknod not
    permitted: a socket stands in), names no path under /dev and no device outside its scratch
    directory; a value that would is refused before anything runs."""
    attempts = fuzz_cli.all_attempts(list(fuzz_cli.COMMANDS))
    assert not [a for a in attempts if "/dev" in a.value]
    for mknod_permitted in (True, False):
        if not mknod_permitted:
            def refused(*args, **kwargs):
                raise PermissionError(1, "Operation not permitted")
            monkeypatch.setattr(os, "mknod", refused)
        scratch = tmp_path / f"scratch-{mknod_permitted}"
        scratch.mkdir()
        nodes, checks = fuzz_cli._make_nodes(scratch)
        mode = os.lstat(nodes["{chardev}"]).st_mode
        assert (stat.S_ISCHR(mode) if mknod_permitted else stat.S_ISSOCK(mode)) and checks["{chardev}"](mode)
        assert all(path.startswith(str(scratch)) for path in nodes.values())
        for attempt in attempts:
            argv = fuzz_cli.argv_of(attempt, scratch, tmp_path, nodes)
            assert not [a for a in argv if a.split("=", 1)[-1].startswith("/dev")], (attempt, argv)
    for value in ("/dev/null", "gnn=/dev/null", "/dev/../dev/zero"):
        with pytest.raises(RuntimeError, match="never names a device"):
            fuzz_cli.argv_of(fuzz_cli.Attempt("benchmark", "--json", "x", value), tmp_path, tmp_path, {})


def test_every_bounded_number_is_also_tried_at_its_bound():
    """The values just inside each bound (10**9 for a count, 4,096 for a width, 256 workers, the last
    seed) are attempts of their own: where the bounds that were not bounds showed."""
    bound = {(a.command, a.option): a.value for a in fuzz_cli.at_bound_attempts(list(fuzz_cli.COMMANDS))}
    assert bound[("benchmark", "--problems")] == str(10 ** 9)
    assert bound[("train rl", "--candidates")] == "4096"
    assert bound[("train sampler", "--workers")] == "256"
    assert bound[("critical evaluate", "--seed")] == str(2 ** 32 - 1)
    assert ("train sampler", "--eval-problems") in bound and ("critical generate-data", "--num-maps") in bound


def test_each_attempt_runs_under_a_memory_limit(tmp_path, monkeypatch):
    """An attempt that allocates past --memory-gib fails there (a MemoryError: a traceback, a finding),
    instead of taking the machine's memory; one within it runs."""
    code = "import sys; n = int(sys.argv[-1]); b = bytearray(n); print(len(b))"
    monkeypatch.setitem(fuzz_cli.COMMANDS, "alloc", fuzz_cli.Command("alloc", ("alloc",), lambda: None, ()))
    monkeypatch.setattr(fuzz_cli, "ENTRY", code)
    attempts = [fuzz_cli.Attempt("alloc", "--bytes", "big", str(2 * 2 ** 30)),
                fuzz_cli.Attempt("alloc", "--bytes", "small", str(2 ** 20))]
    outcomes = fuzz_cli.fuzz(attempts, jobs=2, timeout=60, workdir=tmp_path, progress=False, memory_gib=1.0)
    assert [o.traceback for o in outcomes] == [True, False], [o.last_line for o in outcomes]
    assert "MemoryError" in outcomes[0].last_line and outcomes[1].returncode == 0
