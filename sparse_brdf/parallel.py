"""Where work runs: the package's thread pool, BLAS threads, and Dask clusters.

The only module that starts threads or worker processes (``tests/test_architecture.py``
checks it). Two levels:

- **Within a process**, :func:`parallel_map` maps small numpy tasks (one tensor, one
  (channel, dictionary) pair) over one shared pool of :func:`n_threads` threads with BLAS
  held to one thread per task (:func:`blas_single_thread`): measured here (2 cores,
  float32, 90x90x180) 3.5x faster than letting OpenBLAS thread each small mode product.
- **Across processes**, batch encoding, the bench and the trainer hand their independent
  pieces of work to an executor from :func:`executor`:

- neither ``workers`` nor ``scheduler``: :class:`InProcess`, which runs each piece here,
  one after another, in input order (each piece may still use the thread pool,
  :func:`parallel_map`);
- ``workers=N``: a local Dask cluster of N worker processes (one thread each), started
  here and closed on leaving the ``with`` block;
- ``scheduler=ADDRESS``: the workers of an existing Dask cluster (``tcp://host:8786``).

Both executors offer the same calls: :meth:`~InProcess.map` (results in input order),
:meth:`~InProcess.as_completed` (``(index, result)`` pairs as pieces finish, for progress
bars and saving as results arrive), :meth:`~InProcess.scatter` (a large object every
piece reads -- an ensemble's dictionaries -- sent once to each worker rather than once
per piece), and :meth:`~InProcess.place` / :meth:`~InProcess.run_on` (objects that stay
on one worker across many calls: the trainer's shards of tensors).

Dask is imported only when a cluster is asked for: ``import sparse_brdf``, the CLI's
``--help`` and every in-process run never load it. The Dask executor counts the bytes
it sends and receives (``stats``), measured with ``dask.sizeof``.
"""

from __future__ import annotations

import contextlib
import logging
import os
import threading
from collections.abc import Callable, Iterable, Iterator, Sequence
from concurrent.futures import CancelledError, ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any, TypeVar

from threadpoolctl import ThreadpoolController

from .errors import UsageError, WorkerLostError

#: The Dask executor's byte counters (``Executor.stats``).
STAT_KEYS = ("bytes_scattered", "bytes_sent", "bytes_received", "tasks")

T = TypeVar("T")
R = TypeVar("R")


def usable_cores() -> int:
    """Cores this process may run on."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return os.cpu_count() or 1


def n_threads() -> int:
    """Threads of the pool: ``$SPARSE_BRDF_THREADS`` or the number of usable cores."""
    env = os.environ.get("SPARSE_BRDF_THREADS")
    if env:
        return max(1, int(env))
    return usable_cores()


# ------------------------------------------------------------------ the thread pool
# One pool of worker threads and one BLAS controller per process, made on first use: an
# encode runs about 400 small maps, and a new pool plus a fresh scan of the loaded BLAS
# libraries per map cost 0.18 s of a 2 s encode (2 cores, measured 2026-12-02).
_POOL: ThreadPoolExecutor | None = None
_POOL_KEY: tuple[int, int] = (0, 0)  # (process id, workers) the pool was made for
_POOL_LOCK = threading.Lock()
_CONTROLLER: ThreadpoolController | None = None
_IN_WORKER = threading.local()


def _pool(workers: int) -> ThreadPoolExecutor:
    """The shared pool of ``workers`` threads (a new one after a fork or a new count)."""
    global _POOL, _POOL_KEY
    with _POOL_LOCK:
        if _POOL is None or _POOL_KEY != (os.getpid(), workers):
            _POOL = ThreadPoolExecutor(workers, thread_name_prefix="sparse-brdf")
            _POOL_KEY = (os.getpid(), workers)
        return _POOL


def _stop_pool() -> None:
    """Shut the shared pool down without waiting, its queued tasks cancelled; the next
    map makes a new one. Shutting down wakes every idle worker thread to exit, also one
    that an interrupt left unregistered with ``concurrent.futures`` (a KeyboardInterrupt
    inside ``ThreadPoolExecutor``'s thread start, after the thread runs and before it is
    recorded for the exit): nothing else would wake that thread, and the interpreter's
    exit would wait on it forever."""
    global _POOL
    with _POOL_LOCK:
        pool, _POOL = _POOL, None
    if pool is not None:
        pool.shutdown(wait=False, cancel_futures=True)


def blas_single_thread() -> contextlib.AbstractContextManager:
    """A context holding BLAS to one thread in this process (the controller, a scan of
    the loaded BLAS libraries, is built once)."""
    global _CONTROLLER
    if _CONTROLLER is None:
        _CONTROLLER = ThreadpoolController()
    return _CONTROLLER.limit(limits=1, user_api="blas")


def parallel_map(fn: Callable[[T], R], items: Iterable[T], limit_blas: bool = True
                 ) -> Iterator[R]:
    """``map(fn, items)`` on the pool's threads, results in input order, BLAS held to one
    thread (``limit_blas``). Called from inside one of its own tasks, it maps in that
    thread (no pool deadlock). An interrupt (KeyboardInterrupt) while it maps shuts the
    pool down, so the process can exit."""
    workers = n_threads()
    with blas_single_thread() if limit_blas else contextlib.nullcontext():
        if workers == 1 or getattr(_IN_WORKER, "active", False):
            yield from map(fn, items)
            return

        def task(item: T) -> R:
            _IN_WORKER.active = True
            try:
                return fn(item)
            finally:
                _IN_WORKER.active = False

        try:
            yield from _pool(workers).map(task, items)
        except KeyboardInterrupt:  # Ctrl-C, SIGTERM: the process is ending; let it exit
            _stop_pool()
            raise


# -------------------------------------------------------------------- executors


class InProcess:
    """Runs every piece of work here, sequentially, in input order."""

    n_workers = 1
    distributed = False

    def __init__(self) -> None:
        self.stats = dict.fromkeys(STAT_KEYS, 0)

    def describe(self) -> str:
        return "in-process"

    def scatter(self, obj: Any) -> Any:
        """A handle to ``obj`` to pass to :meth:`map` (here: ``obj`` itself)."""
        return obj

    def map(self, fn: Callable, items: Iterable, *shared: Any) -> list:
        """``[fn(item, *shared) for item in items]``."""
        return [fn(item, *shared) for item in items]

    def as_completed(self, fn: Callable, items: Iterable, *shared: Any) -> Iterator[tuple]:
        """``(index, fn(item, *shared))`` for each item, as each finishes."""
        for i, item in enumerate(items):
            yield i, fn(item, *shared)

    def place(self, fn: Callable, arg_lists: Sequence[tuple]) -> list:
        """``fn(*args)`` for each tuple of ``arg_lists``, each result kept where it was made
        (workers in turn) for :meth:`run_on`; returns handles to the results."""
        return [fn(*args) for args in arg_lists]

    def run_on(self, handles: Sequence, fn: Callable, arg_lists: Sequence[tuple] | None,
               *shared: Any, tick: Callable[[int], None] | None = None) -> list:
        """``fn(obj, *args, *shared)`` for each placed object and its tuple of
        ``arg_lists``, where the object lives; results in order. ``tick(k)`` is called as
        the k-th result arrives (progress bars)."""
        out = []
        for k, (h, a) in enumerate(zip(handles, arg_lists or [()] * len(handles),
                                       strict=True)):
            out.append(fn(h, *a, *shared))
            if tick is not None:
                tick(k)
        return out

    def release(self, handles: Sequence) -> None:
        """Forget placed or scattered objects."""

    def close(self) -> None:
        pass


@dataclass
class _Placed:
    """An object kept on one worker: its future and that worker's address."""

    future: Any
    worker: str


class DaskExecutor:
    """Runs pieces of work on the workers of a ``distributed.Client``."""

    distributed = True
    #: How many times :meth:`as_completed` and :meth:`map` run a piece again whose
    #: worker was lost (objects placed on one worker are not retried: see :meth:`run_on`).
    RETRIES = 3

    def __init__(self, client, cluster=None):
        self.client, self.cluster = client, cluster
        self.workers = sorted(client.scheduler_info()["workers"])
        if not self.workers:
            client.wait_for_workers(1, timeout=60)
            self.workers = sorted(client.scheduler_info()["workers"])
        self.n_workers = len(self.workers)
        self.stats = dict.fromkeys(STAT_KEYS, 0)
        self._turn = 0
        # scattered objects by their futures' keys: sent again if their workers are lost
        self._kept: dict[str, tuple[Any, Any]] = {}

    def describe(self) -> str:
        where = "local cluster" if self.cluster is not None else self.client.scheduler.address
        return f"{self.n_workers} Dask workers ({where})"

    def _size(self, obj: Any) -> int:
        from dask.sizeof import sizeof  # lazy: Dask is optional (see the module doc)

        return int(sizeof(obj))

    def _sent(self, args: Sequence) -> None:
        from dask.distributed import Future  # lazy: Dask is optional (see the module doc)

        def size(a):  # futures are references to data already on the workers
            if isinstance(a, Future):
                return 0
            if isinstance(a, (tuple, list)):
                return sum(size(b) for b in a)
            return self._size(a)

        self.stats["bytes_sent"] += size(args)
        self.stats["tasks"] += 1

    def scatter(self, obj: Any) -> Any:
        """A future of ``obj``, copied once to every worker (``broadcast``)."""
        self.stats["bytes_scattered"] += self._size(obj) * self.n_workers
        fut = self.client.scatter([obj], broadcast=True, hash=False)[0]
        self._kept[fut.key] = (obj, fut)
        return fut

    def _renewed(self, arg: Any) -> Any:
        """``arg`` with each scattered future whose data is gone scattered again (a
        worker that joined after the broadcast has no copy: if every worker that had one
        dies, the data is lost and the tasks that read it are cancelled)."""
        if isinstance(arg, (tuple, list)):
            return type(arg)(self._renewed(a) for a in arg)
        kept = self._kept.get(getattr(arg, "key", None))
        if kept is None:
            return arg
        obj, fut = kept
        if fut.status != "finished":
            fut = self.client.scatter([obj], broadcast=True, hash=False)[0]
            self.stats["bytes_scattered"] += self._size(obj) * self.n_workers
            self._kept[arg.key] = self._kept[fut.key] = (obj, fut)
        return fut

    @staticmethod
    def _lost(fut) -> bool:
        """Whether ``fut`` failed for want of a worker (not by its task's own error)."""
        from distributed import KilledWorker  # lazy: Dask is optional (see the module doc)

        if fut.status in ("cancelled", "lost"):
            return True
        return fut.status == "error" and isinstance(fut.exception(), KilledWorker)

    def _submit(self, fn, args, worker=None):
        self._sent(args)
        kw = {"workers": [worker], "allow_other_workers": False} if worker else {}
        return self.client.submit(fn, *args, pure=False, **kw)

    def _result(self, fut) -> Any:
        from distributed import KilledWorker  # lazy: Dask is optional (see the module doc)

        try:
            out = fut.result()
        except (CancelledError, KilledWorker) as exc:  # not the task's own error
            raise WorkerLostError(
                f"a Dask worker was lost while running {str(fut.key).split('-', 1)[0]} "
                f"({type(exc).__name__}: "
                f"{exc}); run the command again: training resumes from its "
                "--checkpoint-dir, a batch encode or a bench from its output folder"
            ) from exc
        self.stats["bytes_received"] += self._size(out)
        return out

    def map(self, fn: Callable, items: Iterable, *shared: Any) -> list:
        out = dict(self.as_completed(fn, items, *shared))
        return [out[i] for i in range(len(out))]

    def as_completed(self, fn: Callable, items: Iterable, *shared: Any) -> Iterator[tuple]:
        """A piece whose worker was lost runs again, up to :attr:`RETRIES` times, with
        any scattered object it reads sent again if its data went with the worker."""
        from dask.distributed import as_completed  # lazy: Dask is optional (see the module doc)

        tasks = [(item, *shared) for item in items]
        futures = [self._submit(fn, args) for args in tasks]
        index = {f.key: (i, 0) for i, f in enumerate(futures)}
        pending = as_completed(futures)
        for fut in pending:
            i, tries = index.pop(fut.key)
            if tries < self.RETRIES and self._lost(fut):
                again = self._submit(fn, self._renewed(tasks[i]))
                index[again.key] = (i, tries + 1)
                pending.add(again)
                continue
            yield i, self._result(fut)

    def place(self, fn: Callable, arg_lists: Sequence[tuple]) -> list:
        handles = []
        for args in arg_lists:
            worker = self.workers[self._turn % self.n_workers]
            self._turn += 1
            # the arguments go to that worker alone (scattered, not embedded in the graph)
            self.stats["bytes_scattered"] += sum(self._size(a) for a in args)
            sent = self.client.scatter(list(args), workers=[worker], hash=False)
            fut = self.client.submit(fn, *sent, pure=False, workers=[worker],
                                     allow_other_workers=False)
            handles.append(_Placed(fut, worker))
        return handles

    def run_on(self, handles: Sequence, fn: Callable, arg_lists: Sequence[tuple] | None,
               *shared: Any, tick: Callable[[int], None] | None = None) -> list:
        arg_lists = arg_lists or [()] * len(handles)
        futures = [self._submit(fn, (h.future, *a, *shared), h.worker)
                   for h, a in zip(handles, arg_lists, strict=True)]
        out = []
        for k, f in enumerate(futures):
            out.append(self._result(f))
            if tick is not None:
                tick(k)
        return out

    def release(self, handles: Sequence) -> None:
        for h in handles:
            fut = getattr(h, "future", h)
            _, renewed = self._kept.pop(getattr(fut, "key", None), (None, fut))
            if renewed is not fut:
                self._kept.pop(renewed.key, None)
                renewed.release()
            fut.release()

    def close(self) -> None:
        self._kept.clear()
        self.client.close()
        if self.cluster is not None:
            self.cluster.close()


Executor = InProcess | DaskExecutor


def start_executor(workers: int | None = None, scheduler: str | None = None) -> Executor:
    """The executor that ``workers``/``scheduler`` ask for (see the module doc); call its
    ``close()`` when done, or use :func:`executor`."""
    if workers is not None and scheduler is not None:
        raise UsageError("give --workers N (a local cluster) or --scheduler ADDRESS (an "
                         "existing one), not both")
    if workers is None and scheduler is None:
        return InProcess()
    try:
        # lazy: Dask is an optional dependency (the `cluster` extra), loaded only here
        from dask.distributed import Client, LocalCluster
    except ImportError as exc:
        raise UsageError("--workers and --scheduler need Dask's distributed scheduler: "
                         "pip install 'sparse-brdf[cluster]'") from exc
    if scheduler is not None:
        return DaskExecutor(Client(scheduler))
    if workers < 1:
        raise UsageError(f"--workers must be >= 1, got {workers}")
    # each process gets its share of the cores for the package's own thread pool
    threads = max(1, usable_cores() // workers)
    # the dashboard on any free port: never clash with another cluster on this machine
    cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                           dashboard_address=":0", silence_logs=logging.ERROR,
                           env={"SPARSE_BRDF_THREADS": str(threads)})
    try:
        client = Client(cluster)
    except BaseException:
        cluster.close()
        raise
    return DaskExecutor(client, cluster)


@contextlib.contextmanager
def executor(workers: int | None = None, scheduler: str | None = None) -> Iterator[Executor]:
    """``with executor(workers, scheduler) as ex:`` -- see :func:`start_executor`; a
    local cluster is shut down on leaving the block."""
    ex = start_executor(workers, scheduler)
    try:
        yield ex
    finally:
        ex.close()
