"""Where independent jobs run: this process, the local cores, or a Dask cluster.

One small abstraction shared by ``harness test`` (a suite's runs) and ``harness sweep`` (its
batches of lambdas), so both scale the same way:

- ``InlineEngine``: in this process, each job when its result is first asked for (one job at
  a time: the real rig, ``--workers 1``, debugging).
- ``LocalEngine``: a process pool over the cores of this machine (default: every core). Its
  workers come from a ``forkserver`` (a clean process with the harness imported once), ignore
  Ctrl-C and poll a shared stop flag: ``stop()`` makes every running run end at its next tick
  boundary (rig safe, logs closed) and cancels the jobs not started.
- ``DaskEngine``: an existing Dask distributed cluster, addressed by ``--cluster
  tcp://HOST:8786`` or the environment variable ``SGSRT_CLUSTER``. Workers on other machines
  need the same project installed (``pip install -e '.[cluster]'``); they share no file
  system with the client: jobs that write files return them (``ships_files``), and the
  client writes them into its output folder. ``stop()`` cancels what has not started; a job
  already running on a worker finishes there and its result is dropped.

``make_engine(cluster, workers)`` picks one. A job is a picklable top-level function and
picklable arguments; ``submit`` returns a future with ``result()``, ``done()``, ``cancel()``
and ``add_done_callback(fn)`` (called with the future, possibly from another thread).
``current_worker()`` names the process a job ran in (for reports and the cluster test), and
``stop_requested()`` is what a job polls (``execute_run``'s ``should_stop``).
"""

from __future__ import annotations

import multiprocessing
import os
import signal
import socket
import threading
from collections.abc import Callable, Iterable
from concurrent.futures import Future, ProcessPoolExecutor
from typing import Any, Protocol

CLUSTER_ENV = "SGSRT_CLUSTER"

_stop_event: Any = None  # multiprocessing Event in a LocalEngine worker
_inline_stop = threading.Event()


class EngineError(RuntimeError):
    """The engine could not be started (bad address, no scheduler there, Dask missing)."""


class TaskFuture(Protocol):
    def result(self, timeout: float | None = None) -> Any: ...
    def done(self) -> bool: ...
    def cancel(self) -> bool: ...
    def add_done_callback(self, fn: Callable[[Any], None]) -> None: ...


class Engine(Protocol):
    name: str
    workers: int
    ships_files: bool

    def submit(self, fn: Callable[..., Any], /, *args: Any) -> TaskFuture: ...
    def stop(self) -> None: ...
    def close(self) -> None: ...


def stop_requested() -> str | None:
    """Polled by a running job: a reason to stop at the next tick, or None."""
    if _inline_stop.is_set():
        return "suite stopped"
    if _stop_event is not None and _stop_event.is_set():
        return "suite stopped"
    return None


def current_worker() -> str:
    """``dask:<worker address>`` inside a Dask worker, else ``<host>:<pid>``."""
    try:
        from distributed import get_worker

        return f"dask:{get_worker().address}"
    except (ImportError, ValueError):
        return f"{socket.gethostname()}:{os.getpid()}"


class _LazyFuture(Future):
    """A concurrent.futures.Future computed in this thread when its result is asked for."""

    def __init__(self, fn: Callable[..., Any], args: tuple[Any, ...]) -> None:
        super().__init__()
        self._job = (fn, args)

    def result(self, timeout: float | None = None) -> Any:
        if self._job is not None and self.set_running_or_notify_cancel():
            fn, args = self._job
            self._job = None
            try:
                self.set_result(fn(*args))
            except BaseException as exc:  # noqa: BLE001 - handed to the caller via the future
                self.set_exception(exc)
        return super().result(timeout)


class InlineEngine:
    name = "inline"
    workers = 1
    ships_files = False

    def __init__(self) -> None:
        _inline_stop.clear()

    def submit(self, fn: Callable[..., Any], /, *args: Any) -> TaskFuture:
        return _LazyFuture(fn, args)

    def stop(self) -> None:
        _inline_stop.set()

    def close(self) -> None:
        _inline_stop.clear()


def _init_local_worker(event: Any) -> None:
    global _stop_event
    _stop_event = event
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent decides; runs end cleanly
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    os.environ.setdefault("OMP_NUM_THREADS", "1")


class LocalEngine:
    ships_files = False

    def __init__(self, workers: int | None = None,
                 preload: Iterable[str] = ("harness.core.session",)) -> None:
        self.workers = max(1, workers or os.cpu_count() or 1)
        self.name = f"local ({self.workers} processes)"
        ctx = multiprocessing.get_context("forkserver")
        ctx.set_forkserver_preload(list(preload))
        self._event = ctx.Event()
        self._pool = ProcessPoolExecutor(max_workers=self.workers, mp_context=ctx,
                                         initializer=_init_local_worker,
                                         initargs=(self._event,))
        self._futures: list[Future] = []

    def submit(self, fn: Callable[..., Any], /, *args: Any) -> TaskFuture:
        fut = self._pool.submit(fn, *args)
        self._futures.append(fut)
        return fut

    def stop(self) -> None:
        """Running jobs stop at their next tick; queued ones are cancelled. (Not
        ``shutdown(wait=False)``: after it, ``close`` could no longer wait for the running
        jobs to end.)"""
        self._event.set()
        for fut in self._futures:
            fut.cancel()

    def close(self) -> None:
        self._pool.shutdown(wait=True, cancel_futures=True)


class DaskEngine:
    ships_files = True

    def __init__(self, address: str) -> None:
        try:
            from distributed import Client
        except ImportError as exc:
            raise EngineError("--cluster needs Dask distributed: pip install -e "
                              "'.[cluster]'") from exc
        try:
            self._client = Client(address, timeout=10)
        except (OSError, TimeoutError) as exc:
            raise EngineError(f"cluster {address}: no Dask scheduler answered ({exc})") from exc
        self.address = address
        self.workers = max(1, sum(
            w.get("nthreads", 1) for w in self._client.scheduler_info()["workers"].values()))
        self.name = f"dask {address} ({self.workers} worker threads)"
        self._futures: list[Any] = []

    def submit(self, fn: Callable[..., Any], /, *args: Any) -> TaskFuture:
        fut = self._client.submit(fn, *args, pure=False)
        self._futures.append(fut)
        return fut

    def stop(self) -> None:
        pending = [f for f in self._futures if not f.done()]
        if pending:
            self._client.cancel(pending)

    def close(self) -> None:
        self._client.close()


def make_engine(cluster: str | None = None, workers: int | None = None,
                preload: Iterable[str] = ("harness.core.session",)) -> Engine:
    """``cluster`` (else ``$SGSRT_CLUSTER``): a Dask scheduler address; otherwise
    ``workers`` local processes (default every core; 1 runs inline)."""
    address = cluster or os.environ.get(CLUSTER_ENV) or None
    if address:
        if "://" not in address:
            address = f"tcp://{address}"
        return DaskEngine(address)
    if workers is not None and workers < 1:
        raise EngineError(f"--workers: expected an integer >= 1, got {workers}")
    n = workers or os.cpu_count() or 1
    if n == 1:
        return InlineEngine()
    return LocalEngine(n, preload)
