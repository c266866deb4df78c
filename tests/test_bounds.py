"""Counts at the largest value their flag's parser takes (10**9) are refused in one line when what they keep
would not fit this machine (issue 52 item 6: `train sampler --problems 10**9` and `--dagger-rounds`, `critical
generate-data` / `evaluate --num-maps` ran past 120 s; `train sampler --eval-problems` was a 23-line MemoryError,
`train rl --eval-problems` 41 lines, `train rl --n-steps` a MemoryError); an allocation that fails anyway is one
line too. ``python -m tools.fuzz_cli --at-bound`` tries every bounded flag at its bound."""

from __future__ import annotations

import contextlib
import signal

import pytest

from train.args import MEMORY_SHARE, UsageError, check_fits_in_memory, machine_memory

BILLION = str(10 ** 9)


@contextlib.contextmanager
def _within(seconds: float):
    """Fail (not hang) when the block runs past ``seconds``: a count that is not refused starts its work."""
    def expired(signum, frame):
        raise TimeoutError(f"still running after {seconds} s: the count was not refused")
    previous = signal.signal(signal.SIGALRM, expired)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


@pytest.mark.parametrize("argv, flag", [
    (["train", "sampler", "--task", "maze2d", "--problems", BILLION], "--problems"),
    (["train", "sampler", "--task", "maze2d", "--dagger-rounds", BILLION], "--dagger-rounds"),
    (["train", "sampler", "--task", "maze2d", "--dagger-problems", BILLION], "--dagger-problems"),
    (["train", "sampler", "--task", "maze2d", "--eval-problems", BILLION], "--eval-problems"),
    (["train", "sampler", "--task", "maze2d", "--hidden", BILLION], "--hidden"),
    (["train", "sampler", "--task", "maze2d", "--dagger-rounds", "5000", "--dagger-problems", "1",
      "--dagger-minutes", "10"], "--dagger-minutes"),
    (["critical", "generate-data", "--num-maps", BILLION], "--num-maps"),
    (["critical", "evaluate", "--num-maps", BILLION], "--num-maps"),
    (["critical", "evaluate", "--eval-problems", BILLION], "--eval-problems"),
    (["critical", "train", "--model", "gnn", "--pairs-per-map", BILLION], "--pairs-per-map"),
    (["critical", "train", "--model", "gnn", "--layers", BILLION], "--layers"),
    (["train", "rl", "--task", "maze2d", "--eval-problems", BILLION], "--eval-problems"),
    (["train", "rl", "--task", "maze2d", "--n-steps", BILLION], "--n-steps"),
    (["train", "rl", "--task", "maze2d", "--max-nodes", BILLION], "--max-nodes"),
    (["train", "rl", "--task", "maze2d", "--n-epochs", BILLION], "--n-epochs"),
])
def test_a_count_past_what_fits_is_refused_in_one_line(argv, flag, tmp_path, capsys, monkeypatch):
    from train.cli import main
    monkeypatch.chdir(tmp_path)         # a data or run directory made by mistake would land here
    out = [] if argv[:2] == ["critical", "generate-data"] or argv[:2] == ["critical", "evaluate"] else \
        ["--out", str(tmp_path / "run" / ("critical_gnn.pt" if argv[0] == "critical" else ""))]
    data = ["--data", str(tmp_path / "data")] if argv[0] == "critical" else ["--data-dir", str(tmp_path / "data")] \
        if argv[:2] == ["train", "sampler"] else []
    with _within(60), pytest.raises(SystemExit) as info:
        main([*argv, *out, *data])
    err = capsys.readouterr().err.strip().splitlines()
    assert info.value.code == 2 and len(err) == 1 and flag in err[0], err
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_the_memory_check_names_the_need_and_passes_what_fits():
    have = machine_memory()
    check_fits_in_memory("--x", 1000, 1024, "things")                     # a megabyte: fits anywhere
    with pytest.raises(UsageError, match=r"^--x: [\d,]+ things need at least [\d.,]+ GiB, more than 50%") as info:
        check_fits_in_memory("--x", int(MEMORY_SHARE * have) + 1, 1, "things")
    assert "\n" not in str(info.value)


def test_the_defaults_pass_the_checks():
    from train.critical.args import GenerateArgs
    from train.rl.args import RLArgs, check_memory
    from train.tree.args import TrainArgs, check_counts
    check_counts(TrainArgs())
    check_memory(RLArgs())
    GenerateArgs().check_size()


@pytest.mark.parametrize("error", [MemoryError(), RuntimeError("[enforce fail at alloc_cpu.cpp:127] err == 0. "
                                                               "DefaultCPUAllocator: can't allocate memory: you "
                                                               "tried to allocate 2148532224 bytes.")])
def test_an_allocation_that_fails_anyway_is_one_line(error, monkeypatch, capsys):
    import train.cli as cli

    def allocate():
        raise error
    monkeypatch.setattr(cli, "cmd_samplers", allocate)
    assert cli.main(["samplers"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("gnn-mp: error: out of memory"), err
