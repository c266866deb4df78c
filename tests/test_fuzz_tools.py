"""tools/fuzz_tools.py: every ``python -m tools.*`` script's flags read from its ``--help``, and a sample of the
bad values that were tracebacks (issue 52 item 8: 46 of 159 attempts) now one line each (the full run is
``python -m tools.fuzz_tools``)."""

from __future__ import annotations

from tools import fuzz_tools


def test_every_script_has_flags_or_arguments_read_from_its_help():
    for tool in fuzz_tools.TOOLS:
        options, positional = fuzz_tools.options_of(tool)
        assert options or positional, tool
        assert "--write" not in options
    assert "--seed" in fuzz_tools.options_of("bench_env")[0] and fuzz_tools.options_of("mbm_table")[1]


def test_every_script_of_tools_is_fuzzed():
    """A script run as ``python -m tools.NAME`` (its main through ``run_script``) is in the fuzzer's list
    (the fuzzer itself aside)."""
    from pathlib import Path
    scripts = {p.stem for p in (Path(fuzz_tools.__file__).parent).glob("*.py")
               if 'if __name__ == "__main__":' in p.read_text() and "run_script(main)" in p.read_text()}
    assert len(scripts) >= 15
    assert scripts - {"fuzz_tools"} == set(fuzz_tools.TOOLS)


def test_a_sample_of_bad_values_is_one_line_each(tmp_path):
    A = fuzz_tools.Attempt
    attempts = [A("bench_checker", "--task", "text", "abc"), A("bench_env", "--seed", "negative", "-1"),
                A("bench_env", "--sizes", "huge", fuzz_tools.HUGE), A("bench_vec", "--seed", "negative", "-1"),
                A("compare_on_kinds", "--configs", "negative", "-1"), A("compare_on_kinds", "--problems", "negative", "-1"),
                A("compare_on_kinds", "--workers", "huge", fuzz_tools.HUGE),
                A("rl_tree_swap", "--checkpoint", "not json", "{text}"), A("scene_gallery", "--out", "empty", ""),
                A("scene_gallery", "--problems", "huge", fuzz_tools.HUGE), A("fuzz_cli", "--timeout", "huge", fuzz_tools.HUGE),
                A("fuzz_cli", "--json", "directory", "{dir}"), A("tune_proposals", "--task", "text", "abc"),
                A("tune_batch", "--batches", "negative", "-1"), A("tune_batch", "--uniform-mix", "nan", "nan"),
                A("mbm_table", "", "json of another kind", "{json}"), A("vamp_table", "", "not json", "{text}"),
                A("spherize", "--seed", "negative", "-1")]
    outcomes = fuzz_tools.fuzz(attempts, jobs=2, timeout=120, workdir=tmp_path, progress=False)
    assert fuzz_tools.counts(outcomes)["tracebacks"] == 0, [(o.attempt, o.last_line) for o in outcomes if o.traceback]
    assert all(o.returncode == 2 and o.last_line.startswith(f"python -m tools.{o.attempt.tool}") or
               o.returncode == 2 and "usage" not in o.last_line for o in outcomes), \
        [(o.attempt, o.returncode, o.last_line) for o in outcomes]
