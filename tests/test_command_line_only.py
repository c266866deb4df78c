"""A hyperparameter file never chooses where a run writes, what it overwrites, continues or ships, or
what it imports (issue 52 item 3: ``gnn-mp: {out: R, overwrite: true}`` overwrote a finished run, and
``gnn-mp: {ship: true}`` replaced the package's shipped weights, with no flag on the command line)."""

from __future__ import annotations

import pytest

from train.rl.args import COMMAND_LINE_ONLY
from train.rl.cli import parse


def _file(tmp_path, body: str):
    path = tmp_path / "hp.yml"
    path.write_text(body)
    return str(path)


@pytest.mark.parametrize("section", [
    "gnn-mp:\n  out: {run}\n  overwrite: true\n",
    "gnn-mp:\n  ship: true\n",
    "gnn-mp:\n  overwrite: true\n",
    "gnn-mp:\n  resume: true\n",
    "gnn-mp:\n  import: [os]\n",
    "gnn-mp:\n  modules: [os]\n",
    "gnn-mp:\n  hyperparams: other.yml\n",
    "sb3-ppo:\n  ship: true\n",                           # the earlier layout: a section of flag values
    "sb3-ppo:\n  out: {run}\n",
])
def test_a_file_giving_a_command_line_only_flag_is_refused_in_one_line(tmp_path, capsys, section):
    path = _file(tmp_path, section.format(run=tmp_path / "finished"))
    with pytest.raises(SystemExit) as exc:
        parse(["--task", "maze2d", "--hyperparams", path])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "command-line flag only" in err and path in err
    assert not (tmp_path / "finished").exists()


def test_the_same_flags_on_the_command_line_and_other_keys_in_the_file_are_taken(tmp_path):
    path = _file(tmp_path, "gnn-mp:\n  n_steps: 64\n  eval_problems: 3\n")
    args = parse(["--task", "maze2d", "--hyperparams", path, "--out", str(tmp_path / "run"), "--overwrite",
                  "--ship"])
    assert (args.n_steps, args.eval_problems) == (64, 3)
    assert (args.out, args.overwrite, args.ship) == (tmp_path / "run", True, True)
    assert set(COMMAND_LINE_ONLY) >= {"out", "overwrite", "ship", "resume", "modules"}
