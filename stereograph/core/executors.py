"""Executors: where a node's tasks run -- here, in a process pool, or on a Dask cluster.

An executor maps a function over tasks and knows nothing of what the tasks do. A lost task
(a worker that died) comes back as :class:`TaskLost`. Public names: :class:`SerialExecutor`,
:class:`ProcessExecutor`, :class:`DaskExecutor`, :class:`TaskLost`, :func:`workers_executor`.
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import gc
import os
import signal
import uuid
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from stereograph.core.calls import TaskResult
from stereograph.core.errors import ConfigError
from stereograph.core.threads import ONE_THREAD, one_thread_each


def progress_advance(progress: Any, name: str, ok: bool = True) -> None:
    """One entry of ``name`` done on a progress display (stereograph.app.progress); a failed one is
    said first to a display that counts them (``item_failed`` is optional)."""
    if not ok and hasattr(progress, "item_failed"):
        progress.item_failed(name)
    progress.advance(name)


@dataclass
class TaskLost:
    """A task whose worker died (killed, out of memory) or whose cluster failed: not the node's
    fault."""

    error: str
    hint: str = (
        "a worker ran out of memory or was killed: run again (finished items are cached), "
        "with fewer --workers or more memory per worker"
    )

    def as_result(self) -> TaskResult:
        return TaskResult(False, error=self.error, hint=self.hint)


def lost_as_failed(results: Iterable[Any]) -> Iterable[TaskResult]:
    return (r.as_result() if isinstance(r, TaskLost) else r for r in results)


class SerialExecutor:
    """Runs tasks one after another in this process, each when the caller asks for its result.

    Every executor has ``workers`` (how many tasks run at once) and ``remote`` (whether tasks run
    in another process, so must be picklable), ``map`` and ``close``."""

    workers = 1
    remote = False

    def map(self, fn: Callable[[Any], Any], tasks: list[Any]) -> Iterable[Any]:
        return (fn(t) for t in tasks)

    def close(self, now: bool = False) -> None:
        pass


def _worker_start() -> None:
    """A pool worker's set-up: one thread per library pool (below), and Ctrl-C left to the process
    that owns the pool. A terminal's Ctrl-C reaches every process of its group: a worker waiting for
    its next task printed a KeyboardInterrupt traceback; the owner ends its workers itself
    (close(now=True))."""
    one_thread_each()
    signal.signal(signal.SIGINT, signal.SIG_IGN)


# Libraries' own thread pools run one thread each in a worker: the processes are the
# parallelism (docs/parallel.md, "What runs where").
class ProcessExecutor:
    """Runs tasks in a pool of worker processes (results in order).

    A worker that dies (killed, out of memory) breaks Python's pool; the tasks then unfinished
    are run again one at a time in a fresh pool, so that a task which kills its worker every
    time comes back alone as :class:`TaskLost` and the others finish.
    """

    remote = True

    def __init__(self, workers: int):
        self.workers = workers
        self.pool = cf.ProcessPoolExecutor(max_workers=workers, initializer=_worker_start)
        self._forked = False  # whether this pool has started its processes
        self._froze = False
        self._ended = False  # closed at once (Ctrl-C): no pool is started again

    def _submit(self, fn: Callable[[Any], Any], task: Any) -> cf.Future:
        # (a thread still handing tasks over, compare's variants: each is lost at once)
        if self._ended:
            raise cf.process.BrokenProcessPool("the run was interrupted")
        if not self._forked:
            # Before the pool forks: objects alive now out of the cyclic collector's reach, or a
            # collection in a worker copies every page holding one (docs/parallel.md).
            gc.freeze()
            self._froze = self._forked = True
        return self.pool.submit(fn, task)

    def map(self, fn: Callable[[Any], Any], tasks: list[Any]) -> Iterable[Any]:
        tasks = list(tasks)
        try:
            futures = [self._submit(fn, t) for t in tasks]
        except cf.process.BrokenProcessPool:  # broken by an earlier task (one made ahead, say)
            return self._alone(fn, tasks)
        return self._results(fn, tasks, futures)

    def start(self, fn: Callable[[Any], Any], tasks: list[Any]) -> list[cf.Future]:
        """Submit tasks now, to run while this process goes on with other work (see
        :func:`stereograph.core.ahead.start_ahead`); :meth:`stop` cancels those not begun."""
        futures: list[cf.Future] = []
        try:
            for t in tasks:
                futures.append(self._submit(fn, t))
        except cf.process.BrokenProcessPool:
            self._restart()
        return futures

    def stop(self, futures: list[cf.Future]) -> None:
        for fut in futures:
            fut.cancel()
        cf.wait(futures)
        if any(
            not f.cancelled() and isinstance(f.exception(), cf.process.BrokenProcessPool)
            for f in futures
        ):
            self._restart()  # a worker died making items ahead: their region tasks make them again

    def _results(
        self, fn: Callable[[Any], Any], tasks: list[Any], futures: list[cf.Future]
    ) -> Iterable[Any]:
        for k, fut in enumerate(futures):
            try:
                yield fut.result()
            except cf.process.BrokenProcessPool:
                yield from self._alone(fn, tasks[k:])
                return

    def _alone(self, fn: Callable[[Any], Any], tasks: list[Any]) -> Iterable[Any]:
        self._restart()
        for t in tasks:
            try:
                yield self._submit(fn, t).result()
            except cf.process.BrokenProcessPool as e:
                yield TaskLost(f"its worker process died ({type(e).__name__})")
                self._restart()

    def _restart(self) -> None:
        if self._ended:
            return
        self.pool.shutdown(wait=False, cancel_futures=True)
        self.pool = cf.ProcessPoolExecutor(max_workers=self.workers, initializer=_worker_start)
        self._forked = False

    def close(self, now: bool = False) -> None:
        """Wait for the workers to end; ``now`` (Ctrl-C, SIGTERM): cancel what is queued and end the
        workers at once -- their tasks would otherwise go on for as long as the queue lasts."""
        if self._froze:
            gc.unfreeze()
            self._froze = False
        if not now:
            self.pool.shutdown()
            return
        self._ended = True
        processes = list((getattr(self.pool, "_processes", None) or {}).values())
        self.pool.shutdown(wait=False, cancel_futures=True)
        for proc in processes:
            with contextlib.suppress(Exception):
                proc.terminate()
        for proc in processes:
            with contextlib.suppress(Exception):
                proc.join(timeout=5)


class DaskExecutor:
    """Runs item tasks on a Dask cluster (``pip install -e '.[dask]'``).

    Parameters
    ----------
    address : str, optional
        A running scheduler (``tcp://host:8786``); default: a local cluster of ``workers``
        processes.
    """

    remote = True

    def __init__(self, address: str | None = None, workers: int = 2):
        try:
            from distributed import Client, LocalCluster
        except ImportError:
            raise ConfigError(
                "the Dask executor needs the 'dask' extra",
                hint="pip install -e '.[dask]', or use --workers N for a local process pool",
            ) from None
        # One library thread per worker process, as in the process pool (see ONE_THREAD).
        self.cluster = None if address else _local_cluster(LocalCluster, workers)
        self.client = Client(address or self.cluster)
        self.workers = max(1, len(self.client.scheduler_info().get("workers", {})) or workers)

    def map(self, fn: Callable[[Any], Any], tasks: list[Any]) -> Iterable[Any]:
        # pure=False: two equal tasks are two calls (the cache, not Dask, deduplicates). A worker
        # killed mid-task has its task run again elsewhere (Dask's allowed-failures); a task that
        # keeps killing workers comes back as TaskLost, alone.
        futures = self.client.map(fn, list(tasks), pure=False)
        for fut in futures:
            try:
                yield fut.result()
            except Exception as e:  # KilledWorker, a lost connection: not the node's fault
                yield TaskLost(
                    f"the Dask cluster lost it ({type(e).__name__}: {e})",
                    "a worker died or the cluster failed: run again (finished items are cached)",
                )

    def check_shared(self, folders: list[Path]) -> None:
        """Refuse a cluster whose workers do not see ``folders`` (the cache and the run folder).

        Workers read the cache and write items' files there themselves, so they must be on storage
        every worker sees (one machine, or a network file system mounted at the same path)."""
        token = uuid.uuid4().hex
        probes = []
        for d in folders:
            p = d / f".stereograph-probe-{token}"
            try:
                d.mkdir(parents=True, exist_ok=True)
                p.write_text(token)
            except OSError:
                continue  # a read-only cache: nothing to probe with (the workers only read it)
            probes.append(str(p))
        try:
            seen = self.client.run(_sees, probes, token)
        finally:
            for p in probes:
                Path(p).unlink(missing_ok=True)
        blind = sorted(w for w, ok in seen.items() if not ok)
        if blind:
            raise ConfigError(
                f"Dask workers {', '.join(blind[:3])} do not see this run's cache and run folder "
                f"({', '.join(str(d) for d in folders)})",
                hint="put --cache-dir and --out on storage every worker mounts at the same path "
                "(a network file system), or use --dask local / --workers N",
            )

    def close(self, now: bool = False) -> None:
        self.client.close()
        if self.cluster is not None:
            self.cluster.close()


def _local_cluster(LocalCluster: Any, workers: int) -> Any:
    """A LocalCluster of ``workers`` processes with one thread each (and one library thread, as
    the process pool: ONE_THREAD), without Dask's shipped ``MALLOC_TRIM_THRESHOLD_`` (it made
    image-sized arrays page-fault again: docs/parallel.md, "Dask")."""
    import dask

    key = "distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_"
    drop = {key: None} if dask.config.get(key, None) in (65536, "65536") else {}
    with dask.config.set(drop):
        return LocalCluster(
            n_workers=workers,
            threads_per_worker=1,
            processes=True,
            dashboard_address=":0",  # (a free port: two runs at once do not fight over 8787)
            env={k: os.environ.get(k, v) for k, v in ONE_THREAD.items()},
        )


def _sees(paths: list[str], token: str) -> bool:
    """(On a Dask worker) whether every probe file is there with our token."""
    try:
        return all(Path(p).read_text() == token for p in paths)
    except OSError:
        return False


def workers_executor(workers: int | None, dask: str | None = None) -> Any:
    """The executor for ``--workers N`` (1 or None: serial) or ``--dask [ADDRESS|local]``."""
    if dask:
        return DaskExecutor(None if dask == "local" else dask, max(workers or 2, 1))
    if not workers or workers <= 1:
        return SerialExecutor()
    return ProcessExecutor(min(workers, os.cpu_count() or 1))
