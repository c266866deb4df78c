"""``tools.same_counters``: the refactor check's comparison of two benchmark reports, and its refusals."""

from __future__ import annotations

import copy

import pytest

from tools import same_counters


def _report() -> dict:
    run = {"problem": 0, "success": True, "nodes_expanded": 12, "edges": 30, "collision_checks": 410, "iterations": 25,
           "path_length": 1.25, "wall_time_s": 0.001}
    return {"runs": {"uniform": [run, {**run, "problem": 1, "success": False, "path_length": None}],
                     "gnn": [{**run, "nodes_expanded": 9}]}}


def test_identical_reports_have_no_differences_and_wall_times_do_not_count():
    before = _report()
    after = copy.deepcopy(before)
    after["runs"]["uniform"][0]["wall_time_s"] = 9.0          # a time is not a result
    assert same_counters.differences("maze2d", before, after) == (3, 3, [])


@pytest.mark.parametrize("field, value", [("success", False), ("nodes_expanded", 13), ("edges", 31),
                                          ("collision_checks", 411), ("iterations", 26), ("path_length", 1.2500001)])
def test_each_counter_that_changes_is_named_with_its_run(field, value):
    before = _report()
    after = copy.deepcopy(before)
    old = after["runs"]["uniform"][1 if field == "success" else 0]
    problem = old["problem"]
    if field == "success":
        value = True
    was = old[field]
    old[field] = value
    compared, identical, found = same_counters.differences("maze2d", before, after)
    assert (compared, identical) == (3, 2)
    assert found == [f"maze2d uniform problem {problem}: {field} {was!r} -> {value!r}"]


def test_a_sampler_or_run_missing_from_the_second_report_differs():
    before = _report()
    after = copy.deepcopy(before)
    del after["runs"]["gnn"]
    after["runs"]["uniform"].pop()
    compared, identical, found = same_counters.differences("arm", before, after)
    assert (compared, identical) == (3, 1)
    assert found == ["arm uniform run 1: not in the second report", "arm gnn: not in the second report"]


@pytest.mark.parametrize("argv, message", [
    (["--base", "no-such-revision-here"], "is not a commit of this repository"),
    (["--base", "HEAD", "--tasks", "maze2d,nonesuch"], "--tasks takes some of maze2d"),
    (["--base", "HEAD", "--head", "tests"], "holds no gnn_mp_envs package"),
])
def test_bad_arguments_are_refused_in_one_line(argv, message, capsys):
    with pytest.raises(SystemExit) as exit_:
        same_counters.main(argv)
    assert exit_.value.code == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1
