"""Where evaluation jobs run: in this process, in a local process pool, or as Ray tasks.

``run_jobs(fn, jobs, on_result, executor)`` calls ``fn(*job.args)`` for every job and hands each
outcome to ``on_result(job, result, error)`` as soon as it finishes (in completion order), so the
caller can log it at once. A job whose call raises, or whose worker dies (a process killed by
the kernel, a crashed Ray worker), is run once more (``retries``); if it fails again
``on_result`` gets ``result=None`` and ``error`` (one line: the exception's type and message).
A dead worker of the local pool fails every job of the pool; those are run again one at a time,
so that only the job that kills a worker on its own is charged with the failure.
Ctrl-C or SIGTERM in the driver stops everything and propagates: what was in flight is lost, what
finished was handed over already. The local pool's workers leave SIGINT to the driver, which
terminates them, and on Linux (where the pool forks them) they end with the driver
(``PR_SET_PDEATHSIG``) even when it is killed outright, so no worker is left running jobs for
nobody.

Executors (``make_executor``):

* ``LocalExecutor(workers)``: ``workers`` forked processes (``concurrent.futures``), or this
  process when ``workers`` is 1; a pool broken by a dead worker is replaced.
* ``RayExecutor(address, num_cpus)``: Ray tasks of one CPU each, on the cluster at ``address``
  (``ray start --head`` prints it; every node needs this distribution installed) or on a Ray
  started for the run with ``num_cpus`` CPUs. ``share(obj)`` puts an object into Ray's object
  store once (the model files), and a job's arguments that are such references reach ``fn`` as
  the objects, on whichever node runs it. Ray is an optional extra: ``pip install .[ray]``.
"""

from __future__ import annotations

import concurrent.futures as cf
import ctypes
import multiprocessing as mp
import os
import signal
import sys
from collections.abc import Callable, Iterable
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from typing import Any

__all__ = ["EXECUTORS", "Job", "LocalExecutor", "RayExecutor", "make_executor", "require_ray", "run_jobs"]

EXECUTORS = ("local", "ray")


@dataclass(frozen=True)
class Job:
    """key: what identifies the job to the caller (e.g. ``(variant, demo_seed, scenario)``);
    args: ``fn``'s positional arguments."""

    key: tuple
    args: tuple


def job_error_line(e: BaseException) -> str:
    """One line for a failed job: the exception's type and the first line of its message."""
    cause = getattr(e, "cause", None)  # a Ray task error carries the task's own exception
    e = cause if isinstance(cause, BaseException) else e
    text = str(e).strip().splitlines()
    return f"{type(e).__name__}: {text[0] if text else ''}".rstrip(": ")


PR_SET_PDEATHSIG = 1  # prctl(2): the signal a process gets when its parent ends


def _start_worker(parent: int | None, initializer: Callable[[], None] | None) -> None:
    """First thing in each worker of a local pool: SIGINT is left to the driver (a terminal's
    Ctrl-C reaches the whole process group, and every idle worker printed a KeyboardInterrupt
    traceback), SIGTERM ends it quietly (a fork inherits the driver's handlers, which raise), and
    on Linux a worker forked by the driver (pid ``parent``; None when another process starts the
    workers, as the forkserver does) gets SIGTERM when the thread that forked it ends: the pool
    forks from the thread that submits, the driver's main thread here, so when the driver ends,
    however it ends; then ``initializer``."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    if parent is not None and sys.platform.startswith("linux"):
        try:
            ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, int(signal.SIGTERM))
        except (OSError, AttributeError):  # no prctl here: the driver's close() still stops the worker
            pass
        if os.getppid() != parent:  # the driver ended before that took effect
            os._exit(1)
    if initializer is not None:
        initializer()


class _Tracked:
    """A multiprocessing context remembering the processes it starts (the pool's workers, which
    ``concurrent.futures`` names only from Python 3.14, ``terminate_workers``): on Linux "fork",
    so that each worker is the driver's child (Python 3.14 made the forkserver the default, whose
    workers outlive a driver killed outright), elsewhere the platform's default."""

    def __init__(self):
        self._ctx = mp.get_context("fork" if sys.platform.startswith("linux") else None)
        self.processes: list = []

    def __getattr__(self, name: str) -> Any:
        return getattr(self._ctx, name)

    def Process(self, *args, **kwargs):  # (the context's own name)
        proc = self._ctx.Process(*args, **kwargs)
        self.processes.append(proc)
        return proc


class LocalExecutor:
    """Jobs in ``workers`` forked processes (each started by ``initializer``), or inline when
    ``workers`` is 1 (``fn`` is then looked up afresh by the caller: tests replace it)."""

    remote = False

    def __init__(self, workers: int = 2, initializer: Callable[[], None] | None = None):
        if workers < 1:
            raise ValueError(f"workers must be at least 1, got {workers}")
        self.workers, self.initializer = int(workers), initializer
        self._pool: cf.ProcessPoolExecutor | None = None
        self._context: _Tracked | None = None

    def share(self, obj: Any) -> Any:
        return obj

    def _ensure_pool(self) -> cf.ProcessPoolExecutor:
        if self._pool is None:
            self._context = _Tracked()
            forked = self._context.get_start_method() == "fork"
            self._pool = cf.ProcessPoolExecutor(max_workers=self.workers, mp_context=self._context,  # type: ignore[call-overload]
                                                initializer=_start_worker,
                                                initargs=(os.getpid() if forked else None, self.initializer))
        return self._pool

    def run(self, fn: Callable, jobs: list[Job]):
        """Yield ``(job, result, exception)`` per job as each finishes."""
        if self.workers == 1:
            for job in jobs:
                try:
                    yield job, fn(*job.args), None
                except Exception as e:  # noqa: BLE001 (any failure of a job is its result; Ctrl-C propagates)
                    yield job, None, e
            return
        pool = self._ensure_pool()
        futures = {pool.submit(fn, *job.args): job for job in jobs}
        for f in cf.as_completed(futures):
            e = f.exception()
            if isinstance(e, BrokenProcessPool):
                self._drop_pool()  # a worker died: this pool takes no more jobs, the next run starts one
            yield futures[f], (None if e else f.result()), e

    def _drop_pool(self, cancel: bool = False) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=not cancel, cancel_futures=True)
            if cancel and self._context is not None:  # the jobs in flight are dropped: end their workers
                for proc in self._context.processes:
                    if proc.is_alive():
                        proc.terminate()
                for proc in self._context.processes:
                    proc.join(timeout=5.0)
            self._pool, self._context = None, None

    def close(self, cancel: bool = False) -> None:
        """Stop the workers; ``cancel``: drop the queued jobs and terminate the workers of the
        ones in flight."""
        self._drop_pool(cancel)


class RayExecutor:
    """Jobs as Ray tasks of one CPU, on the cluster at ``address`` or on a local Ray with
    ``num_cpus`` CPUs started here (and stopped by ``close``)."""

    remote = True

    def __init__(self, address: str | None = None, num_cpus: int | None = None):
        require_ray(address)
        import ray

        from lfd.cli import UsageError
        self._ray = ray
        self._started = not ray.is_initialized()
        if self._started:
            kw: dict[str, Any] = {"include_dashboard": False, "log_to_driver": False, "configure_logging": False}
            try:
                if address:
                    ray.init(address=address, **kw)
                else:
                    ray.init(num_cpus=num_cpus, **kw)
            except (ConnectionError, RuntimeError, ValueError) as e:
                where = f"the Ray cluster at {address}" if address else "a local Ray"
                raise UsageError(f"--executor ray: cannot start or reach {where} ({job_error_line(e)})") from e

    def share(self, obj: Any) -> Any:
        return self._ray.put(obj)

    def run(self, fn: Callable, jobs: list[Job]):
        ray = self._ray
        task = ray.remote(num_cpus=1, max_retries=0)(fn)  # our own retry counts crashes and errors alike
        pending = {task.remote(*job.args): job for job in jobs}
        while pending:
            done, _ = ray.wait(list(pending), num_returns=1)
            ref = done[0]
            job = pending.pop(ref)
            try:
                yield job, ray.get(ref), None
            except Exception as e:  # noqa: BLE001 (RayTaskError: the job raised; or its worker died)
                yield job, None, e

    def close(self, cancel: bool = False) -> None:
        if self._started and self._ray.is_initialized():
            self._ray.shutdown()


def _check_reachable(address: str, timeout_s: float = 5.0) -> None:
    """``UsageError`` unless a TCP connection to ``address`` (``host:port``, optionally
    ``ray://host:port``; ``auto`` is left to Ray) opens within ``timeout_s``."""
    import socket

    from lfd.cli import UsageError
    if address == "auto":
        return
    host, _, port = address.removeprefix("ray://").rpartition(":")
    try:
        with socket.create_connection((host or "127.0.0.1", int(port)), timeout=timeout_s):
            pass
    except (OSError, ValueError) as e:
        raise UsageError(f"--address {address}: no Ray cluster answers there ({e}); start one with "
                         f"'ray start --head' and pass the address it prints") from None


def require_ray(address: str | None = None) -> None:
    """``UsageError`` naming the extra when Ray is not installed, or when nothing answers at
    ``address`` (``ray.init`` itself would retry an unreachable address for minutes)."""
    import importlib.util

    if importlib.util.find_spec("ray") is None:
        from lfd.cli import UsageError
        raise UsageError("--executor ray needs Ray: pip install 'lfd-landmarks[ray]'")
    if address:
        _check_reachable(address)


def make_executor(name: str, workers: int = 2, address: str | None = None,
                  initializer: Callable[[], None] | None = None):
    """``"local"`` (``workers`` processes) or ``"ray"`` (``address``, or a local Ray of ``workers`` CPUs)."""
    if name == "local":
        if address:
            raise ValueError("an address is for --executor ray")
        return LocalExecutor(workers, initializer)
    if name == "ray":
        return RayExecutor(address, None if address else workers)
    raise ValueError(f"unknown executor {name!r}; choose from {EXECUTORS}")


def run_jobs(fn: Callable, jobs: Iterable[Job], on_result: Callable[[Job, Any, str | None], None],
             executor, retries: int = 1) -> None:
    """Run every job on ``executor``; ``on_result(job, result, None)`` for each success and
    ``on_result(job, None, error)`` for a job that failed ``retries + 1`` times."""
    failures: dict = {}  # job key -> failures charged to it
    todo = list(jobs)

    def settle(job: Job, result, e, again: list) -> None:
        """Hand a success over; charge a failure to its job, to run again or to report."""
        if e is None:
            on_result(job, result, None)
            return
        failures[job.key] = failures.get(job.key, 0) + 1
        if failures[job.key] <= retries:
            again.append(job)
        else:
            on_result(job, None, job_error_line(e))

    try:
        while todo:
            again: list = []
            orphans = []
            for job, result, e in executor.run(fn, todo):
                if isinstance(e, BrokenProcessPool) and len(todo) > 1:
                    orphans.append(job)  # a worker died: which job killed it is not known yet
                else:
                    settle(job, result, e, again)
            for job in orphans:  # each alone, so that a worker that dies again is its job's fault
                for job_, result, e in executor.run(fn, [job]):
                    settle(job_, result, e, again)
            todo = again
    except BaseException:
        executor.close(cancel=True)
        raise
    executor.close()
