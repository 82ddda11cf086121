"""Events in a recording: the text log under ``/events/<source>`` and a marker on every time
plot at the event's time, and the run's summary as a markdown table.

A marker is a point of the plot's own first signal at the event's time (so it sits on the
curve, at the plot's scale) in a series per kind of event (``/markers/<plot>/<kind>``), its
name in the plot's legend. Kinds: ``fault`` (``/events/<device>``, level ERROR),
``interrupt`` / ``error`` (``/events/harness``), ``warning`` (``/events/monitor``, one
series per kind of warning, ``/markers/<plot>/warning/<kind>``; ``/events/can_log`` is not
marked) and ``verdict`` (``/events/verdict``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import rerun as rr

from harness.review.layouts import PLOTS

MARKER_STYLE: dict[str, tuple[str, tuple[int, int, int], float]] = {
    # kind: (marker shape, colour, size in ui points)
    "fault": ("cross", (230, 20, 20), 14.0),
    "error": ("cross", (230, 20, 20), 14.0),
    "interrupt": ("diamond", (255, 140, 0), 12.0),
    "warning": ("up", (240, 190, 0), 10.0),
    "verdict": ("asterisk", (200, 0, 200), 14.0),
    "step": ("square", (200, 60, 20), 11.0),  # a sequence's step that did not pass
}
MAX_LABEL = 48


def event_kind(entity: str, level: str) -> str:
    source = entity.rstrip("/").rsplit("/", 1)[-1]
    if source == "verdict":
        return "verdict"
    if source == "sequence":
        return "step" if level in ("ERROR", "CRITICAL") else "warning"
    if source in ("monitor", "can_log"):
        return "warning"
    if source == "harness":
        return "error" if level in ("ERROR", "CRITICAL") else "interrupt"
    return "fault" if level in ("ERROR", "CRITICAL") else "warning"


def marker_name(kind: str, text: str) -> str:
    """The legend's name of a marker: the kind and the event's source and what happened
    (``FAULT hub_sensor: silent``), not its whole message (that is in the event log)."""
    head = ": ".join(text.split(": ")[:2])
    label = f"{kind.upper()} {head}"
    return label if len(label) <= MAX_LABEL else label[: MAX_LABEL - 3] + "..."


def log_event(rec: rr.RecordingStream, time_s: float, entity: str, text: str,
              level: str = "WARN", values: Mapping[str, float] | None = None,
              name: str | None = None, series: str | None = None) -> None:
    """``text`` as a TextLog at ``entity`` (``/events/...``) at ``time_s`` on the ``time``
    timeline, and a marker on every plot whose first signal's value at that time is in
    ``values`` (channel -> value; NaN and missing channels are skipped), in the series
    ``/markers/<plot>/<series>`` (default: the event's kind)."""
    rec.set_time("time", duration=time_s)
    rec.log(entity, rr.TextLog(text, level=level))
    if values:
        kind = event_kind(entity, level)
        log_markers(rec, time_s, kind, name or marker_name(kind, text), values, series)


def log_markers(rec: rr.RecordingStream, time_s: float, kind: str, name: str,
                values: Mapping[str, float], series: str | None = None) -> int:
    """One marker per plot at ``time_s`` (see module docstring) in the series
    ``/markers/<plot>/<series or kind>``; returns how many."""
    shape, colour, size = MARKER_STYLE.get(kind, MARKER_STYLE["warning"])
    rec.set_time("time", duration=time_s)
    n = 0
    for plot in PLOTS.values():
        value = next((values[c] for c in plot.channels
                      if c in values and not math.isnan(values[c])), None)
        if value is None:
            continue
        rec.log(f"{plot.marker_path}/{series or kind}", rr.Scalars(float(value)), rr.SeriesPoints(
            names=name, markers=shape, colors=[colour], marker_sizes=size))
        n += 1
    return n


def _fmt(v: Any) -> str:
    if v is None:
        return "-"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        if math.isnan(v):
            return "-"
        return f"{v:.6g}"
    if isinstance(v, dict):
        return ", ".join(f"{k} {_fmt(x)}" for k, x in v.items())
    if isinstance(v, list):
        return "; ".join(_fmt(x) for x in v) if v else "none"
    return str(v).replace("|", "\\|").replace("\n", " ")


# the rows of the summary table, in this order (others follow under "More")
SUMMARY_ROWS: tuple[tuple[str, str], ...] = (
    ("stopped_by", "ended by"),
    ("error", "error"),
    ("clock", "clock"),
    ("bus", "bus"),
    ("rate_hz", "rate (Hz)"),
    ("simulated_time_s", "simulated time (s)"),
    ("target_angle_deg", "target angle (deg)"),
    ("final_angle_deg", "final angle (deg)"),
    ("final_angle_error_deg", "final angle error (deg)"),
    ("settle_time_s", "settle time (s)"),
    ("settle_band_deg", "settle band (deg)"),
    ("peak_tip_accel_m_s2", "peak tip acceleration (m/s^2)"),
    ("residual_tip_accel_m_s2", "residual tip acceleration, peak (m/s^2)"),
    ("residual_tip_accel_rms_m_s2", "residual tip acceleration, rms (m/s^2)"),
    ("steady_tip_accel_amplitude_m_s2", "steady tip acceleration amplitude (m/s^2)"),
    ("beta", "beta"),
    ("frequency_ratio", "frequency ratio lambda"),
    ("max_wheel_torque_cmd_n_m", "peak wheel torque commanded (N m)"),
    ("max_wheel_torque_measured_n_m", "peak wheel torque measured (N m)"),
    ("wheel_torque_limit_n_m", "wheel torque limit (N m)"),
    ("overruns", "overruns"),
    ("lateness_ms", "lateness (ms)"),
    ("wire_timing", "timing on the wire (ms)"),
    ("work_ms", "work per tick (ms)"),
    ("bus_load_percent", "bus load, worst case (%)"),
    ("frames", "frames"),
    ("monitor_warnings", "monitor warnings"),
    ("wall_time_s", "wall time (s)"),
    ("real_time_factor", "real-time factor"),
)
HIDDEN = {"run", "ticks", "faults", "injected_faults", "controller_design", "virtual_rig",
          "realtime_measures", "residual_window_s", "dry_run"}


def summary_markdown(summary: Mapping[str, Any]) -> str:
    """The run's summary (summary.json) as markdown: a headline saying how it ended, its
    faults, then a table of the measured values with their units."""
    name = summary.get("run", "run")
    ended = summary.get("stopped_by", "?")
    faults = summary.get("faults") or []
    lines = [f"# {name}: {ended}"]
    if faults:
        lines.append("")
        for f in faults:
            lines.append(f"**FAULT** at {_fmt(f.get('time_s'))} s: {f.get('device')}: "
                         f"{f.get('kind')}: {f.get('message')}" if isinstance(f, dict)
                         else f"**FAULT** {f}")
    if summary.get("error"):
        lines += ["", f"**{summary['error']}**"]
    injected = summary.get("injected_faults") or []
    if injected:
        lines += ["", "Injected: " + "; ".join(
            f"{i.get('kind')} at {_fmt(i.get('at_s'))} s"
            + (f" on {i['device']}" if i.get("device") else "") for i in injected)]
    lines += ["", "| quantity | value |", "|---|---|"]
    shown = set()
    for key, label in SUMMARY_ROWS:
        value = summary.get(key)
        if value in (None, "", []):
            pass
        elif key == "monitor_warnings" and isinstance(value, dict):
            lines.append(f"| {label} | " + (", ".join(
                f"{k.replace('_', ' ')} {n}" for k, n in value.items() if n) or "none") + " |")
        elif key == "wire_timing" and isinstance(value, dict):
            lines += [f"| {a} | {b} |" for a, b in wire_timing_rows(value)]
        elif key == "frames" and isinstance(value, dict):
            lines += [f"| frames {k.replace('_', ' ')} | {_fmt(v)} |" for k, v in value.items()]
        else:
            lines.append(f"| {label} | {_fmt(value)} |")
        shown.add(key)
    for key, v in summary.items():
        if key in shown or key in HIDDEN or isinstance(v, dict | list):
            continue
        if v not in (None, ""):
            lines.append(f"| {key} | {_fmt(v)} |")
    return "\n".join(lines) + "\n"


def wire_timing_rows(w: Mapping[str, Any]) -> list[tuple[str, str]]:
    """summary.json's ``wire_timing`` as table rows (label, value): where its time stamps
    come from and what they say, then each figure's percentiles."""
    rows = [("timing on the wire: source",
             f"{_fmt(w.get('source'))} (SYNC sent by {_fmt(w.get('sync_sent_by'))}): "
             f"{_fmt(w.get('note'))}")]
    if w.get("sync_period_jitter_ms"):
        rows.append(("SYNC period jitter on the wire (ms)", _fmt(w["sync_period_jitter_ms"])))
    for device, p in (w.get("answer_latency_ms") or {}).items():
        rows.append((f"answer latency after SYNC, {device.replace('_', ' ')} (ms)", _fmt(p)))
    if w.get("command_margin_ms"):
        rows.append(("command margin before the next SYNC (ms)", _fmt(w["command_margin_ms"])))
    return rows


def values_at(rrd: Path, times_s: Sequence[float]) -> list[dict[str, float]]:
    """For each time, every plotted channel's recorded value at the last row at or before it
    (one streaming pass over the recording; memory bounded by the chunk size)."""
    from harness.record.reader import iter_chunks

    wanted = {c for p in PLOTS.values() for c in p.channels if not c.startswith("/bus/")}
    times = np.asarray(times_s, dtype=float)
    out: list[dict[str, float]] = [{} for _ in times]
    best: list[dict[str, float]] = [{} for _ in times]  # channel -> time of the value kept
    for chunk in iter_chunks(rrd, content=sorted(wanted)):
        entity = chunk.entity_path
        if entity not in wanted or chunk.is_static or "time" not in chunk.timeline_names:
            continue
        batch = chunk.to_record_batch()
        t = batch.column("time").cast("int64").to_numpy(zero_copy_only=False) * 1e-9
        if not len(t):
            continue
        v = batch.column("Scalars:scalars").to_pylist()
        order = np.argsort(t, kind="stable")
        t = t[order]
        for i, ti in enumerate(times):
            k = int(np.searchsorted(t, ti + 1e-9, side="right")) - 1
            if k < 0 or best[i].get(entity, -np.inf) >= t[k]:
                continue
            x = v[int(order[k])]
            best[i][entity] = float(t[k])
            out[i][entity] = float(x[0] if isinstance(x, list) else x)
    return out


def mark_events(rec: rr.RecordingStream, run_rrd: Path,
                events: Sequence[tuple[float, str, str]]) -> int:
    """Markers for events written into another file of the run (verdict.rrd): each
    ``(time_s, kind, name)`` marked on every plot at the run's signal values at that time
    (read from ``run_rrd``). Returns how many markers were logged."""
    if not events:
        return 0
    vals = values_at(run_rrd, [e[0] for e in events])
    return sum(log_markers(rec, t, kind, name, v, marker_series(kind, name))
               for (t, kind, name), v in zip(events, vals, strict=True))


def marker_series(kind: str, name: str) -> str:
    """A marker's series under ``/markers/<plot>/``: a verdict's per criterion
    (``verdict/<criterion>``: a legend names the series' last name, so criteria sharing one
    series all showed the last criterion's), the others per kind."""
    if kind != "verdict":
        return kind
    words = name.split()
    criterion = words[1] if len(words) > 1 and words[0] == "VERDICT" else name
    safe = "".join(ch if ch.isalnum() or ch in "_-" else "_" for ch in criterion)
    return f"verdict/{safe or 'criterion'}"
