"""One meaning of "success" in every table of a report: the main table's success rate, the field
table's and the per-scene table's "solved" and ``tools/mbm_table``'s all count a path found within the
node budget that passes the re-check (a hand-made results JSON, the kind an mbm run writes)."""

from __future__ import annotations

import json
import re


def run(problem, family, success=True, nodes=50, wall=0.01, path_valid=True):
    return {"sampler": "x", "problem": problem, "family": family, "success": success, "nodes_expanded": nodes,
            "edges": nodes, "collision_checks": 10 * nodes, "iterations": nodes, "wall_time_s": wall,
            "sampler_time_s": 0.0, "planner_time_s": wall, "path_length": 5.0 if success else None,
            "path_valid": path_valid if success else None, "path_valid_fine": path_valid if success else None}


def report_json(tmp_path):
    """One problem per row as a one-problem run prints it, and a few more: an OMPL row over the node
    budget, a path failing the re-check, a slow run (past the OMPL time limit), a failure. The stored
    success rates are an earlier version's (the planner's success alone): the tables recount."""
    from train.benchmark.stats import sampler_summary
    runs = {"uniform": [run(0, "cage"), run(1, "box", wall=12.0), run(2, "box", success=False)],
            "gnn": [run(0, "cage", path_valid=False), run(1, "box"), run(2, "box")],
            "ompl-rrtconnect": [run(0, "cage", nodes=7000), run(1, "box"), run(2, "box")]}
    report = {"task": "panda-mbm", "env_id": "GNNMP/PandaMBM-v0", "problems": 3, "seed": 0, "split": "test",
              "max_nodes": 5000, "time_limit_s": 10.0, "scene": "all",
              "results": {n: {**sampler_summary(r), "success_rate": sum(x["success"] for x in r) / len(r)}
                          for n, r in runs.items()}, "runs": runs}
    path = tmp_path / "panda-mbm.json"
    path.write_text(json.dumps(report))
    return path


def test_every_table_of_a_report_counts_the_same_success(tmp_path, capsys):
    from tools.mbm_table import main as mbm_table
    from train.benchmark.tables import format_family_table, format_field_table, format_table
    report = json.loads(report_json(tmp_path).read_text())
    expected = {"uniform": (2, 3), "gnn": (2, 3), "ompl-rrtconnect": (2, 3)}     # solved, problems
    per_scene = {"cage": {"uniform": "1/1", "gnn": "0/1", "ompl-rrtconnect": "0/1"},
                 "box": {"uniform": "1/2", "gnn": "2/2", "ompl-rrtconnect": "2/2"}}

    main = {line.split()[0]: line.split()[1] for line in format_table(report).splitlines()[3:6]}
    assert main == {name: f"{100 * s / n:.0f}%" for name, (s, n) in expected.items()}
    field = {line.split()[0]: line.split()[1] for line in format_field_table(report).splitlines()[3:6]}
    assert field == {name: f"{s}/{n}" for name, (s, n) in expected.items()}
    family = {(line.split()[0], line.split()[1]): line.split()[2]
              for line in format_family_table(report).splitlines()[3:]}
    assert family == {(scene, name): v for scene, row in per_scene.items() for name, v in row.items()}

    assert mbm_table([str(tmp_path / "panda-mbm.json")]) == 0
    out = capsys.readouterr().out
    rows = {cells[0]: cells[1:] for cells in (
        [c.strip() for c in line.strip("|").split("|")] for line in out.splitlines() if line.startswith("| "))}
    for scene, row in per_scene.items():
        names = [c.strip() for c in next(l for l in out.splitlines() if l.startswith("| scene |")).strip("|").split("|")][1:]
        assert {n: re.match(r"(\d+/\d+)", cell).group(1) for n, cell in zip(names, rows[scene])} == row
    for name, (s, n) in expected.items():
        assert rows[f"{name} (ours)"][0] == f"{s}/{n}"


def test_the_json_success_rate_is_the_same_count():
    from train.benchmark.stats import sampler_summary, solved
    runs = [run(0, "a"), run(1, "a", nodes=7000), run(2, "a", path_valid=False), run(3, "a", wall=99.0),
            run(4, "a", success=False)]
    assert [solved(r, 5000) for r in runs] == [True, False, False, True, False]
    summary = sampler_summary(runs, 5000)
    assert summary["success_rate"] == 0.4 and summary["path_length"]["median"] == 5.0
