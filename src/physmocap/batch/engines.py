"""Where the runs of a batch execute: a local process pool (the default, nothing to set up) or Ray (a local
instance, or an existing cluster). Both take `BatchTask`s and hand back (task, record) pairs as runs finish:

    engine.submit(task); engine.wait(timeout) -> [(task, record), ...]; engine.stop() on Ctrl-C; engine.close()

A worker that dies (killed for memory, a crash inside a native library) costs its run a retry, up to
`max_retries`; after that the input is recorded as failed and the batch goes on.
"""

from __future__ import annotations

import collections
import concurrent.futures
import logging
import multiprocessing
import os
import signal
import socket
from concurrent.futures.process import BrokenProcessPool

from .task import THREAD_ENV, BatchTask, capture_one, failed_record, limit_threads

MAX_RETRIES = 2  # a run whose worker died is tried this many more times
STOP_GRACE_SECONDS = 10.0  # after Ctrl-C, how long a worker may take to unwind its run before it is killed
# A Ray worker runs some twenty threads of Ray's own; glibc's malloc gives threads arenas of their own, and the
# worker's peak memory grew from run to run with them (docs/decisions/batch-ray-overhead.md, "Memory").
RAY_WORKER_ENV = THREAD_ENV | {"MALLOC_ARENA_MAX": "2"}


def _pool_worker_init() -> None:
    # Ctrl-C reaches the whole terminal's process group; only the parent acts on it and stops the workers.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    limit_threads()


class ProcessPoolEngine:
    """`workers` spawned processes (spawn: MediaPipe's and OpenCV's threads do not survive a fork), each running
    one input at a time. At most `workers` runs are handed to the pool at once, so a pool broken by a dying
    worker tells exactly which runs it took down."""

    def __init__(self, workers: int, max_retries: int = MAX_RETRIES):
        os.environ.update(THREAD_ENV)  # spawned workers inherit it before they load numpy
        self.workers = workers
        self.max_retries = max_retries
        self._executor = self._new_executor()
        self._queue: collections.deque[BatchTask] = collections.deque()
        self._running: dict[concurrent.futures.Future, BatchTask] = {}
        self._deaths: collections.Counter[str] = collections.Counter()

    def _new_executor(self) -> concurrent.futures.ProcessPoolExecutor:
        return concurrent.futures.ProcessPoolExecutor(self.workers, multiprocessing.get_context("spawn"),
                                                      initializer=_pool_worker_init)

    def submit(self, task: BatchTask) -> None:
        self._queue.append(task)
        self._fill()

    def _fill(self) -> None:
        while self._queue and len(self._running) < self.workers:
            task = self._queue.popleft()
            self._running[self._executor.submit(capture_one, task)] = task

    def unfinished(self) -> int:
        return len(self._queue) + len(self._running)

    def wait(self, timeout: float) -> list[tuple[BatchTask, dict]]:
        if not self._running:
            return []
        done, _ = concurrent.futures.wait(self._running, timeout, concurrent.futures.FIRST_COMPLETED)
        finished, lost = [], []
        for future in done:
            task = self._running.pop(future)
            try:
                finished.append((task, future.result()))
            except BrokenProcessPool:
                lost.append(task)
        if lost:
            finished += self._retry(lost)
        self._fill()
        return finished

    def _retry(self, lost: list[BatchTask]) -> list[tuple[BatchTask, dict]]:
        """A worker died and took the pool down: a new pool, the lost runs queued first again, or failed."""
        self._executor.shutdown(wait=False, cancel_futures=True)
        self._executor = self._new_executor()
        given_up = []
        for task in reversed(lost):
            self._deaths[task.name] += 1
            if self._deaths[task.name] > self.max_retries:
                reason = (f"the worker process running it died {self._deaths[task.name]} times (killed for memory, "
                          "or a crash inside a native library).")
                given_up.append((task, failed_record(task, 1, reason, 0.0)))
            else:
                self._queue.appendleft(task)
        return given_up

    def stop(self) -> None:
        """Ctrl-C: no new runs; the running ones are unwound (SIGTERM: atomic writes remove their temporary
        files), then killed if they take longer than STOP_GRACE_SECONDS."""
        self._queue.clear()
        workers = multiprocessing.active_children()
        self._executor.shutdown(wait=False, cancel_futures=True)
        for process in workers:
            process.terminate()
        for process in workers:
            process.join(STOP_GRACE_SECONDS)
            if process.is_alive():
                process.kill()
        self._running.clear()

    def close(self) -> None:
        self._executor.shutdown(wait=True)


CLUSTER_CONNECT_TIMEOUT = 10.0  # s: a cluster's address must answer within this (Ray itself retries for minutes)


def _check_reachable(address: str) -> None:
    """ConnectionError unless host:port (or ray://host:port) accepts a TCP connection in CLUSTER_CONNECT_TIMEOUT."""
    host, _, port = address.split("://")[-1].rpartition(":")
    if not port.isdigit():
        raise ValueError(f"{address} has no port number")
    try:
        with socket.create_connection((host, int(port)), timeout=CLUSTER_CONNECT_TIMEOUT):
            pass
    except OSError as exc:
        raise ConnectionError(f"nothing answers there within {CLUSTER_CONNECT_TIMEOUT:g} s: {exc}") from None


class RayEngine:
    """Each input a Ray task needing one CPU, retried `max_retries` times when its worker dies. `address` None
    starts a local Ray with `workers` CPUs (stopped by close()); "auto" or host:port joins a running cluster, whose
    CPUs then decide how many run at once. Every worker must see the inputs and the output folder at the same
    paths (a shared file system)."""

    def __init__(self, address: str | None, workers: int, max_retries: int = MAX_RETRIES):
        import ray

        self._ray = ray
        self._local_node = None
        if address is None:
            self._local_node = _start_local_ray(workers)
            ray.init(address=self._local_node.address, log_to_driver=False, logging_level=logging.WARNING)
        else:  # a cluster's other nodes start their workers from their own environment
            if address != "auto":
                _check_reachable(address)
            ray.init(address=address, runtime_env={"env_vars": RAY_WORKER_ENV}, include_dashboard=False,
                     log_to_driver=False, logging_level=logging.WARNING)
        self._remote = ray.remote(capture_one).options(num_cpus=1, max_retries=max_retries, retry_exceptions=False)
        self._running: dict = {}

    def cluster_cpus(self) -> int:
        return int(self._ray.cluster_resources().get("CPU", 0))

    def submit(self, task: BatchTask) -> None:
        self._running[self._remote.remote(task)] = task

    def unfinished(self) -> int:
        return len(self._running)

    def wait(self, timeout: float) -> list[tuple[BatchTask, dict]]:
        ray = self._ray
        if not self._running:
            return []
        ready, rest = ray.wait(list(self._running), num_returns=1, timeout=timeout)
        if ready and rest:
            more, _ = ray.wait(rest, num_returns=len(rest), timeout=0)
            ready += more
        finished = []
        for ref in ready:
            task = self._running.pop(ref)
            try:
                finished.append((task, ray.get(ref)))
            except ray.exceptions.RayError as exc:  # the worker or its node died more often than retried
                reason = f"the Ray task failed: {_first_line(exc)}"
                finished.append((task, failed_record(task, 1, reason, 0.0)))
        return finished

    def stop(self) -> None:
        """Ctrl-C: cancel every task (a running one gets KeyboardInterrupt and unwinds, its atomic writes leaving
        no partial file), wait up to STOP_GRACE_SECONDS, then shut a local Ray down."""
        ray = self._ray
        refs = list(self._running)
        for ref in refs:
            ray.cancel(ref)
        if refs:
            ray.wait(refs, num_returns=len(refs), timeout=STOP_GRACE_SECONDS)
        self._running.clear()
        self.close()

    def close(self) -> None:
        if self._ray.is_initialized():
            self._ray.shutdown()
        if self._local_node is not None:
            self._local_node.kill_all_processes(check_alive=False, allow_graceful=True, wait=True)
            self._local_node = None


def _start_local_ray(cpus: int):
    """A local Ray head of `cpus` CPUs without the log monitor (only streams worker output, which the batch does
    not show) and the autoscaler monitor (nothing to scale on one machine): together about a fifth of Ray's own
    start-up CPU, taken from the captures when every core runs one (docs/decisions/batch-ray-overhead.md).
    ray.init cannot leave them out; Ray's own test clusters (ray.cluster_utils) start a node this way. The reaper
    process it spawns stops the node should this process die without close()."""
    from ray._private.node import Node
    from ray._private.parameter import RayParams

    # Its daemons and workers inherit this environment: no runtime_env, which would start more workers.
    os.environ.update(RAY_WORKER_ENV)
    params = RayParams(num_cpus=cpus, include_dashboard=False, no_monitor=True,
                       include_log_monitor=False)  # type: ignore[arg-type]  # a flag Ray annotates as str
    return Node(params, head=True, shutdown_at_exit=True, spawn_reaper=True, ray_init_cluster=True)


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return text[0] if text else type(exc).__name__
