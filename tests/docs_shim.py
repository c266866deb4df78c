"""The commands the docs' shell blocks call, as tests/test_docs.py runs them.

``gnn-mp ...`` and ``python -m tools.<name> ...`` (also as ``.venv/bin/...``) get the budget
flags of :data:`BUDGET` appended to their command line (argparse keeps the last value of a flag,
so an appended ``--problems 2`` wins over the page's ``--problems 100``) and run in a fresh
process forked from the preloaded interpreter of tests/docs_server.py, so that a page of ten
commands does not import torch ten times. Any other ``python`` command is the real interpreter
(with the budget for ``-m pytest``). docs/index.md ("How the docs are tested") prints the table.

Started as ``python -S docs_shim.py SOCKET REAL_PYTHON {gnn-mp|python} ARGS...``: standard
library only, a few milliseconds.
"""

from __future__ import annotations

import json
import os
import socket
import struct
import sys

#: Dataset flags of every ``gnn-mp critical`` sub-command (10 maps, 2 evaluation problems).
CRITICAL_DATA = ["--num-maps", "10", "--pairs-per-map", "1", "--eval-problems", "2"]
#: Command (as its first words) -> flags appended to it. The longest matching prefix wins.
BUDGET: dict[str, list[str]] = {
    "gnn-mp benchmark": ["--problems", "2", "--ompl-time-limit", "2", "--workers", "1"],
    "gnn-mp benchmark --suite": ["--suite", "smoke", "--workers", "1"],
    "gnn-mp train sampler": ["--problems", "6", "--minutes", "0.01", "--dagger-problems", "3",
                             "--dagger-minutes", "0.01", "--eval-problems", "1"],
    # the Fetch's third DAgger problem, planned by the barely trained GNN, takes minutes: one problem
    "gnn-mp train sampler --task fetch-mbm": ["--problems", "6", "--minutes", "0.01", "--dagger-problems", "1",
                                              "--dagger-minutes", "0.01", "--eval-problems", "1"],
    "gnn-mp train rl": ["--total-steps", "32", "--n-envs", "2", "--n-steps", "16", "--batch-size", "16",
                        "--eval-every", "32", "--eval-problems", "1", "--eval-max-steps", "100",
                        "--learning-starts", "16", "--buffer-size", "256"],
    "gnn-mp critical generate-data": CRITICAL_DATA,
    "gnn-mp critical train": [*CRITICAL_DATA, "--epochs", "1", "--max-steps", "2", "--batch-size", "2"],
    "gnn-mp train critical": [*CRITICAL_DATA, "--epochs", "1", "--max-steps", "2", "--batch-size", "2"],
    "gnn-mp critical evaluate": [*CRITICAL_DATA, "--problems", "2", "--samples", "2"],
    "python -m tools.bench_sampler": ["--act-nodes", "60", "--window", "5", "--rounds", "1", "--batch", "4",
                                      "--nodes", "40", "--trees", "2", "--conversions", "1"],
    "python -m tools.bench_arm": ["--problems", "2", "--raw-checks", "200", "--window", "100"],
    "python -m tools.bench_vec": ["--steps", "400", "--modes", "single,sync,async"],
    "python -m tools.tune_proposals": ["--problems", "2", "--repeats", "1"],
    "python -m tools.tune_batch": ["--problems", "2", "--repeats", "1", "--batches", "1,2"],
    "python -m tools.rl_tree_swap": ["--problems", "2", "--max-steps", "200"],
    "python -m tools.compare_on_kinds": ["--problems", "2", "--workers", "1"],
    "python -m pytest": ["tests/test_architecture.py"],
}


def budget(words: list[str]) -> list[str]:
    """The flags appended to the command ``words`` (none for ``--help``)."""
    if "-h" in words or "--help" in words:
        return []
    line = " ".join(words)
    keys = [k for k in BUDGET if line == k or line.startswith(k + " ")]
    if "--suite" in words[2:] and words[:2] == ["gnn-mp", "benchmark"]:
        keys = ["gnn-mp benchmark --suite"]
    return list(BUDGET[max(keys, key=len)]) if keys else []


def run_in_server(socket_path: str, request: dict) -> int:
    """Hand the command and this process's standard streams to the server; its exit status."""
    conn = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    conn.connect(socket_path)
    data = json.dumps(request).encode()
    socket.send_fds(conn, [struct.pack("!Q", len(data))], [0, 1, 2])
    conn.sendall(data)
    reply = b""
    while len(reply) < 4:
        chunk = conn.recv(4 - len(reply))
        if not chunk:
            print("docs test: the command ended without an exit status", file=sys.stderr)
            return 1
        reply += chunk
    return struct.unpack("!i", reply)[0]


def main() -> int:
    socket_path, python, kind, *args = sys.argv[1:]
    request = {"cwd": os.getcwd(), "env": dict(os.environ)}
    if kind == "gnn-mp":
        return run_in_server(socket_path, {**request, "kind": "gnn-mp",
                                           "argv": args + budget(["gnn-mp", *args])})
    if args[:1] == ["-m"] and len(args) > 1 and args[1].startswith("tools."):
        return run_in_server(socket_path, {**request, "kind": "module", "module": args[1],
                                           "argv": args[2:] + budget(["python", *args])})
    extra = budget(["python", *args]) if args[:1] == ["-m"] else []
    os.execv(python, [python, *args, *extra])
    return 1


if __name__ == "__main__":
    sys.exit(main())
