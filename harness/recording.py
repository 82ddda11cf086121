"""Recording a run into Rerun (.rrd) without disturbing the loop.

Each tick the loop writes one row of numbers into a preallocated array (no Rerun call).
Blocks of rows are sent with Rerun's columnar ``send_columns``: in lockstep whenever a block
is full, in real time one channel-block per tick in the slack after the command is out
(``drain(1)``), and everything left on ``close()``, which the loop calls on every exit path.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

APPLICATION_ID = "sgsrt-harness"


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


class Recorder:
    """Per-tick numeric channels (entity paths) on the ``time`` timeline (seconds)."""

    def __init__(self, path: Path, channels: list[str], n_rows: int, recording_name: str,
                 block_rows: int = 500, blueprint: rrb.Blueprint | None = None,
                 live_view_url: str | None = None) -> None:
        self.path = path
        self.channels = list(channels)
        self.index = {c: i for i, c in enumerate(self.channels)}
        self.data = np.full((n_rows, len(channels)), np.nan)
        self.time_s = np.zeros(n_rows)
        self.rows = 0
        self.block_rows = block_rows
        self._sent = 0  # rows [0, _sent) sent for every channel
        self._pending: list[tuple[int, int, int]] = []  # (channel, start, stop)
        self._closed = False
        self.rec = rr.RecordingStream(APPLICATION_ID, recording_id=recording_name)
        bp = blueprint or default_blueprint()
        if live_view_url is None:
            self.rec.save(str(path), default_blueprint=bp)
        else:
            # the file and a viewer we started bound to 127.0.0.1 (harness.live_view); we
            # never call serve_grpc, which binds every interface
            self.rec.set_sinks(rr.FileSink(str(path)), rr.GrpcSink(live_view_url))
            self.rec.send_blueprint(bp)
        self.rec.send_recording_name(recording_name)

    def row(self, time_s: float) -> np.ndarray:
        """The next row to fill (a view); call ``commit()`` when written."""
        self.time_s[self.rows] = time_s
        return self.data[self.rows]

    def commit(self) -> None:
        self.rows += 1
        if self.rows - self._sent >= self.block_rows:
            start, stop = self._sent, self.rows
            self._pending.extend((c, start, stop) for c in range(len(self.channels)))
            self._sent = stop

    def drain(self, max_blocks: int | None = None) -> int:
        """Send up to ``max_blocks`` pending channel-blocks (all if None)."""
        n = 0
        while self._pending and (max_blocks is None or n < max_blocks):
            c, start, stop = self._pending[0]
            self._send(c, start, stop)
            self._pending.pop(0)  # only once sent: an interrupted send is retried on close
            n += 1
        return n

    def _send(self, c: int, start: int, stop: int) -> None:
        values = self.data[start:stop, c]
        self.rec.send_columns(
            self.channels[c],
            indexes=[rr.TimeColumn("time", duration=self.time_s[start:stop])],
            columns=rr.Scalars.columns(scalars=values),
        )

    def log_static_text(self, entity: str, text: str) -> None:
        self.rec.log(entity, rr.TextDocument(text, media_type="text/markdown"), static=True)

    def log_event(self, time_s: float, entity: str, text: str, level: str = "WARN") -> None:
        """A TextLog under ``/events/...`` and a marker on every plot at ``time_s``, on the
        plot's signal at the last recorded row (harness.review.events)."""
        from harness.review.events import log_event

        log_event(self.rec, time_s, entity, text, level, self.latest_values())

    def latest_values(self) -> dict[str, float]:
        """Every channel's value in the last committed row (empty before the first)."""
        if self.rows == 0:
            return {}
        row = self.data[self.rows - 1]
        return {c: float(row[i]) for i, c in enumerate(self.channels)}

    def send_layout(self, blueprint: rrb.Blueprint) -> None:
        """Replace the recording's layout (made default and active), e.g. at the end of a
        run when the plots' ranges are known."""
        self.rec.send_blueprint(blueprint, make_active=True, make_default=True)

    def log_summary(self, summary: dict) -> None:
        """The run's summary as a markdown table at ``/run/summary``."""
        from harness.review.events import summary_markdown

        self.log_static_text("/run/summary", summary_markdown(summary))

    def close(self) -> None:
        """Send everything recorded so far and finalise the file (idempotent)."""
        if self._closed:
            return
        self._closed = True
        if self.rows > self._sent:
            self._pending.extend((c, self._sent, self.rows) for c in range(len(self.channels)))
            self._sent = self.rows
        self.drain()
        self.rec.flush()
        self.rec.disconnect()

    def column(self, channel: str) -> np.ndarray:
        return self.data[: self.rows, self.index[channel]]
