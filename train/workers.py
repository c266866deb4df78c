"""Jobs in other processes: the worker pool and the Ray runner that the benchmark and the tree
samplers' dataset collection both use.

A job is a tuple; ``fn(job)`` (a module-level function, so it pickles) runs it in a worker and
``finished(result)`` is called in this process for every job, in completion order:

    with WorkerPool(workers, modules) as pool:      # or RayPool(address, workers, modules): Ray actors
        pool.run(jobs, finished, fn)

Each worker imports the plugin modules of this process once (every ``--import`` module, a module
of the current directory from the file this process loaded: :func:`train.args.plugin_sources`) and
keeps what its jobs cache (envs, samplers); results do not depend on the worker count or the
backend when every job seeds itself. A dead worker or Ray actor is a
:class:`~concurrent.futures.process.BrokenProcessPool`.

Nothing else of the current directory is imported anywhere: Ray puts the driver's current
directory at the head of every worker's ``sys.path`` (and starts its local workers there), so a
``train.py`` or ``numpy.py`` there would replace a module of the same name in the actors;
:func:`start_ray` starts Ray from an empty private directory instead, and the actors work in the
driver's directory without it on their path. :class:`WithPlugins` carries the plugins into the
processes other libraries start (SB3's ``SubprocVecEnv``, TorchRL's ``ParallelEnv`` and
``RayCollector``).
"""

from __future__ import annotations

import atexit
import multiprocessing
import os
import shutil
import signal
import sys
import tempfile
from concurrent.futures import ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from typing import Any, Callable, Iterable

from train.args import PluginSource, UsageError, import_plugin_sources, plugin_sources


def _die_with_parent() -> None:
    """Ask Linux to SIGKILL this worker when the parent process dies (SIGTERM, SIGKILL, a crash),
    so no worker, and hence no resource tracker, outlives it; and leave Ctrl-C to the parent, which
    stops the workers itself (one line instead of a traceback per worker)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        import ctypes
        PR_SET_PDEATHSIG = 1
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL)
    except (OSError, AttributeError):   # not Linux/glibc: workers still end with the pool
        return
    if os.getppid() == 1:   # the parent died before the request took effect
        os._exit(1)


def _init_worker(plugins: Iterable[PluginSource], die_with_parent: bool = True) -> None:
    """Worker initializer: die with the parent and import the parent's plugin modules. What the jobs
    need (envs, samplers) is built by the first job that needs it, so one pool serves several tasks."""
    if die_with_parent:
        _die_with_parent()
    import_plugin_sources(plugins)


class WithPlugins:
    """``fn`` as a picklable callable that first imports this process's plugin modules (``--import``,
    :func:`train.args.plugin_sources`) wherever it is called: how an env builder reaches the processes
    that SB3's ``SubprocVecEnv``, TorchRL's ``ParallelEnv`` or a ``RayCollector`` start, where a task
    registered by ``--import`` is otherwise unknown. In this process the imports are already done.
    (Slots, no ``__dict__``: TorchRL's ``CloudpickleWrapper`` copies a wrapped callable's ``__dict__``
    into its own, and a ``fn`` there would replace the wrapper's.)"""

    __slots__ = ("wrapped_fn", "plugins")

    def __init__(self, fn: Callable[..., Any], modules: Iterable[str] = ()) -> None:
        self.wrapped_fn, self.plugins = fn, plugin_sources(modules)

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        import_plugin_sources(self.plugins)
        return self.wrapped_fn(*args, **kwargs)


class WorkerPool:
    """``workers`` processes that run jobs, reused across calls (a benchmark suite's tasks: each
    worker pays its imports once). Forked while this process has not imported torch, else spawned
    (:func:`worker_start_method`). On an error or Ctrl-C the workers are killed at once."""

    def __init__(self, workers: int, modules: list[str] = ()) -> None:
        context = multiprocessing.get_context(worker_start_method())
        self.executor = ProcessPoolExecutor(max_workers=workers, mp_context=context, initializer=_init_worker,
                                            initargs=(plugin_sources(modules),))
        self.killed = False

    def run(self, jobs: list[tuple], finished: Callable[[Any], None], fn: Callable[[tuple], Any]) -> None:
        """``finished(fn(job))`` for every job, in completion order (``fn``: a module-level function)."""
        try:
            futures = [self.executor.submit(fn, job) for job in jobs]
            for future in as_completed(futures):
                finished(future.result())
        except BaseException:
            self.kill()
            raise

    def kill(self) -> None:
        self.killed = True
        processes = list((self.executor._processes or {}).values())   # the pool has no public kill
        self.executor.shutdown(wait=False, cancel_futures=True)
        for process in processes:
            process.kill()
        for process in processes:
            process.join(timeout=5)

    def __enter__(self) -> "WorkerPool":
        return self

    def __exit__(self, *exc) -> None:
        if not self.killed:
            self.executor.shutdown()


class _JobActor:
    """A Ray actor: one worker process with what its jobs cache, as a pool's workers. It works in the
    driver's directory when this machine has it (a job's relative paths), never with it on ``sys.path``."""

    def __init__(self, plugins: Iterable[PluginSource], directory: str) -> None:
        if os.path.isdir(directory):
            os.chdir(directory)
        _init_worker(plugins, die_with_parent=False)

    def run(self, fn, job: tuple) -> Any:
        return fn(job)


#: The empty directory Ray was started from (:func:`start_ray`), removed at exit.
_RAY_DIRECTORY: list[str] = []


def start_ray(address: str | None, **init: Any) -> None:
    """``ray.init(address, **init)`` from an empty private directory: Ray adds the driver's current
    directory to every worker's ``sys.path`` (first) and starts a local instance's workers there,
    so a ``train.py``, ``numpy.py`` or ``agents/`` in the user's directory would be imported by the
    actors in place of the modules of that name. The directory stays (empty) until this process
    exits: the workers of a local instance keep it as their working directory.

    SIGTERM keeps the handler it had: ``ray.init`` replaces it (a Python ``sys.exit``, then the C++
    core worker's failure handler, which answers SIGTERM with a stack dump and SIGABRT); the
    command's handler ends the run as Ctrl-C does (:func:`train.cli.terminate_as_interrupt`)."""
    import threading

    import ray
    if not _RAY_DIRECTORY:
        _RAY_DIRECTORY.append(tempfile.mkdtemp(prefix="gnn-mp-ray-"))
        atexit.register(shutil.rmtree, _RAY_DIRECTORY[0], True)
    main_thread = threading.current_thread() is threading.main_thread()
    sigterm = signal.getsignal(signal.SIGTERM) if main_thread else None
    here = os.getcwd()
    os.chdir(_RAY_DIRECTORY[0])
    try:
        ray.init(address=address, **init)
    finally:
        os.chdir(here)
        if sigterm is not None:
            signal.signal(signal.SIGTERM, sigterm)


class RayPool:
    """Ray actors that run jobs, as :class:`WorkerPool`'s processes do, reused across calls (a
    benchmark's timed runs, then the re-checks of their paths): Ray is started (or joined) once and
    each actor pays its imports once. ``address``: ``"local"`` starts a local instance with
    ``workers`` CPUs (the flags' ``--ray``), ``"auto"`` or ``ray://HOST:10001`` joins a cluster.
    The actors are made by the first :meth:`run`, no more than its jobs. A local instance this pool
    started is shut down on leaving it. A job's :class:`~train.args.UsageError` is raised here as it
    was raised there."""

    def __init__(self, address: str, workers: int, modules: list[str] = ()) -> None:
        try:
            import ray
        except ImportError:
            raise UsageError("--ray needs Ray: pip install 'gnn-mp-envs[ray]'") from None
        self.workers, self.plugins, self.actors = workers, plugin_sources(modules), []
        local = address == "local"
        self.started = not ray.is_initialized()
        if self.started:
            try:
                start_ray(None if local else address, num_cpus=workers if local else None, include_dashboard=False,
                          log_to_driver=False, configure_logging=False)
            except (ConnectionError, RuntimeError, ValueError) as exc:
                raise UsageError(f"cannot reach Ray at {address}: {str(exc).splitlines()[0]}") from None

    def run(self, jobs: list[tuple], finished: Callable[[Any], None], fn: Callable[[tuple], Any]) -> None:
        """``finished(fn(job))`` for every job, in completion order (``fn``: a module-level function)."""
        import ray
        from ray.util import ActorPool
        if not jobs:
            return
        try:
            if not self.actors:
                actor = ray.remote(num_cpus=1)(_JobActor)
                self.actors = [actor.remote(self.plugins, os.getcwd())
                               for _ in range(max(1, min(self.workers, len(jobs))))]
            pool = ActorPool(self.actors)
            for result in pool.map_unordered(lambda a, job: a.run.remote(fn, job), jobs):
                finished(result)
        except ray.exceptions.RayTaskError as exc:
            cause = exc.cause if isinstance(getattr(exc, "cause", None), UsageError) else None
            raise cause or UsageError(f"a Ray task failed: {str(exc).splitlines()[0]}") from None
        except ray.exceptions.RayActorError:
            raise BrokenProcessPool("a Ray actor died") from None

    def __enter__(self) -> "RayPool":
        return self

    def __exit__(self, *exc) -> None:
        self.actors = []
        if self.started:
            import ray
            ray.shutdown()


class SharedPool:
    """The workers of a run whose job batches come apart in time (a benchmark's timed runs, then the re-check of
    their paths; a tree sampler's training data, then each DAgger round's): a :class:`RayPool` (``ray``: an address or ``"local"``) or a :class:`WorkerPool` of
    ``workers`` processes (none for one worker: jobs run here), made by the first :meth:`run` and reused by
    the next, so Ray starts and each worker pays its imports once per run, not once per batch."""

    def __init__(self, workers: int, ray: str | None = None, modules: list[str] = ()) -> None:
        self.workers, self.ray, self.modules = int(workers), ray, list(modules)
        self.pool: WorkerPool | RayPool | None = None

    def run(self, jobs: list[tuple], finished: Callable[[Any], None], fn: Callable[[tuple], Any]) -> None:
        """``finished(fn(job))`` for every job, in completion order (here, in order, without workers)."""
        if not jobs:
            return
        if self.pool is None and self.ray is None and min(self.workers, len(jobs)) <= 1:
            for job in jobs:
                finished(fn(job))
            return
        if self.pool is None:                    # never more processes than the first batch's jobs
            self.pool = (RayPool(self.ray, self.workers, self.modules) if self.ray is not None
                         else WorkerPool(min(self.workers, len(jobs)), self.modules))
        self.pool.run(jobs, finished, fn)

    def __enter__(self) -> "SharedPool":
        return self

    def __exit__(self, *exc) -> None:
        if self.pool is not None:
            self.pool.__exit__(*exc)
            self.pool = None


def worker_start_method() -> str:
    """``"fork"`` while this process has not imported torch (classical jobs: the workers start at
    once, with everything imported), ``"spawn"`` once it has (torch's thread pools do not survive a
    fork: a forked worker can deadlock)."""
    return "spawn" if "torch" in sys.modules else "fork"
