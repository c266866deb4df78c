"""A preloaded interpreter for tests/test_docs.py: every ``gnn-mp`` or ``python -m tools.*`` command
of the docs' shell blocks runs in a process forked from it, instead of paying torch's, PyG's and
SB3's imports (10-30 s on a busy 2-core machine) again for each of ~60 commands.

``python docs_server.py SOCKET`` imports :data:`PRELOAD` (no thread starts, so forking is safe;
checked), prints ``ready`` and serves requests from tests/docs_shim.py: the command's words, its
working directory and environment, and its standard streams as file descriptors. For each, a
forked child takes those streams, directory, environment and ``PYTHONPATH``, runs the command the
way its console script or ``python -m`` would, and returns the exit status. Its children (worker
processes, the OMPL runner) are its own; nothing is shared between commands but the imports.
"""

from __future__ import annotations

import importlib
import json
import os
import runpy
import signal
import socket
import struct
import sys
import threading
import traceback
import types

PRELOAD = ("train.cli", "train.benchmark", "train.benchmark.runs", "train.tree.cli", "train.tree.training",
           "train.rl.cli", "train.rl.sb3", "train.rl.torchrl", "train.critical.cli", "train.critical.training",
           "train.critical.evaluation", "agents.registry", "agents.tree.samplers", "agents.rl.sampler",
           "agents.critical.models", "torch_geometric", "matplotlib.pyplot", "tools.bench_sampler",
           "tools.tune_proposals")


def receive(conn: socket.socket) -> tuple[dict, list[int]]:
    header, fds, _, _ = socket.recv_fds(conn, 8, 3)
    (size,) = struct.unpack("!Q", header)
    data = b""
    while len(data) < size:
        chunk = conn.recv(size - len(data))
        if not chunk:
            raise EOFError("request cut short")
        data += chunk
    return json.loads(data), fds


def run(request: dict) -> int:
    """The command of ``request`` in this (forked) process; its exit status."""
    os.chdir(request["cwd"])
    os.environ.clear()
    os.environ.update(request["env"])
    paths = [os.path.abspath(p) for p in request["env"].get("PYTHONPATH", "").split(os.pathsep) if p]
    if request["kind"] == "module":
        paths.insert(0, os.getcwd())                      # what `python -m` puts first
    sys.path[1:1] = paths
    importlib.invalidate_caches()                        # files written since the preload (my_pkg/...)
    try:
        if request["kind"] == "gnn-mp":
            sys.modules["__main__"] = types.ModuleType("__main__")   # spawned workers import no main script
            sys.argv = ["gnn-mp", *request["argv"]]
            from train.cli import main
            return int(main(request["argv"]) or 0)
        sys.argv = [request["module"], *request["argv"]]
        runpy.run_module(request["module"], run_name="__main__", alter_sys=True)
        return 0
    except SystemExit as exc:
        if exc.code is None or isinstance(exc.code, int):
            return int(exc.code or 0)
        print(exc.code, file=sys.stderr)
        return 1
    except BaseException:
        traceback.print_exc()
        return 1


def child(conn: socket.socket, request: dict, fds: list[int]) -> None:
    signal.signal(signal.SIGCHLD, signal.SIG_DFL)
    signal.signal(signal.SIGINT, signal.default_int_handler)
    for target, fd in enumerate(fds):
        os.dup2(fd, target)
        os.close(fd)
    code = 1
    try:
        code = run(request)
    finally:
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except (OSError, ValueError):
                pass
        code = code if 0 <= code < 256 else 1
        conn.sendall(struct.pack("!i", code))
        os._exit(code)


def main(socket_path: str) -> None:
    for module in PRELOAD:
        importlib.import_module(module)
    from gnn_mp_envs.robots.world import import_pybullet
    import_pybullet()
    if threading.active_count() != 1:
        raise RuntimeError(f"the preload started threads ({threading.enumerate()}); forking would not be safe")
    server = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    server.bind(socket_path)
    server.listen(16)
    signal.signal(signal.SIGCHLD, signal.SIG_IGN)        # children are reaped by the kernel
    print("ready", flush=True)
    while True:
        conn, _ = server.accept()
        try:
            request, fds = receive(conn)
        except (OSError, EOFError, ValueError) as exc:
            print(f"docs server: bad request ({exc})", file=sys.stderr, flush=True)
            conn.close()
            continue
        sys.stdout.flush()
        sys.stderr.flush()
        if os.fork() == 0:
            server.close()
            child(conn, request, fds)
        for fd in fds:
            os.close(fd)
        conn.close()


if __name__ == "__main__":
    main(sys.argv[1])
