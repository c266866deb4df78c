"""The reference says what the code does: the task lists of ``gnn-mp benchmark --help`` and of the docs
name every built-in task (``BUILTIN_TASKS`` of gnn_mp_envs/registration.py), docs/quickstart.md's flag
table covers every flag of ``gnn-mp benchmark`` and names every suite and every task's time budget, and
the API reference documents the RL, checkpoint and graph functions."""

from __future__ import annotations

import re
from pathlib import Path

from gnn_mp_envs.registration import BUILTIN_TASKS

ROOT = Path(__file__).resolve().parents[1]
TASKS = [spec.name for spec in BUILTIN_TASKS]


def benchmark_help() -> str:
    """``gnn-mp benchmark --help`` on one line (argparse's wrapping at hyphens undone)."""
    from train.cli import build_parser
    parser = build_parser()
    action = next(a for a in parser._subparsers._group_actions if a.dest == "command")
    return " ".join(action.choices["benchmark"].format_help().split()).replace("- ", "-")


def flag_table(page: str) -> dict[str, str]:
    """``--flag`` -> its row, from the flag table of a page (rows ``| `--flag ...` | meaning |``)."""
    rows = re.findall(r"^\| (`--[^|]*) \| (.*) \|$", (ROOT / "docs" / page).read_text(), re.M)
    return {flag: f"{first} | {rest}" for first, rest in rows for flag in re.findall(r"--[\w-]+", first)}


def test_the_help_names_every_built_in_task():
    text = benchmark_help()
    task_help = text[text.index("--task TASK task family"):text.index("--samplers SAMPLERS comma")]
    assert len(TASKS) >= 6 and all(task in task_help for task in TASKS), task_help
    time_help = text[text.index("--ompl-time-limit OMPL_TIME_LIMIT seconds"):]
    for spec in BUILTIN_TASKS:
        assert f"{spec.time_limit_s:g} s for" in time_help and spec.name in time_help


def test_the_quickstart_flag_table_covers_every_flag_of_the_benchmark():
    """Every flag ``gnn-mp benchmark --help`` lists has a row of its own, or is named in one (the
    suite's --out, --no-ompl, --no-vamp, --no-render; --import's alias)."""
    table = flag_table("quickstart.md")
    text = (ROOT / "docs" / "quickstart.md").read_text()
    rows = "\n".join(line for line in text.splitlines() if line.startswith("| `--"))
    flags = sorted(set(re.findall(r"(?<![\w-])--[a-z][\w-]*", benchmark_help())) - {"--help"})
    assert len(flags) >= 25
    missing = [f for f in flags if not re.search(rf"`{f}[` ]", rows)]
    assert missing == [], f"docs/quickstart.md's flag table lacks {missing}"
    assert {"--checker", "--save-paths", "--no-recheck", "--success-plot"} <= set(table)


def test_the_docs_name_every_built_in_task_suite_and_time_budget():
    from train.benchmark.suites import SUITES
    table = flag_table("quickstart.md")
    assert all(f"`{task}`" in table["--task"] for task in TASKS), table["--task"]
    assert all(f"`{suite}`" in table["--suite"] for suite in SUITES), table["--suite"]
    suite_help = benchmark_help()[benchmark_help().index("--suite SUITE run"):]
    assert all(suite in suite_help for suite in SUITES), suite_help
    for spec in BUILTIN_TASKS:
        assert f"{spec.name} {spec.max_nodes}" in table["--max-nodes"], spec.name
    limits = {spec.time_limit_s for spec in BUILTIN_TASKS}
    assert all(f"{limit:g} s" in table["--ompl-time-limit"] for limit in limits)
    slow = [spec.name for spec in BUILTIN_TASKS if spec.time_limit_s != 10.0]
    assert all(name in table["--ompl-time-limit"] for name in slow)
    environments = (ROOT / "docs" / "environments.md").read_text()
    task_row = next(line for line in environments.splitlines() if line.startswith("| `task` |"))
    assert all(f"`{task}`" in task_row for task in TASKS), task_row
    ids = re.findall(r"^\| `(GNNMP/[^`]+)` \| ([\w-]+) \|", environments, re.M)
    assert sorted({task for _, task in ids}) == sorted(TASKS)
    for spec in BUILTIN_TASKS:                 # the sentence naming the id each task is benchmarked with
        assert f"`{spec.name}` with `{spec.env_id}`" in " ".join(environments.split()), spec.name


def test_the_api_reference_documents_the_rl_checkpoint_and_graph_functions():
    """The directives of docs/api/ name the functions a user of the learned models calls (the site's
    build, tests/test_docs_site.py, checks that each one renders)."""
    api = {p.name: p.read_text() for p in (ROOT / "docs" / "api").glob("*.md")}
    text = "\n".join(api.values())
    for module, names in {"agents.rl.policies": ["policy_from_sb3", "policy_from_torchrl"],
                          "agents.rl.sampler": ["save_policy", "sampler_from_checkpoint", "load_rl_sampler"],
                          "agents.checkpoints": ["save_checkpoint", "load_checkpoint", "read_checkpoint",
                                                 "register_model_kind"],
                          "agents.nn.graph": ["to_pyg", "tree_data"]}.items():
        assert f"::: {module}" in text, module
        block = text[text.index(f"::: {module}"):]
        block = block[:block.find("\n::: ", 1) if "\n::: " in block[1:] else len(block)]
        for name in names:
            assert name in block, (module, name)
    assert "export_tree" in api["environments.md"] and "::: gnn_mp_envs.envs.vector" in text
    nav = (ROOT / "mkdocs.yml").read_text()
    assert all(f"api/{page}" in nav for page in api), "an API page is not in the nav"
