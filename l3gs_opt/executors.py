"""Running independent tasks: here, in forked processes, or on a Dask cluster (one mechanism for
``bench`` and ``experiments``).

:func:`run_tasks` calls ``work(task)`` for every task and hands each result to ``write(task,
result)`` in this process, as soon as it is ready (so the caller's record file grows as tasks
finish and an interrupted run loses only the tasks in flight):

* ``jobs=0``: in this process, one after another (no time limit enforced);
* ``executor="local"``: up to ``jobs`` forked processes at a time, each task in its own, killed
  once it outlives ``hard_limit_s``; each is told its share of the cores (:func:`usable_cores`:
  e.g. how many HiGHS runs :mod:`l3gs_opt.models.backends.highs_race` races);
* ``executor="dask"``: on a Dask cluster (a local one with ``jobs`` threads by default, or the
  scheduler at ``address``), each task again in its own forked, killable process.

A task whose process is killed or dies gives ``failed(task, seconds, why)`` (``why``: ``killed``
or ``died``) as its result.

``start_method``: ``fork`` (default; ``work`` may be any callable) or ``spawn`` (a fresh
interpreter per task; ``work`` and the tasks must pickle). Use ``spawn`` when this process has
run compiled parallel code (numba, torch) before: a forked child of a process whose thread pools
are running can hang in them. (HiGHS's pool needs no spawn: the HiGHS adapter drops it in every
forked child, :mod:`l3gs_opt.models.backends.highs`.)
"""

from __future__ import annotations

import multiprocessing as mp
import os
import time
from typing import Any, Callable, Sequence

from l3gs_opt import stop
from l3gs_opt.errors import L3gsError

__all__ = ["EXECUTORS", "WORKER_CORES_ENV", "ExecutorError", "check_executor", "run_tasks", "run_guarded", "usable_cores"]

EXECUTORS = ("local", "dask")
#: Environment variable holding a local worker's share of the cores (set in each worker).
WORKER_CORES_ENV = "L3GS_WORKER_CORES"


def usable_cores() -> int:
    """Cores this process may use: its share of a local worker pool (:data:`WORKER_CORES_ENV`,
    when it is a positive integer), else the cores it may run on."""
    env = os.environ.get(WORKER_CORES_ENV, "")
    if env.isdigit() and int(env) > 0:
        return int(env)
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:   # (not on Linux)
        return os.cpu_count() or 1


class ExecutorError(L3gsError, ValueError):
    """A bad executor request (names the option)."""


def _fork_worker(conn: Any, work: Callable[[Any], Any], task: Any, cores: int | None = None) -> None:
    if cores is not None:   # this worker's share (solvers that run threads size them by it)
        os.environ[WORKER_CORES_ENV] = str(cores)
    try:
        conn.send(work(task))
    finally:
        conn.close()


def run_guarded(work: Callable[[Any], Any], task: Any, hard_limit_s: float | None,
                failed: Callable[[Any, float, str], Any], start_method: str = "fork") -> Any:
    """``work(task)`` in a child process killed past ``hard_limit_s`` seconds (what Dask workers run)."""
    ctx = mp.get_context(start_method)
    parent, child = ctx.Pipe(duplex=False)
    proc = ctx.Process(target=_fork_worker, args=(child, work, task))
    started = time.perf_counter()
    with stop.noted_interrupts() as interrupted:
        proc.start()
    child.close()
    try:
        interrupted()
        if parent.poll(hard_limit_s):
            try:
                return parent.recv()
            except EOFError:
                return failed(task, time.perf_counter() - started, "died")
        return failed(task, time.perf_counter() - started, "killed")
    finally:
        if proc.is_alive():
            proc.kill()
        proc.join()


def check_executor(executor: str, jobs: int, address: str | None = None) -> None:
    """Refuse a bad executor request before any work (the CLIs call it before building a plan):
    an unknown executor, ``jobs`` not an integer >= 0, or an ``address`` that is empty, given to
    the local executor (where it would be ignored), or not a Dask scheduler address
    (``[tcp://]host:port``, or another scheme Dask knows).

    Raises
    ------
    ExecutorError
        Naming ``executor``, ``jobs`` or ``address``.
    """
    if executor not in EXECUTORS:
        raise ExecutorError(f"executor {executor!r} is not one of {', '.join(EXECUTORS)}")
    if isinstance(jobs, bool) or not isinstance(jobs, int) or jobs < 0:
        raise ExecutorError(f"jobs = {jobs!r}: must be an integer >= 0")
    if address is None:
        return
    if executor != "dask":
        raise ExecutorError(f"address {address!r}: only the dask executor uses a scheduler address")
    if not address.strip():
        raise ExecutorError("address '': empty (leave it out for a local Dask cluster)")
    try:
        from distributed.comm.addressing import parse_address, parse_host_port
        from distributed.comm.registry import get_backend
    except ImportError:
        return   # (the dask executor itself says what to install)
    try:   # Dask's own parsers: what they refuse here would be a traceback from Client() later
        scheme, location = parse_address(address)
        get_backend(scheme)
        if scheme in ("tcp", "tls"):
            _, port = parse_host_port(location)
            if not 0 < int(port) < 65536:
                raise ValueError(f"port {port} is not in 1..65535")
    except (ValueError, TypeError) as exc:
        raise ExecutorError(f"address {address!r}: not a Dask scheduler address ({exc}; e.g. "
                            "tcp://127.0.0.1:8786)") from None


def run_tasks(todo: Sequence[Any], work: Callable[[Any], Any], write: Callable[[Any, Any], None], *,
              jobs: int = 1, executor: str = "local", address: str | None = None,
              hard_limit_s: float | None = None, failed: Callable[[Any, float, str], Any],
              start_method: str = "fork") -> None:
    """Run ``work`` on every task of ``todo``; ``write(task, result)`` each result here, as it comes
    (see the module doc). ``work`` and ``failed`` must be picklable for a remote Dask cluster.

    Raises
    ------
    ExecutorError
        A request :func:`check_executor` refuses, or ``dask`` without the ``distributed`` package.
    """
    check_executor(executor, jobs, address)
    if start_method not in ("fork", "spawn"):
        raise ExecutorError(f"start_method {start_method!r} is not one of fork, spawn")
    if jobs == 0:
        for task in todo:
            write(task, work(task))
    elif executor == "local":
        _run_local(list(todo), work, write, jobs, hard_limit_s, failed, start_method)
    else:
        _run_dask(list(todo), work, write, jobs, address, hard_limit_s, failed, start_method)


def _run_local(todo: list, work: Callable, write: Callable, jobs: int, limit: float | None,
               failed: Callable, start_method: str) -> None:
    ctx = mp.get_context(start_method)
    share = max(1, usable_cores() // jobs)
    running: list[tuple[Any, Any, Any, float]] = []
    queue = list(todo)
    with stop.noted_interrupts() as interrupted:
        try:
            while queue or running:
                while queue and len(running) < jobs:
                    task = queue.pop(0)
                    parent, child = ctx.Pipe(duplex=False)
                    proc = ctx.Process(target=_fork_worker, args=(child, work, task, share))
                    proc.start()
                    child.close()
                    running.append((task, proc, parent, time.perf_counter()))
                    interrupted()   # a Ctrl-C that landed in the fork (see l3gs_opt.stop)
                still = []
                for task, proc, conn, started in running:
                    elapsed = time.perf_counter() - started
                    if conn.poll():
                        try:
                            result = conn.recv()
                        except EOFError:
                            result = failed(task, elapsed, "died")
                        proc.join()
                        write(task, result)
                    elif not proc.is_alive():
                        proc.join()
                        write(task, failed(task, elapsed, "died"))
                    elif limit is not None and elapsed > limit:
                        proc.kill()
                        proc.join()
                        write(task, failed(task, elapsed, "killed"))
                    else:
                        still.append((task, proc, conn, started))
                running = still
                if running:
                    time.sleep(0.01)
        finally:
            for _, proc, _, _ in running:  # interrupted: stop the children, keep what was written
                proc.kill()
                proc.join()


def _run_dask(todo: list, work: Callable, write: Callable, jobs: int, address: str | None,
              limit: float | None, failed: Callable, start_method: str) -> None:
    try:
        from dask.distributed import Client, LocalCluster, as_completed
    except ImportError:
        raise ExecutorError("executor 'dask' needs the package 'distributed' (pip install 'l3gs-opt[dask]')") from None
    cluster = None
    if address:
        client = Client(address)
    else:
        # Threads, not processes: each task already runs in its own killable child process, and
        # daemonic Dask worker processes may not start children.
        cluster = LocalCluster(n_workers=1, threads_per_worker=max(1, jobs), processes=False,
                               dashboard_address=None)
        client = Client(cluster)
    try:
        futures = {client.submit(run_guarded, work, task, limit, failed, start_method, pure=False): task
                   for task in todo}
        for future in as_completed(futures):
            write(futures[future], future.result())
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
