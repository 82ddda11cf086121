"""Recording a run into Rerun (.rrd) without disturbing the loop, in bounded memory.

Each tick the loop writes one row of numbers into the current block (a small array; no
Rerun call). A full block (``block_rows`` rows, 1 s at 500 Hz) is queued and sent with
Rerun's columnar ``send_columns``: in lockstep at once, in real time one channel-block per
tick in the slack after the command is out (``drain(1)``), and everything left on
``close()``, which the session calls on every exit path. Memory does not grow with the run:
only the current block, the queued blocks (bounded: past ``max_pending_blocks`` the oldest is
sent at once) and the retained tail (the last ``retain_rows`` rows, for the summary) are held.

The file sink writes as blocks are sent: Rerun's batcher hands what was logged to the file
sink's own thread at least every 200 ms (its flush tick), so after a SIGKILL the .rrd holds
everything but the last blocks (tested) without the loop waiting for the disk. An explicit
``flush()`` (which blocks until written: about 10 ms here, five ticks at 500 Hz) is made
only every ``flush_every_blocks`` blocks when that is set (0, the default: only on close).

How series are named and drawn, how an event is marked on the plots and how the summary
reads are the review layer's (``harness.review.annotations``), handed in by the caller as an
``Annotator``: this module imports nothing of ``harness.review`` (which reads recordings
with ``harness.record.reader``), so the dependency runs one way. Without one, events are
plain text logs and the summary a JSON block.
"""

from __future__ import annotations

import contextlib
import json
import os
import sys
import threading
from collections import deque
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from harness.record.output import OutputError, SpaceGuard
from harness.record.streams import save_with_blueprint, send_blueprint, sweep_orphans

APPLICATION_ID = "sgsrt-harness"

FLUSH_TIMEOUT_S = 30.0
"""A flush waits at most this long: Rerun's flush waited forever once its file sink's thread
had died on a full disk (a run hung with 64 KB free), and with ``--view`` to an address
where no viewer listened, its own timeout notwithstanding. The flush runs in a thread the
caller waits for with this bound (the wait also lets SIGTERM through)."""

ABANDONED = threading.Event()
"""Set when a flush was given up: Rerun's own shutdown at exit would wait for the same stuck
sink, so ``harness.cli`` then ends the process with ``os._exit`` once its output is out."""


def _bounded(call: Callable[[], object], timeout_s: float) -> None:
    """``call()`` in a thread, waited for at most ``timeout_s``; ``TimeoutError`` after."""
    done = threading.Event()
    errors: list[BaseException] = []

    def run() -> None:
        try:
            call()
        except BaseException as exc:  # handed to the caller
            errors.append(exc)
        finally:
            done.set()

    threading.Thread(target=run, name="recording-flush", daemon=True).start()
    if not done.wait(timeout_s):
        ABANDONED.set()
        raise TimeoutError(f"no answer from Rerun's sinks in {timeout_s:g} s")
    if errors:
        raise errors[0]


_FAILED_STREAMS: list[rr.RecordingStream] = []
"""Streams whose sink failed or stopped answering (one per such failure, so bounded)."""


def flush_within(rec: rr.RecordingStream, timeout_s: float | None = None) -> None:
    """``rec.flush()`` waited for at most ``timeout_s`` (default ``FLUSH_TIMEOUT_S``, read at
    the call: Rerun's own timeout did not hold); ``TimeoutError`` after, the sink's own error
    as raised."""
    bound = FLUSH_TIMEOUT_S if timeout_s is None else timeout_s
    _bounded(lambda: rec.flush(timeout_sec=bound), bound + 1)


def close_stream(rec: rr.RecordingStream, path: Path | str) -> None:
    """Flush a recording stream saving to ``path`` within ``FLUSH_TIMEOUT_S``, then
    disconnect it (the caller drops it and calls ``sweep_orphans``). ``OutputError`` naming
    the file when its sink failed or did not answer; then it is not disconnected, since a
    stuck sink would hold the disconnect too (and ``harness.cli`` ends the process without
    Rerun's shutdown, ``ABANDONED``)."""
    path = Path(path)
    try:
        flush_within(rec)
    except Exception as exc:
        if isinstance(exc, TimeoutError) or "timed out" in str(exc).lower():
            ABANDONED.set()
        # held, never orphaned: sweep_orphans flushes orphans, and would wait on its sink
        _FAILED_STREAMS.append(rec)
        raise OutputError(path.parent, f"{path.name} could not be written ({exc})") from exc
    rec.disconnect()


START_TIMEOUT_S = 20.0
"""Rerun's ``save`` waited forever when its file sink's first write failed (a disk with
64 KB free: the sink's thread died and ``set_sink`` waited for its flush). A Rust call cannot
be interrupted, so past this bound the process ends (exit 4) with one line naming the file;
nothing has been sent to the rig yet (the recorder exists before the loop starts)."""


@contextlib.contextmanager
def _start_watchdog(path: Path) -> Iterator[None]:
    started = threading.Event()

    def watch() -> None:
        if not started.wait(START_TIMEOUT_S):
            print(f"harness: cannot write to the output folder {path.parent}: the recording "
                  f"{path.name} did not start in {START_TIMEOUT_S:g} s (a full or failing "
                  "disk); nothing was sent to the rig", file=sys.stderr, flush=True)
            os._exit(4)

    threading.Thread(target=watch, name="recording-start-watchdog", daemon=True).start()
    try:
        yield
    finally:
        started.set()


def default_blueprint(extra_views: list[rrb.View] | None = None) -> rrb.Blueprint:
    """Attitude, wheel, tip acceleration and loop timing stacked on one time line; the other
    devices and analysis views in tabs below."""
    main = rrb.Vertical(
        rrb.TimeSeriesView(origin="/attitude", name="Attitude (deg)"),
        rrb.TimeSeriesView(origin="/wheel", name="Reaction wheel"),
        rrb.TimeSeriesView(origin="/tip", name="Tip acceleration (m/s^2)"),
        rrb.TimeSeriesView(origin="/timing", name="Loop timing (ms)"),
    )
    tabs = rrb.Tabs(
        rrb.TimeSeriesView(origin="/thrusters", name="Thrusters"),
        rrb.TimeSeriesView(origin="/piezo", name="Piezo"),
        rrb.TimeSeriesView(origin="/rotor", name="Disturbance rotor"),
        *(extra_views or []),
    )
    return rrb.Blueprint(rrb.Vertical(main, tabs, row_shares=[4, 1]), collapse_panels=True)


BlockObserver = Callable[[np.ndarray, np.ndarray], None]


class Annotator(Protocol):
    """What the review layer adds to a recording (harness.review.annotations)."""

    def name_series(self, rec: rr.RecordingStream, channels: list[str]) -> None:
        """Each channel's legend name and style, logged static."""

    def log_event(self, rec: rr.RecordingStream, time_s: float, entity: str, text: str,
                  level: str, values: Mapping[str, float], name: str | None,
                  series: str | None) -> None:
        """An event at ``time_s``, marked on the plots at ``values`` (channel -> value)."""

    def summary_text(self, summary: Mapping[str, Any]) -> str:
        """The run's summary as markdown."""


class PlainAnnotator:
    """No review layer: entity paths as legends, events as text logs, the summary as JSON."""

    def name_series(self, rec: rr.RecordingStream, channels: list[str]) -> None:
        return None

    def log_event(self, rec: rr.RecordingStream, time_s: float, entity: str, text: str,
                  level: str, values: Mapping[str, float], name: str | None,
                  series: str | None) -> None:
        rec.set_time("time", duration=time_s)
        rec.log(entity, rr.TextLog(text, level=level))

    def summary_text(self, summary: Mapping[str, Any]) -> str:
        return "```json\n" + json.dumps(summary, indent=1, default=str) + "\n```\n"


class _BoundedFlushStream:
    """A ``RecordingStream`` whose ``flush`` is its recorder's (bounded in time)."""

    def __init__(self, recorder: Recorder) -> None:
        self._recorder = recorder

    def flush(self, *args: object, **kwargs: object) -> None:
        self._recorder.flush()

    def __getattr__(self, name: str) -> object:
        return getattr(self._recorder._stream(), name)


class _Block:
    __slots__ = ("t", "data", "next_channel")

    def __init__(self, t: np.ndarray, data: np.ndarray) -> None:
        self.t = t
        self.data = data
        self.next_channel = 0


class Recorder:
    """Per-tick numeric channels (entity paths) on the ``time`` timeline (seconds).

    ``n_rows`` is only a hint (kept for callers; nothing is preallocated for the run).
    ``observers`` are called with each completed block ``(time_s, rows)`` in order; they
    see every row exactly once (the session's running summary is one)."""

    def __init__(self, path: Path, channels: list[str], n_rows: int, recording_name: str,
                 block_rows: int = 500, blueprint: rrb.Blueprint | None = None,
                 live_view_url: str | None = None, retain_rows: int = 0,
                 flush_every_blocks: int = 0, max_pending_blocks: int = 30,
                 observers: list[BlockObserver] | None = None,
                 max_pending_events: int = 100, annotator: Annotator | None = None,
                 guard: SpaceGuard | None = None) -> None:
        self.path = path
        self.live_view_url = live_view_url
        # checked once per block: the run stops (OutputError) before the disk is full
        self.guard = guard
        self.space_stop: OutputError | None = None  # the guard stopped the run
        self.failed: OutputError | None = None  # the file sink failed
        self.channels = list(channels)
        self.index = {c: i for i, c in enumerate(self.channels)}
        self.n_rows_hint = n_rows
        self.block_rows = max(1, int(block_rows))
        self.retain_rows = max(0, int(retain_rows))
        self.flush_every_blocks = max(0, int(flush_every_blocks))
        self.max_pending_blocks = max(1, int(max_pending_blocks))
        self.observers: list[BlockObserver] = list(observers or [])
        self.rows = 0
        self._t = np.zeros(self.block_rows)
        self._data = np.full((self.block_rows, len(self.channels)), np.nan)
        self._fill = 0
        self._pending: deque[_Block] = deque()
        # events queued in the tick (queue_event), sent by drain() in the slack
        self._events: deque[tuple[float, str, str, str, dict[str, float], str | None,
                                  str | None]] = deque()
        self.max_pending_events = max(1, int(max_pending_events))
        self._tail: deque[_Block] = deque()
        self._tail_rows = 0
        self._blocks_sent = 0
        self._closed = False
        self._last_block: _Block | None = None
        rec = rr.RecordingStream(APPLICATION_ID, recording_id=recording_name)
        self.rec: rr.RecordingStream | None = rec
        bp = blueprint or default_blueprint()
        # no RRD footer: writing one keeps a manifest entry per chunk in memory until the
        # file is closed (measured: ~1.2 MB per 100 000 rows, 0.5 GB for a day); the file
        # stays a valid RRD, read by streaming (harness.record.reader)
        with _start_watchdog(path):
            if live_view_url is None:
                save_with_blueprint(rec, path, bp, write_footer=False)
            else:
                # the file and a viewer we started bound to 127.0.0.1 (harness.live_view);
                # we never call serve_grpc, which binds every interface
                rec.set_sinks(rr.FileSink(str(path), write_footer=False),
                              rr.GrpcSink(live_view_url))
                send_blueprint(rec, bp)
        rec.send_recording_name(recording_name)
        self.annotator: Annotator = annotator or PlainAnnotator()
        self.annotator.name_series(rec, self.channels)

    def row(self, time_s: float) -> np.ndarray:
        """The next row to fill (a view); call ``commit()`` when written."""
        self._t[self._fill] = time_s
        return self._data[self._fill]

    def commit(self) -> None:
        self.rows += 1
        self._fill += 1
        if self._fill >= self.block_rows:
            self._complete_block()

    def _complete_block(self) -> None:
        n = self._fill
        if n == 0:
            return
        block = _Block(self._t[:n].copy(), self._data[:n].copy())
        self._t = np.zeros(self.block_rows)
        self._data = np.full((self.block_rows, len(self.channels)), np.nan)
        self._fill = 0
        self._pending.append(block)
        self._last_block = block
        if self.retain_rows:
            self._tail.append(block)
            self._tail_rows += n
            while self._tail and self._tail_rows - len(self._tail[0].t) >= self.retain_rows:
                self._tail_rows -= len(self._tail.popleft().t)
        for observe in self.observers:
            observe(block.t, block.data)
        if self.guard is not None and self.space_stop is None:
            try:
                self.guard.check()
            except OutputError as exc:
                self.space_stop = exc
                raise
        while len(self._pending) > self.max_pending_blocks:  # never had the time: bound it
            self._send_block_rest(self._pending[0])

    @property
    def pending_blocks(self) -> int:
        return len(self._pending)

    def drain(self, max_blocks: int | None = None) -> int:
        """Send up to ``max_blocks`` pending events and channel-blocks (all if None)."""
        n = 0
        while self._events and (max_blocks is None or n < max_blocks):
            self._send_event(self._events.popleft())
            n += 1
        while self._pending and (max_blocks is None or n < max_blocks):
            self._send_one(self._pending[0])
            n += 1
        return n

    def _send_block_rest(self, block: _Block) -> None:
        while self._pending and self._pending[0] is block:
            self._send_one(block)

    def _send_one(self, block: _Block) -> None:
        c = block.next_channel
        self._stream().send_columns(
            self.channels[c],
            indexes=[rr.TimeColumn("time", duration=block.t)],
            columns=rr.Scalars.columns(scalars=block.data[:, c]),
        )
        block.next_channel = c + 1  # only once sent: an interrupted send is retried on close
        if block.next_channel >= len(self.channels):
            self._pending.popleft()
            self._blocks_sent += 1
            if self.flush_every_blocks and self._blocks_sent % self.flush_every_blocks == 0:
                self.flush()

    def flush(self) -> None:
        """Hand everything logged so far to the file (blocks until written, at most
        ``FLUSH_TIMEOUT_S``). Raises ``OutputError`` when the file sink failed (Rerun's
        writer thread stops at the first failed write: a full or read-only disk)."""
        if self.failed is not None:
            raise self.failed
        rec = self._stream()
        try:
            flush_within(rec)
        except Exception as exc:
            viewer = f"; or the live viewer at {self.live_view_url} stopped answering" \
                if self.live_view_url else ""
            self.failed = OutputError(self.path.parent, f"the recording {self.path.name} "
                                      f"could not be written ({exc}{viewer})")
            if "timed out" in str(exc).lower() or isinstance(exc, TimeoutError):
                ABANDONED.set()  # the sink still holds data: Rerun's exit would wait for it
            raise self.failed from exc

    @property
    def bounded_stream(self) -> rr.RecordingStream:
        """The recording stream for code that logs into it directly (the decoded bus after
        the run), with its ``flush()`` bounded as ``Recorder.flush``."""
        return _BoundedFlushStream(self)  # type: ignore[return-value]

    def log_static_text(self, entity: str, text: str) -> None:
        self._stream().log(entity, rr.TextDocument(text, media_type="text/markdown"), static=True)

    def log_event(self, time_s: float, entity: str, text: str, level: str = "WARN",
                  mark: bool = True) -> None:
        """A TextLog under ``/events/...`` and (``mark``) a marker on every plot at
        ``time_s``, on the plot's signal at the last recorded row (the annotator's)."""
        self.annotator.log_event(self._stream(), time_s, entity, text, level,
                                 self.latest_values() if mark else {}, None, None)

    def queue_event(self, time_s: float, entity: str, text: str, level: str = "WARN",
                    series: str | None = None, name: str | None = None) -> None:
        """As ``log_event`` (markers at the last committed row's values), but sent by the
        next ``drain()``, outside the tick's critical path; past ``max_pending_events``
        queued, the oldest is sent at once (memory stays bounded). ``series`` and ``name``:
        the markers' series and legend name (the annotator's ``log_event``)."""
        self._events.append((time_s, entity, text, level, self.latest_values(), series, name))
        while len(self._events) > self.max_pending_events:
            self._send_event(self._events.popleft())

    @property
    def pending_events(self) -> int:
        return len(self._events)

    def _send_event(self, event: tuple[float, str, str, str, dict[str, float], str | None,
                                       str | None]) -> None:
        time_s, entity, text, level, values, series, name = event
        self.annotator.log_event(self._stream(), time_s, entity, text, level, values, name,
                                 series)

    def latest_values(self) -> dict[str, float]:
        """Every channel's value in the last committed row (empty before the first)."""
        if self.rows == 0:
            return {}
        if self._fill:
            row = self._data[self._fill - 1]
        elif self._last_block is not None:
            row = self._last_block.data[-1]
        else:
            return {}
        return {c: float(row[i]) for i, c in enumerate(self.channels)}

    def send_layout(self, blueprint: rrb.Blueprint) -> None:
        """Replace the recording's layout (made default and active), e.g. at the end of a
        run when the plots' ranges are known."""
        send_blueprint(self._stream(), blueprint, make_active=True, make_default=True)

    def log_summary(self, summary: dict) -> None:
        """The run's summary as markdown at ``/run/summary`` (the annotator's text)."""
        self.log_static_text("/run/summary", self.annotator.summary_text(summary))

    def finish_rows(self) -> None:
        """Queue the partly filled block (observers see it); rows after it start a new one."""
        self._complete_block()

    def close(self) -> None:
        """Send everything recorded so far and finalise the file (idempotent)."""
        if self._closed:
            return
        self._closed = True
        # the guard's reserve takes what is still queued; after it stopped the run it is
        # not asked again
        self.guard = None
        try:
            if self.failed is None:
                self._complete_block()
                self.drain()
            self.flush()
        finally:
            if self.failed is None:  # a failed or stuck sink would hold disconnect too
                rec = self._stream()
                rec.disconnect()
                # a finished stream keeps its two threads and buffers until destroyed, and
                # rerun destroys it only when a sweep finds it unreferenced: drop ours,
                # then sweep (a process making many runs stays flat;
                # benchmarks/bench_many_runs.py)
                del rec
                self.rec = None
                sweep_orphans()

    def _stream(self) -> rr.RecordingStream:
        if self.rec is None:
            raise RuntimeError(f"{self.path}: the recording is closed")
        return self.rec

    def tail_time(self) -> np.ndarray:
        """Times of the retained tail (the last ``retain_rows`` rows at least, when set)."""
        parts = [b.t for b in self._tail] + [self._t[: self._fill]]
        return np.concatenate(parts) if parts else np.zeros(0)

    def column(self, channel: str) -> np.ndarray:
        """The retained tail of one channel (not the whole run: read run.rrd for that,
        ``harness.record.reader``)."""
        c = self.index[channel]
        parts = [b.data[:, c] for b in self._tail] + [self._data[: self._fill, c]]
        return np.concatenate(parts) if parts else np.zeros(0)
