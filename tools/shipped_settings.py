"""Store a sampling setting chosen on split ``val`` in a shipped checkpoint and its ``.json`` sidecar.

The tuning tools (``tools.tune_proposals``, ``tools.tune_adaptive``) end the same way: the chosen
value joins the checkpoint's ``meta["sampler"]`` (what ``load_sampler`` applies), and the tuning
table with the command that produced it is kept beside it, in the weights and in the sidecar.
"""

from __future__ import annotations

import json
import shlex
import sys
from pathlib import Path
from typing import Any

from gnn_mp_envs.utils.io import atomic_write_text


def tool_command(module: str, argv: list[str] | None) -> str:
    """The command line that ran ``module`` (quoted so that it runs as written)."""
    return f"python -m {module} " + shlex.join(sys.argv[1:] if argv is None else argv)


def store_tuned_setting(sampler: str, task: str, setting: dict[str, Any], tuning_key: str,
                        tuning: dict[str, Any]) -> Path:
    """Write ``setting`` into the shipped ``sampler`` weights of ``task`` and ``tuning`` under
    ``tuning_key``, in the checkpoint's meta and its sidecar; returns the checkpoint's path."""
    from agents.checkpoints import load_checkpoint, save_checkpoint, shipped_checkpoint   # torch: only to write
    path = shipped_checkpoint(sampler, task)
    model, record = load_checkpoint(path)
    meta = dict(record["meta"])
    meta["sampler"] = {**meta.get("sampler", {}), **setting}
    meta[tuning_key] = tuning
    save_checkpoint(path, model, record["kind"], record["ctor_args"], obs_spec=record["obs_spec"], meta=meta)
    sidecar = Path(path).with_suffix(".json")
    side = json.loads(sidecar.read_text()) if sidecar.exists() else {}
    side["sampler"] = meta["sampler"]
    side[tuning_key] = tuning
    atomic_write_text(sidecar, json.dumps(side, indent=2) + "\n")
    print(f"wrote {path} and its sidecar")
    return Path(path)
