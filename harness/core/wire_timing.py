"""Timing on the wire, per tick, from the frames' own time stamps (pure: numbers in).

Three figures a CANopen bus and a reviewer care about, beside the loop's own lateness:

- **SYNC period jitter**: the time between this tick's SYNC and the previous one, minus the
  period (signed; the summary's percentiles are of its magnitude);
- **answer latency**: each device's first frame after this tick's SYNC, minus the SYNC's
  time stamp;
- **command margin**: the next SYNC's time stamp minus the last command frame of the tick
  before it (negative: the commands went out after the next SYNC, too late for it).

Where the time stamps come from (``source``) decides what they say:

- ``kernel`` (SocketCAN): every received frame carries the kernel's receive time, and the
  harness's own SYNC and commands come back as the kernel's echo (``CAN_RAW_RECV_OWN_MSGS``)
  with the time the kernel handed them to the driver: the time on the wire, to the
  driver's latency;
- ``sender`` (socketcand, a Unix-domain socket, the in-process virtual bus with the rig
  running on its own): a frame carries its sender's clock (the rig's time of sending, the
  harness's ``time.time()`` at ``send()`` for its own frames); no transport delay, no time
  on a wire;
- ``none`` (in-process lockstep: the rig answers inside the harness's own tick): nothing
  to measure.

In lockstep over a bus the ticks follow the host's pace, not a period: the answer latency
is measured, the SYNC jitter and the command margin are not.

Memory is fixed (``LatencyHistogram``) whatever the run's length.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import Any

from harness.core.streaming import LatencyHistogram

NAN = math.nan

SOURCE_NOTES = {
    "kernel": ("SocketCAN kernel time stamps: each received frame's time of reception and "
               "the echo of the harness's own SYNC and commands (their time of transmission "
               "as the kernel saw it); measures the bus's timing to the CAN driver's "
               "latency"),
    "sender": ("the senders' own time stamps (the harness's clock at send() for its SYNC and "
               "commands, the rig's clock for its answers): no transport delay and no time "
               "on a wire is measured; the SYNC jitter is the loop's sending jitter"),
    "none": ("in-process lockstep: the rig answers inside the harness's tick, there is no "
             "wire and no period to measure"),
}
LOCKSTEP_NOTE = ("; lockstep: the ticks follow the host's pace, so SYNC jitter and command "
                 "margin are not measured")


class WireTiming:
    """Per-tick timing on the wire (see the module docstring). ``tick`` takes one tick's
    time stamps and returns the tick's recorded figures in ms (NaN where unknown)."""

    def __init__(self, dt_s: float, devices: Iterable[str], source: str,
                 paced: bool = True, sync_sent_by: str = "loop") -> None:
        if source not in SOURCE_NOTES:
            raise ValueError(f"wire timing source {source!r}: expected one of "
                             f"{', '.join(SOURCE_NOTES)}")
        self.dt_s = dt_s
        self.source = source
        self.paced = paced and source != "none"
        self.sync_sent_by = sync_sent_by
        self.jitter_s = LatencyHistogram()  # |period - dt|
        self.jitter_min_s = math.inf  # signed extremes of period - dt
        self.jitter_max_s = -math.inf
        self.latency_s = {d: LatencyHistogram() for d in devices}
        self.margin_s = LatencyHistogram()
        self.margin_min_s = math.inf
        self.late_commands = 0  # commands after the next SYNC
        self.syncs_seen = 0
        self._prev_sync = NAN

    def tick(self, sync_ts: float, prev_cmd_ts: float,
             answers: Iterable[tuple[str, float]]) -> tuple[float, float, float]:
        """One tick: its SYNC's time stamp (NaN: not seen), the last command frame's time
        stamp before that SYNC, and the tick's frames as (device, time stamp). Returns
        (SYNC jitter, latest first answer, command margin) in ms, NaN where not measured.
        An answer stamped before the SYNC answers an earlier one and is not counted."""
        if self.source == "none":
            return NAN, NAN, NAN
        jitter = margin = latest = NAN
        prev = self._prev_sync
        self._prev_sync = sync_ts
        if sync_ts != sync_ts:  # no SYNC time stamp this tick
            return NAN, NAN, NAN
        self.syncs_seen += 1
        if self.paced and prev == prev:
            d = (sync_ts - prev) - self.dt_s
            self.jitter_s.add(abs(d))
            if d < self.jitter_min_s:
                self.jitter_min_s = d
            if d > self.jitter_max_s:
                self.jitter_max_s = d
            jitter = d * 1e3
            # a command of the previous tick: stamped after the previous SYNC
            if prev_cmd_ts == prev_cmd_ts and prev_cmd_ts > prev:
                m = sync_ts - prev_cmd_ts
                self.margin_s.add(m)
                if m < self.margin_min_s:
                    self.margin_min_s = m
                if m < 0.0:
                    self.late_commands += 1
                margin = m * 1e3
        first: dict[str, float] = {}
        for device, ts in answers:
            if ts >= sync_ts and (device not in first or ts < first[device]):
                first[device] = ts
        lat = self.latency_s
        for device, ts in first.items():
            x = ts - sync_ts
            hist = lat.get(device)
            if hist is not None:
                hist.add(x)
            if not latest >= x:  # NaN-safe max
                latest = x
        return jitter, latest * 1e3, margin

    def summary(self) -> dict[str, Any]:
        """summary.json's ``wire_timing``: where the time stamps came from and what they
        can say, and the percentiles (None where not measured)."""
        note = SOURCE_NOTES[self.source] + ("" if self.paced or self.source == "none"
                                            else LOCKSTEP_NOTE)
        out: dict[str, Any] = {"source": self.source, "note": note,
                               "sync_sent_by": self.sync_sent_by,
                               "syncs_time_stamped": self.syncs_seen}
        measured = self.source != "none"
        if measured and self.paced and self.jitter_s.n:
            out["sync_period_jitter_ms"] = {
                **self.jitter_s.percentiles_ms(),
                "min_signed": self.jitter_min_s * 1e3, "max_signed": self.jitter_max_s * 1e3}
        else:
            out["sync_period_jitter_ms"] = None
        out["answer_latency_ms"] = ({d: h.percentiles_ms() for d, h in self.latency_s.items()
                                     if h.n} if measured else None)
        if measured and self.paced and self.margin_s.n:
            out["command_margin_ms"] = {**self.margin_s.percentiles_ms(),
                                        "min": self.margin_min_s * 1e3,
                                        "commands_after_next_sync": self.late_commands}
        else:
            out["command_margin_ms"] = None
        return out
