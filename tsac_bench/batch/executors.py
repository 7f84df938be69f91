"""Where jobs run: a pool of local worker processes, or a dask.distributed cluster.

Both take job specs and yield ``(spec, result)`` pairs as jobs finish, in whatever order they
finish; both run every job through ``worker.execute_job``, so the same seeds give the same
results. Each job runs in a process that can be killed: a hung job is killed at its hard
timeout and a crashed one (segfault, ``os._exit``) is recorded; the batch goes on.
"""

from __future__ import annotations

import multiprocessing
import os
import time
from collections.abc import Iterable, Iterator
from multiprocessing.connection import Connection, wait
from typing import Any

from tsac_bench.batch.records import JobResult, JobSpec
from tsac_bench.batch.worker import (
    execute_job,
    failure,
    hard_timeout,
    kill_group,
    run_in_subprocess,
)


def _serve(conn: Connection, log: str | None) -> None:
    """A worker process's loop: one job in, one result out, until the driver goes away.

    The worker leads its own process group, so that killing a hung job also kills the
    processes its solver started (a CP-SAT or HiGHS helper process). What solvers print goes
    to ``log``, not over the driver's progress bar."""
    if hasattr(os, "setsid"):
        os.setsid()
    if log is not None:
        with open(log, "ab") as sink:
            os.dup2(sink.fileno(), 1)
            os.dup2(sink.fileno(), 2)
    while True:
        try:
            spec = conn.recv()
        except (EOFError, OSError):
            return
        conn.send(execute_job(spec))


class _Worker:
    """One long-lived worker process, so that heavy imports (torch, Pyomo) happen once."""

    def __init__(self, context: Any, log: str | None) -> None:
        self.conn, child = context.Pipe()
        # Not a daemon: a daemonic process may not start the solver processes some methods use.
        self.process = context.Process(target=_serve, args=(child, log))
        self.process.start()
        child.close()
        self.spec: JobSpec | None = None
        self.deadline = float("inf")

    def start(self, spec: JobSpec) -> None:
        self.spec = spec
        timeout = hard_timeout(spec)
        self.deadline = float("inf") if timeout is None else time.monotonic() + timeout
        self.conn.send(spec)

    def kill(self) -> None:
        kill_group(self.process.pid)
        self.process.join()
        self.conn.close()

    def stop(self) -> None:
        self.conn.close()  # the worker reads EOF and returns
        self.process.join(timeout=5)
        if self.process.is_alive():
            self.kill()


def _context() -> Any:
    # forkserver: workers start from a clean process (no driver threads copied by fork);
    # spawn where the platform has no forkserver.
    methods = multiprocessing.get_all_start_methods()
    context = multiprocessing.get_context("forkserver" if "forkserver" in methods else "spawn")
    if "forkserver" in methods:
        context.set_forkserver_preload(["tsac_bench.batch.worker"])
    return context


def run_local(specs: Iterable[JobSpec], jobs: int,
              log: str | os.PathLike[str] | None = None) -> Iterator[tuple[JobSpec, JobResult]]:
    """Run the jobs on ``jobs`` local worker processes; their output is appended to ``log``
    (inherited from the driver when None)."""
    log = None if log is None else os.fspath(log)
    queue = list(specs)
    queue.reverse()  # pop() from the end keeps the given order
    context = _context()
    workers = [_Worker(context, log) for _ in range(min(jobs, len(queue)))]
    try:
        while True:
            for worker in workers:
                if worker.spec is None and queue:
                    worker.start(queue.pop())
            busy = [w for w in workers if w.spec is not None]
            if not busy:
                return
            timeout = max(0.0, min(w.deadline for w in busy) - time.monotonic())
            wait([w.conn for w in busy] + [w.process.sentinel for w in busy],
                 timeout=min(timeout, 3600.0))
            for i, worker in enumerate(workers):
                if worker.spec is None:
                    continue
                result = _collect(worker)
                if result is None:
                    continue
                spec, worker.spec = worker.spec, None
                if result["status"] in ("timeout", "crash"):
                    workers[i] = _Worker(context, log)
                yield spec, result
    finally:
        for worker in workers:
            if worker.spec is None:
                worker.stop()
            else:
                worker.kill()


def _collect(worker: _Worker) -> JobResult | None:
    """The worker's result if its job has ended (finished, crashed or timed out), else None."""
    assert worker.spec is not None
    if worker.conn.poll():
        try:
            return worker.conn.recv()
        except (EOFError, OSError):
            pass  # the process died (mid-send or before): a crash
        worker.kill()
        return failure("crash", f"worker process exited with code {worker.process.exitcode}")
    if not worker.process.is_alive():
        worker.kill()
        return failure("crash", f"worker process exited with code {worker.process.exitcode}")
    if time.monotonic() >= worker.deadline:
        worker.kill()
        return failure("timeout", f"killed after {hard_timeout(worker.spec):g} s (time limit "
                                  f"{worker.spec.get('time_limit')} s)")
    return None


def run_dask(specs: Iterable[JobSpec], jobs: int,
             scheduler: str | None = None) -> Iterator[tuple[JobSpec, JobResult]]:
    """Run the jobs on a dask.distributed cluster: the one at ``scheduler``, or a LocalCluster
    of ``jobs`` single-threaded worker processes. Each job runs in a child process of its Dask
    worker (``worker.run_in_subprocess``) so that a hung job can be killed."""
    from distributed import Client, LocalCluster, as_completed

    specs = list(specs)
    if not specs:
        return
    cluster = None
    if scheduler is None:
        cluster = LocalCluster(n_workers=jobs, threads_per_worker=1, processes=True,
                               dashboard_address=None)
    client = Client(scheduler or cluster)
    try:
        # pure=False: the same spec twice (a resumed job) must run again, not hit a cache.
        futures = {client.submit(run_in_subprocess, spec, pure=False): spec for spec in specs}
        for future in as_completed(futures):
            spec = futures.pop(future)
            if future.status == "finished":
                yield spec, future.result()
            else:
                error = future.exception()
                yield spec, failure("crash", f"dask: {type(error).__name__}: {error}")
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
