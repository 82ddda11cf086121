"""Default Rerun layouts (blueprints), one per kind of run, chosen from the run itself.

Every plot holds signals of one quantity and one unit, named in its title, so that a small
signal never lies flat under a large one (the error has its own plot, torques are apart from
speeds, milliseconds apart from counts). Each plot lists its entities (``contents=``) instead
of taking a device's whole subtree, and shows the whole run (time axis fixed to
0..duration). Events (``/events/**``) are in a text log beside the plots and marked on the
plots at their time (``/markers/<plot>/<kind>``, see ``harness.review.events``); the run's
summary, its verdict (``/run/verdict``, from ``harness judge``) and its configuration are
text views. Every file written for one run (run.rrd, identify.rrd, verdict.rrd) carries the
same layout (``layout_for_run``), so opening them together in any order shows one layout.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import rerun.blueprint as rrb

KINDS = ("slew", "periodic", "free_decay", "thruster", "piezo")

SLEW_CONTROLLERS = {"pd_wheel", "shaped_wheel_slew"}
PERIODIC_CONTROLLERS = {"square_wave"}
FREE_DECAY_CONTROLLERS = {"wheel_bursts", "wheel_pulse", "valve_bursts", "hold"}
THRUSTER_PREFIX = "thruster_"


@dataclass(frozen=True)
class Plot:
    """One time plot: a key (also the marker group under ``/markers/<key>``), a title with
    the unit, and the channels it draws (same quantity, same unit)."""

    key: str
    title: str
    channels: tuple[str, ...]
    from_zero: bool = False  # counts and durations: the y axis always shows 0

    @property
    def marker_path(self) -> str:
        return f"/markers/{self.key}"


# every plot a run may get; the first channel of each is where its event markers sit
PLOTS: dict[str, Plot] = {p.key: p for p in (
    Plot("angle", "Hub angle: measured and reference (deg)",
         ("/attitude/angle_deg", "/attitude/reference_deg")),
    Plot("error", "Angle error: reference - measured (deg)", ("/attitude/error_deg",)),
    Plot("rate", "Hub rate (deg/s)", ("/attitude/rate_deg_s",)),
    Plot("wheel_torque", "Wheel torque: commanded and measured (N m)",
         ("/wheel/torque_cmd_n_m", "/wheel/torque_n_m")),
    Plot("wheel_speed", "Wheel speed (rad/s)", ("/wheel/speed_rad_s",)),
    Plot("tip", "Tip acceleration (m/s^2)", ("/tip/accel_m_s2",)),
    Plot("valves", "Valves: command and state (-1 / 0 / +1)",
         ("/thrusters/valve_cmd", "/thrusters/valve_state")),
    Plot("firings", "Valve firings (count)", ("/thrusters/firings",), from_zero=True),
    Plot("on_time", "Valve on-time, accumulated (s)", ("/thrusters/on_time_s",)),
    Plot("piezo_cmd", "Piezo command ch1, ch2 (V)", ("/piezo/cmd_ch1_v", "/piezo/cmd_ch2_v")),
    Plot("piezo_sensor", "Piezo sensor ch1, ch2 (V)",
         ("/piezo/sensor_ch1_v", "/piezo/sensor_ch2_v")),
    Plot("rotor_speed", "Disturbance rotor speed (rad/s)", ("/rotor/speed_rad_s",)),
    Plot("rotor_angle", "Disturbance rotor angle (rad)", ("/rotor/angle_rad",)),
    Plot("timing", "Loop timing: lateness and work (ms)",
         ("/timing/lateness_ms", "/timing/work_ms"), from_zero=True),
    Plot("wire", "Timing on the wire: SYNC jitter, last answer after SYNC, command margin "
         "(ms)", ("/timing/sync_jitter_ms", "/timing/answer_latency_ms",
                  "/timing/command_margin_ms")),
    Plot("frames", "Telemetry frames per tick: read, late or missing (count)",
         ("/timing/frames_rx", "/bus/late_or_missing"), from_zero=True),
)}

# the main plots of each kind of run, top to bottom, left column then right
MAIN_PLOTS: dict[str, tuple[str, ...]] = {
    "slew": ("angle", "error", "rate", "tip", "wheel_torque", "wheel_speed", "timing",
             "frames"),
    "periodic": ("tip", "angle", "wheel_torque", "rotor_speed", "wheel_speed", "rate",
                 "timing", "frames"),
    "free_decay": ("tip", "wheel_torque", "wheel_speed", "angle", "timing", "frames"),
    "thruster": ("angle", "error", "rate", "tip", "valves", "on_time", "timing", "frames"),
    "piezo": ("angle", "error", "tip", "piezo_cmd", "piezo_sensor", "valves", "timing",
              "frames"),
}

# the bus tab: telemetry decoded at its receive time, per device (harness.review.bus)
BUS_PLOTS: tuple[Plot, ...] = (
    Plot("bus_rx", "Telemetry receive time after its SYNC, per device (ms)",
         ("/bus/hub_sensor/rx_after_sync_ms", "/bus/accelerometer/rx_after_sync_ms",
          "/bus/reaction_wheel/rx_after_sync_ms", "/bus/thruster_valves/rx_after_sync_ms",
          "/bus/piezo_amplifier/rx_after_sync_ms", "/bus/disturbance_rotor/rx_after_sync_ms")),
    Plot("bus_missing", "Telemetry late or missing at its tick (count)",
         ("/bus/late_or_missing",)),
    Plot("bus_hub_angle", "HUB_TLM angle (rad)", ("/bus/hub_sensor/tlm/angle_rad",)),
    Plot("bus_hub_rate", "HUB_TLM rate (rad/s)", ("/bus/hub_sensor/tlm/rate_rad_s",)),
    Plot("bus_accel", "ACCEL_TLM accel (m/s^2)", ("/bus/accelerometer/tlm/accel_m_s2",)),
    Plot("bus_wheel_torque", "WHEEL_CMD torque_cmd and WHEEL_TLM torque (N m)",
         ("/bus/reaction_wheel/cmd/torque_cmd_n_m", "/bus/reaction_wheel/tlm/torque_n_m")),
    Plot("bus_wheel_speed", "WHEEL_TLM speed (rad/s)", ("/bus/reaction_wheel/tlm/speed_rad_s",)),
    Plot("bus_piezo", "PIEZO_CMD voltage (V)",
         ("/bus/piezo_amplifier/cmd/voltage_ch1_v", "/bus/piezo_amplifier/cmd/voltage_ch2_v")),
)

EVENTS_VIEW = "Events (faults, warnings, interrupts, verdict)"
SUMMARY_VIEW = "Run summary"
VERDICT_VIEW = "Verdict"
CONFIG_VIEW = "Configuration"
SPECTRUM_VIEW = "Spectrum of the final free decay: amplitude (m/s^2) vs frequency (Hz)"
WINDOWS_VIEW = "Spectra of the short free decays: amplitude (m/s^2) vs frequency (Hz)"
IDENTIFY_VIEW = "Identified modes"


def run_kind(run: Mapping[str, Any]) -> str:
    """The kind of a run (one of ``KINDS``) from its resolved config (``config.yaml``, or
    its ``run`` section): the controller type first (a controller with a ``piezo``
    section naming channels is a piezo run), then the actuators."""
    data = run.get("run", run)
    controller = data.get("controller") or {}
    ctype = str(controller.get("type", ""))
    actuators = set(data.get("actuators") or ())
    if ctype in SLEW_CONTROLLERS:
        return "slew"
    if ctype in PERIODIC_CONTROLLERS:
        return "periodic"
    if ctype in FREE_DECAY_CONTROLLERS:
        return "free_decay"
    piezo = controller.get("piezo")
    piezo_control = ctype.startswith("piezo") or (
        isinstance(piezo, dict) and bool(piezo.get("channels", True)))
    if piezo_control:
        return "piezo"
    if ctype.startswith(THRUSTER_PREFIX) or "thruster_valves" in actuators:
        return "thruster"
    if "piezo_amplifier" in actuators:
        return "piezo"
    if "disturbance_rotor" in actuators:
        return "periodic"
    return "slew" if "angle_deg" in (data.get("controller") or {}) else "free_decay"


def main_plots(kind: str, actuators: Iterable[str]) -> tuple[str, ...]:
    """The main plots of a kind of run; a free decay excited by the valves (no wheel) shows
    the valves instead of the wheel."""
    keys = MAIN_PLOTS[kind]
    acts = set(actuators)
    if kind == "free_decay" and "thruster_valves" in acts and "reaction_wheel" not in acts:
        swap = {"wheel_torque": "valves", "wheel_speed": "on_time"}
        keys = tuple(swap.get(k, k) for k in keys)
    return keys


def wire_measured(ranges: Mapping[str, Sequence[float]] | None) -> bool:
    """True if the run measured its timing on the wire (a kernel's or adapter's time
    stamps): a channel of the wire plot has a recorded range (unmeasured, they are NaN
    throughout and have none)."""
    return bool(ranges) and any(c in ranges for c in PLOTS["wire"].channels)


def whole_run_axis(end_s: float | None) -> rrb.TimeAxis | None:
    """The time axis of a plot fixed on the whole run, 0 .. where it ended (a faulted run's
    recording ends at the fault, not at the configured duration)."""
    if end_s is None or end_s <= 0:
        return None
    pad = 0.015 * float(end_s)  # so that the last label is not clipped
    return rrb.TimeAxis(view_range=rrb.TimeRange(
        start=rrb.TimeRangeBoundary.absolute(seconds=0.0),
        end=rrb.TimeRangeBoundary.absolute(seconds=float(end_s) + pad)))


AXIS_MARGIN = 0.08


def y_range(plot: Plot, ranges: Mapping[str, Sequence[float]] | None
            ) -> tuple[float, float] | None:
    """The span of a plot's channels' recorded extremes (None: the viewer's own); a
    count's plot always shows 0."""
    if not ranges:
        return None
    found = [ranges[c] for c in plot.channels if c in ranges
             and all(math.isfinite(x) for x in ranges[c][:2])]
    if not found:
        return None
    lo = min(r[0] for r in found)
    return (min(lo, 0.0) if plot.from_zero else lo), max(r[1] for r in found)


def axis_range(plot: Plot, ranges: Mapping[str, Sequence[float]] | None,
               bands: Mapping[str, Sequence[float]] | None = None
               ) -> tuple[float, float] | None:
    """The y axis of a plot: the data's span (and the limit band of a criterion judging one
    of its channels, ``bands``: channel -> [lo, hi]) with a small margin. Never widened to
    round numbers: a 5 deg slew on +-10 or a judged 0.02 deg error on +-100 hid the very
    thing a reviewer looks for."""
    yr = y_range(plot, ranges)
    ends = [] if yr is None else list(yr)
    for c in plot.channels:
        ends += [float(b) for b in (bands or {}).get(c, ())[:2]
                 if b is not None and math.isfinite(b)]
    if not ends:
        return None
    lo, hi = min(ends), max(ends)
    span = hi - lo
    if span <= 0.0:
        span = abs(hi) if hi != 0.0 else 1.0
    pad = AXIS_MARGIN * span
    return labelled_range(lo - pad, hi + pad)


MAX_LABELS = 6.0
"""The most labels a plot's y axis takes at one step of a power of ten: the viewer labels
its axis at powers of ten only (0.01, 0.1, ...) and drops a step whose labels would crowd a
plot of the default layout's height (about 120 points), so a span of 8.5 steps of 0.01
(a wheel torque of -0.025..0.06 N m) was labelled at 0.1: a single "0"."""


def labelled_range(lo: float, hi: float) -> tuple[float, float]:
    """``lo..hi`` widened as little as needed to hold two labels of the step the viewer
    will use (``MAX_LABELS``): an axis with a single label (a lone "0") has no scale."""
    span = hi - lo
    if not (math.isfinite(lo) and math.isfinite(hi)) or span <= 0.0:
        return lo, hi
    step = 10.0 ** math.floor(math.log10(span))
    if span / step > MAX_LABELS:
        step *= 10.0
    first, last = math.ceil(lo / step - 1e-9), math.floor(hi / step + 1e-9)
    if last - first >= 1:
        return lo, hi
    # the two neighbouring labels that widen the range least
    best = min(((min(lo, k * step), max(hi, (k + 1) * step))
                for k in range(math.floor(lo / step) - 1, math.ceil(hi / step) + 1)),
               key=lambda r: r[1] - r[0])
    edge = 0.03 * (best[1] - best[0])  # a label on the very edge is clipped
    return best[0] - (edge if best[0] < lo else 0.0), best[1] + (edge if best[1] > hi
                                                                 else 0.0)


def plot_aggregation(plot: Plot) -> str:
    """``Off`` when every channel of the plot is discrete, else ``MinMax`` (names.py)."""
    from harness.review.names import MIN_MAX, OFF, is_discrete

    return OFF if all(is_discrete(c) for c in plot.channels) else MIN_MAX


CORNERS = ("LeftTop", "RightTop", "LeftBottom", "RightBottom")
LEGEND_BOX = (0.4, 0.5)  # share of a plot's width and height a legend may cover


def legend_corners(time_s: Any, columns: Mapping[str, Any], duration_s: float,
                   ranges: Mapping[str, Sequence[float]], max_points: int = 4000
                   ) -> dict[str, str]:
    """For each plot, the corner where its legend hides the fewest of its samples (an
    opaque legend over the curve hid a faulted slew's angle): plot key -> corner."""
    import numpy as np

    t = np.asarray(time_s, dtype=float)
    if len(t) == 0 or duration_s <= 0:
        return {}
    step = max(1, len(t) // max_points)
    x = t[::step] / (duration_s * 1.015)
    w, h = LEGEND_BOX
    out: dict[str, str] = {}
    for plot in PLOTS.values():
        yr = axis_range(plot, ranges)
        cols = [np.asarray(columns[c], dtype=float)[::step] for c in plot.channels
                if c in columns]
        if yr is None or not cols:
            continue
        counts = dict.fromkeys(CORNERS, 0)
        for v in cols:
            y = (v - yr[0]) / (yr[1] - yr[0])
            ok = np.isfinite(y)
            left, right = x < w, x > 1 - w
            top, bottom = y > 1 - h, y < h
            counts["LeftTop"] += int(np.sum(ok & left & top))
            counts["RightTop"] += int(np.sum(ok & right & top))
            counts["LeftBottom"] += int(np.sum(ok & left & bottom))
            counts["RightBottom"] += int(np.sum(ok & right & bottom))
        out[plot.key] = min(CORNERS, key=lambda c: counts[c])  # ties: the earlier corner
    return out


def time_plot(plot: Plot, end_s: float | None, channels: Iterable[str] | None = None,
              ranges: Mapping[str, Sequence[float]] | None = None,
              legend: str = "LeftTop",
              bands: Mapping[str, Sequence[float]] | None = None) -> rrb.TimeSeriesView:
    """A plot of ``plot``'s channels (those recorded, if ``channels`` is given) and its event
    markers, on the whole run (0 .. ``end_s``); its y axis on ``ranges`` (channel ->
    recorded min, max) and ``bands`` with a margin, when given. Its series default to the
    plot's aggregation (``plot_aggregation``: peaks kept, discrete signals drawn whole)."""
    import rerun as rr

    recorded = None if channels is None else set(channels)
    contents = [c for c in plot.channels
                if recorded is None or c in recorded or c.startswith("/bus/")]
    contents.append(f"{plot.marker_path}/**")
    # a baseline run's copy of a judged channel, once the run is judged (review.verdict)
    contents += [f"/baseline{c}" for c in plot.channels if not c.startswith("/bus/")]
    yr = axis_range(plot, ranges, bands)
    return rrb.TimeSeriesView(
        name=plot.title, contents=contents, axis_x=whole_run_axis(end_s),
        axis_y=None if yr is None else rrb.ScalarAxis(range=yr, zoom_lock=False),
        plot_legend=rrb.PlotLegend(corner=legend),
        defaults=[rr.SeriesLines(aggregation_policy=plot_aggregation(plot))])


SEQUENCE_STEP = "/sequence/step"
"""A sequence's step timeline: the number of the step under way (0 between and after)."""


def sequence_plot(end_s: float | None) -> rrb.TimeSeriesView:
    """A sequence's steps over the run: which step was under way (its number, 1 first), with
    each step's end marked by its outcome (``harness.review.sequence``)."""
    import rerun as rr

    return rrb.TimeSeriesView(
        name="sequence: step under way", contents=[SEQUENCE_STEP, "/sequence/ends/**"],
        axis_x=whole_run_axis(end_s), plot_legend=rrb.PlotLegend(corner="LeftTop"),
        defaults=[rr.SeriesLines(aggregation_policy="Off")])


def events_view() -> rrb.TextLogView:
    """Every event (``/events/**``): its time, level and text (the viewer keeps the time
    and source columns narrow, so each text names its source and time itself)."""
    import rerun.blueprint.encodings as be

    kinds = be.TextLogColumnKind
    return rrb.TextLogView(
        origin="/events", name=EVENTS_VIEW,
        columns=rrb.TextLogColumns(
            timeline_columns=[be.TimelineColumn("time")],
            text_log_columns=[be.TextLogColumn(kinds.LogLevel),
                              be.TextLogColumn(kinds.Body),
                              be.TextLogColumn(kinds.EntityPath, visible=False)]))


def text_views(include_verdict: bool = True) -> rrb.Container:
    """The verdict on top, then the summary and the configuration in tabs."""
    docs = rrb.Tabs(
        rrb.TextDocumentView(origin="/run/summary", name=SUMMARY_VIEW),
        rrb.TextDocumentView(origin="/run/config", name=CONFIG_VIEW))
    if not include_verdict:
        return rrb.Vertical(docs)
    # the verdict gets the larger part: every criterion is on its own lines there
    return rrb.Vertical(rrb.TextDocumentView(origin="/run/verdict", name=VERDICT_VIEW), docs,
                        row_shares=[3, 2])


def spectrum_views() -> list[rrb.View]:
    """The identification (``harness identify`` writes identify.rrd): spectra as bar charts
    over frequency in Hz, one series per identified mode (its name in the legend)."""
    return [
        rrb.BarChartView(origin="/final", name=SPECTRUM_VIEW,
                         plot_legend=rrb.PlotLegend(corner="RightTop")),
        rrb.BarChartView(origin="/short", name=WINDOWS_VIEW,
                         plot_legend=rrb.PlotLegend(corner="RightTop")),
        rrb.TextDocumentView(origin="/identify/modes", name=IDENTIFY_VIEW),
    ]


def _grid(views: Sequence[rrb.View], columns: int = 2) -> rrb.Container:
    cols = [rrb.Vertical(*views[i::columns]) for i in range(columns)]
    return rrb.Horizontal(*cols)


def criterion_bands(run: Mapping[str, Any]) -> dict[str, list[float]]:
    """channel -> [lo, hi] of the limits a run's criteria (``expect:``) put on its samples:
    a ``channel:`` band (``max_abs_*``, ``max_*``, ``min_*`` with ``reduce: each``) or a
    ``settles:`` band, so that a judged channel's plot shows its limit."""
    data = run.get("run", run)
    expect = data.get("expect") or run.get("expect") or {}
    items = expect.values() if isinstance(expect, Mapping) else expect
    out: dict[str, list[float]] = {}

    def widen(channel: str, lo: float, hi: float) -> None:
        if math.isfinite(lo) and math.isfinite(hi):
            cur = out.get(channel)
            out[channel] = [lo, hi] if cur is None else [min(cur[0], lo), max(cur[1], hi)]

    for c in items if isinstance(items, Iterable) else ():
        if not isinstance(c, Mapping):
            continue
        try:
            if isinstance(c.get("settles"), str):
                centre = float(c.get("center_deg", 0.0) or 0.0)
                band = next((float(v) for k, v in c.items() if k.startswith("band_")), None)
                if band is not None:
                    widen(c["settles"], centre - band, centre + band)
            elif isinstance(c.get("channel"), str) and "baseline" not in c \
                    and c.get("reduce", "each") == "each":
                for k, v in c.items():
                    if isinstance(v, bool) or not isinstance(v, int | float):
                        continue
                    if k.startswith("max_abs_"):
                        widen(c["channel"], -float(v), float(v))
                    elif k.startswith("max_") and not k.startswith("max_shift"):
                        widen(c["channel"], float(v), float(v))
                    elif k.startswith("min_"):
                        widen(c["channel"], float(v), float(v))
        except (TypeError, ValueError):  # judged and refused elsewhere; no band drawn
            continue
    return out


def layout_for_run(run: Mapping[str, Any], channels: Iterable[str] | None = None,
                   ranges: Mapping[str, Sequence[float]] | None = None,
                   legends: Mapping[str, str] | None = None,
                   end_s: float | None = None) -> rrb.Blueprint:
    """The default layout of a run from its resolved config (``RunConfig.resolved()`` or
    config.yaml, or its ``run`` section) and its recorded channels: the main plots of its
    kind in two columns, the text views on the right; the bus, the other devices and the
    identification in tabs. ``end_s``: where the recording ends (default: the configured
    duration)."""
    data = run.get("run", run)
    kind = run_kind(data)
    end = end_s if end_s is not None else data.get("duration_s")
    chans = list(channels) if channels is not None else None
    corner = dict(legends or {})
    bands = criterion_bands(run)
    keys = main_plots(kind, data.get("actuators") or ())
    if "timing" in keys and wire_measured(ranges):
        # a real bus's timing on the wire beside the loop's: a reviewer of a real-time run
        # sees whether the bus held the rate without opening another tab
        at = keys.index("timing") + 1
        keys = (*keys[:at], "wire", *keys[at:])
    main = [time_plot(PLOTS[k], end, chans, ranges, corner.get(k, "LeftTop"), bands)
            for k in keys]
    if data.get("sequence"):
        main.append(sequence_plot(end))
    if kind == "free_decay":
        spec = spectrum_views()
        run_page: rrb.Container = rrb.Vertical(
            _grid(main), rrb.Horizontal(spec[0], spec[1], spec[2], column_shares=[3, 3, 3]),
            row_shares=[3, 2], name="Run")
    else:
        run_page = rrb.Vertical(_grid(main), name="Run")
    shown = set(keys)
    others = [time_plot(p, end, chans, ranges, corner.get(k, "LeftTop"), bands)
              for k, p in PLOTS.items() if k not in shown]
    bus = [time_plot(p, end) for p in BUS_PLOTS]
    tabs = [run_page,
            rrb.Vertical(_grid(bus), name="CAN bus (decoded at receive time)"),
            rrb.Vertical(_grid(others), name="Other signals")]
    if kind != "free_decay":
        spec = spectrum_views()
        tabs.append(rrb.Vertical(rrb.Horizontal(spec[0], spec[1]), spec[2],
                                 row_shares=[2, 1], name="Identification"))
    left = rrb.Vertical(rrb.Tabs(*tabs, active_tab=0), events_view(), row_shares=[5, 1])
    root = rrb.Horizontal(left, text_views(), column_shares=[3, 1])
    return rrb.Blueprint(root, rrb.TimePanel(timeline="time", state="collapsed"),
                         collapse_panels=True)


LAYOUT_FILE = "layout.json"
"""Beside run.rrd: the recorded extremes of each channel and each plot's legend corner, so
that every file written later for the run (identify.rrd, verdict.rrd) carries the very
layout run.rrd has."""


def channel_ranges(columns: Mapping[str, Any]) -> dict[str, list[float]]:
    """channel -> [min, max] of its finite values (channels with none are left out)."""
    import numpy as np

    out: dict[str, list[float]] = {}
    for c, v in columns.items():
        a = np.asarray(v, dtype=float)
        a = a[np.isfinite(a)]
        if len(a):
            out[c] = [float(a.min()), float(a.max())]
    return out


def write_layout_file(run_dir: Path, ranges: Mapping[str, Sequence[float]],
                      legends: Mapping[str, str] | None = None,
                      end_s: float | None = None,
                      channels: Iterable[str] | None = None) -> Path:
    """layout.json: each channel's y range and legend corner, the time axis's end, and the
    recorded channels (``channels``; a channel recorded as NaN throughout, such as a timing
    on the wire not measured, has no range but keeps its place in the layout)."""
    path = run_dir / LAYOUT_FILE
    doc: dict[str, Any] = {"y_ranges": {c: list(r) for c, r in ranges.items()},
                           "legends": dict(legends or {})}
    if channels is not None:
        doc["channels"] = list(channels)
    if end_s is not None and math.isfinite(end_s):
        doc["end_s"] = float(end_s)
    path.write_text(json.dumps(doc, indent=1))
    return path


def blueprint_for_run_dir(run_dir: Path) -> rrb.Blueprint:
    """The layout of a recorded run from its config.yaml and layout.json: what run.rrd
    carries. Writers of other files for the run (identify.rrd, verdict.rrd) pass it as their
    ``default_blueprint`` so that the files open together in any order. The recorded
    channels are layout.json's (its ``channels``, or in an older file those with values);
    without it, every plot's channels."""
    import yaml

    cfg = yaml.safe_load((run_dir / "config.yaml").read_text())
    layout = run_dir / LAYOUT_FILE
    saved = json.loads(layout.read_text()) if layout.exists() else {}
    ranges = saved.get("y_ranges")
    channels = saved.get("channels", None if ranges is None else list(ranges))
    return layout_for_run(cfg, channels, ranges, saved.get("legends"), saved.get("end_s"))


def study_layout(curves: Mapping[str, Sequence[str]], timeline: str,
                 texts: Mapping[str, str] | None = None,
                 tensors: Mapping[str, str] | None = None,
                 x_range: tuple[int, int] | None = None,
                 images: Mapping[str, str] | None = None,
                 bars: Mapping[str, str] | None = None) -> rrb.Blueprint:
    """A layout for a sweep, study or calibration: one plot per entry of ``curves`` (title
    with its unit -> entity paths, each plot one quantity) over ``timeline`` (the swept
    variable as a sequence timeline, its scale in its name), its x axis on ``x_range``
    (first, last value on the timeline: the whole sweep in view, not the viewer's own
    window), optional tensor maps, images (title -> entity: a map drawn with its colour
    scale), bar charts (title -> origin) and text documents (title -> entity) on the right."""
    axis = None if x_range is None else rrb.TimeAxis(view_range=rrb.TimeRange(
        start=rrb.TimeRangeBoundary.absolute(seq=int(x_range[0])),
        end=rrb.TimeRangeBoundary.absolute(seq=int(x_range[1]))))
    plots: list[rrb.View] = [
        rrb.TimeSeriesView(name=title, contents=list(paths), axis_x=axis,
                           plot_legend=rrb.PlotLegend(corner="RightTop"))
        for title, paths in curves.items()]
    plots += [rrb.BarChartView(origin=path, name=title,
                               plot_legend=rrb.PlotLegend(corner="RightTop"))
              for title, path in (bars or {}).items()]
    plots += [rrb.TensorView(origin=path, name=title) for title, path in (tensors or {}).items()]
    plots += [rrb.Spatial2DView(origin=path, name=title) for title, path in (images or {}).items()]
    left = _grid(plots, 2 if len(plots) > 2 else 1)
    docs = [rrb.TextDocumentView(origin=path, name=title) for title, path in (texts or {}).items()]
    root: rrb.Container = rrb.Horizontal(left, rrb.Vertical(*docs), column_shares=[3, 1]) \
        if docs else left
    return rrb.Blueprint(root, rrb.TimePanel(timeline=timeline, state="collapsed"),
                         collapse_panels=True)


def blueprint_views(bp: rrb.Blueprint) -> list[rrb.View]:
    """Every view in a blueprint (depth first), for tests and docs."""
    out: list[rrb.View] = []

    def walk(node: Any) -> None:
        if isinstance(node, rrb.View):
            out.append(node)
        elif isinstance(node, rrb.Container):
            for c in node.contents:
                walk(c)

    walk(bp.root_container)
    return out


class PlotStats:
    """What a run's final layout needs, gathered block by block in bounded memory: each
    channel's extremes, and a decimated copy of the rows (at most ``max_rows``; when full,
    every other row is dropped and the stride doubles) for ``legend_corners``. Feed it with
    ``add(time_s, rows)`` (rows: one column per channel), e.g. as a Recorder block
    observer, then ``ranges()`` and ``legends(duration_s)``."""

    def __init__(self, channels: Sequence[str], max_rows: int = 4096) -> None:
        import numpy as np

        self.channels = list(channels)
        self.max_rows = max_rows
        self.lo = np.full(len(self.channels), np.inf)
        self.hi = np.full(len(self.channels), -np.inf)
        self.stride = 1
        self._skip = 0  # rows to skip before the next one kept
        self.t: list[float] = []
        self.rows: list[Any] = []
        self.end_s: float | None = None  # the last row's time: where the recording ends

    def add(self, time_s: Any, rows: Any) -> None:
        import numpy as np

        t = np.asarray(time_s, dtype=float)
        data = np.asarray(rows, dtype=float).reshape(len(t), len(self.channels))
        if not len(t):
            return
        self.end_s = float(t[-1]) if self.end_s is None else max(self.end_s, float(t[-1]))
        with np.errstate(invalid="ignore"):
            self.lo = np.fmin(self.lo, np.nanmin(np.where(np.isfinite(data), data, np.nan),
                                                 axis=0, initial=np.inf))
            self.hi = np.fmax(self.hi, np.nanmax(np.where(np.isfinite(data), data, np.nan),
                                                 axis=0, initial=-np.inf))
        i = self._skip
        while i < len(t):
            self.t.append(float(t[i]))
            self.rows.append(data[i].copy())
            if len(self.t) >= self.max_rows:
                self.t = self.t[::2]
                self.rows = self.rows[::2]
                self.stride *= 2
            i += self.stride
        self._skip = i - len(t)

    def ranges(self) -> dict[str, list[float]]:
        import math as m

        return {c: [float(a), float(b)] for c, a, b in zip(self.channels, self.lo, self.hi,
                                                          strict=True)
                if m.isfinite(a) and m.isfinite(b)}

    def legends(self, duration_s: float) -> dict[str, str]:
        import numpy as np

        if not self.t:
            return {}
        data = np.array(self.rows)
        cols = {c: data[:, i] for i, c in enumerate(self.channels)}
        return legend_corners(np.array(self.t), cols, duration_s, self.ranges())
