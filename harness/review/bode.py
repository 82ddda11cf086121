"""The frequency responses in a recording (``frf.rrd``): Bode plots beside the rig model's.

Rerun's plots are over a timeline; here the timeline is the frequency, a sequence in mHz
(``frequency_mhz``: an integer, its scale in its name; the multisine's 0.025 Hz grid is 25
of them). Per output ``OUT`` of ``harness frf``'s document:

- ``/frf/OUT/magnitude_db/``: the measured H1 (``measured``), its 1-sigma band
  (``plus_1_sigma``, ``minus_1_sigma``: 20 log10 (|H| (1 +- sigma))), the rig model's
  (``model``) and the modal fit's (``fit``), in dB re 1 SI unit of the output per SI unit of
  the input;
- ``/frf/OUT/phase_deg/``: the same in degrees (the measured phase unwrapped, the model's
  shifted by whole turns to start next to it; the band +- sigma in radians);
- ``/frf/OUT/coherence/``: the coherence and the 0.9 line;
- ``/frf/modes``: the modes' table (markdown), fitted against the model's.

The layout (``bode_blueprint``) puts each output in a tab (magnitude, phase, coherence over
the whole band; the tip acceleration's in front), one magnitude plot per fitted mode zoomed
on it (+-20 %), and the table, so that the recording opens on the plots. Its own
application id: opened beside run.rrd, each keeps its own layout.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from harness.record.recording import close_stream
from harness.record.streams import save_with_blueprint, sweep_orphans

APPLICATION_ID = "sgsrt-harness-frf"
TIMELINE = "frequency_mhz"
MODES_ENTITY = "/frf/modes"
COHERENCE_LIMIT = 0.9
ZOOM_SPAN = 0.2
"""A mode's zoomed plot spans its frequency x (1 -+ this)."""

COLOURS = {"measured": (31, 119, 180), "plus_1_sigma": (140, 180, 225),
           "minus_1_sigma": (140, 180, 225), "model": (20, 20, 20), "fit": (214, 39, 40),
           "coherence": (44, 160, 44), "limit": (150, 150, 150)}
NAMES = {"measured": "measured H1", "plus_1_sigma": "H1 +1 sigma",
         "minus_1_sigma": "H1 -1 sigma", "model": "rig model", "fit": "modal fit",
         "coherence": "coherence", "limit": "0.9"}
SHORT = {"hub_rate": "hub", "tip_accel": "tip", "piezo_sensor1": "sensor1",
         "piezo_sensor2": "sensor2"}
"""An output's name in a zoomed plot's title (a narrow plot cuts its title short)."""
WIDTHS = {"measured": 2.0, "model": 1.5, "fit": 1.0}


def mhz(freq_hz: Sequence[float] | np.ndarray) -> np.ndarray:
    """Frequencies in Hz as the timeline's integers (mHz)."""
    return np.round(np.asarray(freq_hz, dtype=float) * 1000.0).astype(np.int64)


def _db(x: np.ndarray) -> np.ndarray:
    return 20.0 * np.log10(np.maximum(np.abs(x), 1e-300))


def bode_curves(entry: Mapping[str, Any]) -> dict[str, dict[str, np.ndarray]]:
    """One output's curves: {"magnitude_db" | "phase_deg" | "coherence": {series: values}}
    on the output's frequencies."""
    mag = np.asarray(entry["h1_mag"], dtype=float)
    sig = np.asarray(entry["sigma_mag_rel"], dtype=float)
    ph = np.unwrap(np.asarray(entry["h1_phase_rad"], dtype=float))
    mph = np.unwrap(np.asarray(entry["model_phase_rad"], dtype=float))
    mph += 2 * math.pi * np.round((ph[0] - mph[0]) / (2 * math.pi))
    magnitude = {"measured": _db(mag), "plus_1_sigma": _db(mag * (1 + sig)),
                 "minus_1_sigma": _db(mag * np.maximum(1 - sig, 1e-6)),
                 "model": _db(np.asarray(entry["model_mag"], dtype=float))}
    if "fit_mag" in entry:
        magnitude["fit"] = _db(np.asarray(entry["fit_mag"], dtype=float))
    phase = {"measured": np.degrees(ph), "plus_1_sigma": np.degrees(ph + sig),
             "minus_1_sigma": np.degrees(ph - sig), "model": np.degrees(mph)}
    coh = np.asarray(entry["coherence"], dtype=float)
    return {"magnitude_db": magnitude, "phase_deg": phase,
            "coherence": {"coherence": coh, "limit": np.full(len(coh), COHERENCE_LIMIT)}}


def axis_ends_mhz(f0_hz: float, f1_hz: float) -> tuple[int, int]:
    """The x axis's ends for f0..f1: whole steps of a power of ten, in mHz."""
    lo, hi = f0_hz * 1000.0, f1_hz * 1000.0
    step = 10.0 ** math.floor(math.log10(max(hi - lo, 1.0)))
    return int(math.floor(lo / step) * step), int(math.ceil(hi / step) * step)


def _axis(ends: tuple[int, int]) -> rrb.TimeAxis:
    return rrb.TimeAxis(view_range=rrb.TimeRange(
        start=rrb.TimeRangeBoundary.absolute(seq=ends[0]),
        end=rrb.TimeRangeBoundary.absolute(seq=ends[1])))


def _range(values: Sequence[np.ndarray], pad: float = 0.05) -> tuple[float, float]:
    v = np.concatenate([np.asarray(x)[np.isfinite(x)] for x in values])
    lo, hi = float(v.min()), float(v.max())
    span = hi - lo or 1.0
    return lo - pad * span, hi + pad * span


CORNERS = ("RightTop", "LeftBottom", "RightBottom", "LeftTop")
LEGEND_BOX = (0.35, 0.45)
"""The share of a plot's width and height its legend covers (five lines)."""


def legend_corner(f: np.ndarray, y: np.ndarray, y_range: tuple[float, float]) -> str:
    """The corner of a plot where its legend hides the fewest points of ``y`` (an opaque
    legend over a resonance hid the very thing a reviewer looks for)."""
    x = (f - f[0]) / max(f[-1] - f[0], 1e-12)
    v = (y - y_range[0]) / (y_range[1] - y_range[0])
    w, h = LEGEND_BOX
    boxes = {"RightTop": (x > 1 - w) & (v > 1 - h), "LeftBottom": (x < w) & (v < h),
             "RightBottom": (x > 1 - w) & (v < h), "LeftTop": (x < w) & (v > 1 - h)}
    return min(CORNERS, key=lambda c: int(np.sum(boxes[c])))


def bode_blueprint(doc: Mapping[str, Any]) -> rrb.Blueprint:
    """The layout (see the module docstring) of ``harness frf``'s document."""
    columns: list[rrb.Container] = []
    zooms: list[rrb.View] = []
    for out, e in doc["outputs"].items():
        f = np.asarray(e["freq_hz"], dtype=float)
        pad = 0.01 * (f[-1] - f[0])
        axis = _axis(axis_ends_mhz(max(f[0] - pad, 0.0), f[-1] + pad))
        curves = bode_curves(e)
        base = f"/frf/{out}"
        unit = e["unit"]
        mag = curves["magnitude_db"]
        # the axis on the measured, the model and the fit; the -1 sigma line where the
        # coherence is low (sigma near 1) runs off it
        mag_range = _range([v for k, v in mag.items() if k != "minus_1_sigma"])
        phase_range = _range([v for k, v in curves["phase_deg"].items()
                              if k in ("measured", "model")])
        views = [
            rrb.TimeSeriesView(
                name=f"{doc['input']} -> {out}: |H| (dB re 1 {unit}) vs frequency (mHz)",
                origin=f"{base}/magnitude_db", axis_x=axis,
                axis_y=rrb.ScalarAxis(range=mag_range, zoom_lock=False),
                plot_legend=rrb.PlotLegend(corner=legend_corner(
                    f, mag["measured"], mag_range))),
            rrb.TimeSeriesView(
                name=f"{out}: phase (deg), colours as above, vs frequency (mHz)",
                origin=f"{base}/phase_deg", axis_x=axis,
                axis_y=rrb.ScalarAxis(range=phase_range, zoom_lock=False),
                plot_legend=rrb.PlotLegend(visible=False)),
            rrb.TimeSeriesView(
                name=f"{out}: coherence (grey: 0.9) vs frequency (mHz)",
                origin=f"{base}/coherence", axis_x=axis,
                axis_y=rrb.ScalarAxis(range=(0.0, 1.05), zoom_lock=False),
                plot_legend=rrb.PlotLegend(visible=False))]
        columns.append(rrb.Vertical(*views, row_shares=[3, 2, 1.5], name=out))
        for m in e.get("modes", []):
            fm = float(m["freq_hz"])
            ends = axis_ends_mhz(fm * (1 - ZOOM_SPAN), fm * (1 + ZOOM_SPAN))
            near = (f * 1000 >= ends[0]) & (f * 1000 <= ends[1])
            if near.sum() < 2:
                continue
            zooms.append(rrb.TimeSeriesView(
                name=f"{SHORT.get(out, out)} mode {m['model_mode']}: {fm:.3f} Hz",
                origin=f"{base}/magnitude_db", axis_x=_axis(ends),
                axis_y=rrb.ScalarAxis(range=_range(
                    [v[near] for k, v in mag.items() if k != "minus_1_sigma"]),
                    zoom_lock=False),
                plot_legend=rrb.PlotLegend(visible=False)))
    right: list[rrb.Container | rrb.View] = []
    if zooms:
        n = math.ceil(len(zooms) / 2)
        right.append(rrb.Horizontal(rrb.Vertical(*zooms[:n]), rrb.Vertical(*zooms[n:]))
                     if len(zooms) > 1 else zooms[0])
    right.append(rrb.TextDocumentView(origin=MODES_ENTITY, name="Modes from the FRF"))
    # one output at a time over the whole band (a tab each): plots half as wide left the
    # frequency axis without labels
    # the tip's tab in front when there is one (it sees every mode; the hub rate hardly
    # sees mode 3, a collocated pole-zero pair)
    outs = list(doc["outputs"])
    front = outs.index("tip_accel") if "tip_accel" in outs else 0
    main = rrb.Tabs(*columns, active_tab=front) if len(columns) > 1 else columns[0]
    root = rrb.Horizontal(main, rrb.Vertical(*right, row_shares=[5, 2][:len(right)]),
                          column_shares=[3, 2])
    return rrb.Blueprint(root, rrb.TimePanel(timeline=TIMELINE, state="collapsed"),
                         collapse_panels=True)


def modes_markdown(doc: Mapping[str, Any]) -> str:
    """The modes fitted to each output's H1 beside the model's, one line a mode."""
    lines = [f"## Modes from the FRF ({doc['input']} input)", "",
             "| output | mode | f (Hz) | zeta | f / model | zeta / model | coh |",
             "|---|---|---|---|---|---|---|"]
    for out, e in doc["outputs"].items():
        for m in e.get("modes", []):
            lines.append(
                f"| {out} | {m['model_mode']} | {m['freq_hz']:.4f} +- "
                f"{m['sigma_omega_rad_s'] / (2 * math.pi):.4f} | {m['damping_ratio']:.4f} +- "
                f"{m['sigma_damping']:.4f} | {m['omega_rad_s'] / m['model_omega_rad_s']:.4f} | "
                f"{m['damping_ratio'] / m['model_damping_ratio']:.3f} | "
                f"{m['coherence_at_mode']:.3f} |"
                + ("" if m.get("determined", True) else " not determined"))
    lines += ["", "f: undamped natural frequency; zeta: damping ratio; +-: 1 sigma; "
              "coh: coherence at the line nearest the mode. Plots: blue the measured H1 "
              "(light: +-1 sigma), black the rig model's FRF, red the modal fit; the zoomed "
              "plots span the mode's frequency +-20 %."]
    return "\n".join(lines) + "\n"


def write_frf_rrd(path: Path, run_dir: Path, doc: Mapping[str, Any]) -> Path:
    """frf.rrd (see the module docstring) of ``harness frf``'s document."""
    rec = rr.RecordingStream(APPLICATION_ID, recording_id=f"{run_dir.name}-frf")
    save_with_blueprint(rec, path, bode_blueprint(doc))
    try:
        for out, e in doc["outputs"].items():
            index = [rr.TimeColumn(TIMELINE, sequence=mhz(e["freq_hz"]))]
            for plot, series in bode_curves(e).items():
                for name, values in series.items():
                    entity = f"/frf/{out}/{plot}/{name}"
                    rec.log(entity, rr.SeriesLines(names=NAMES[name], colors=[COLOURS[name]],
                                                   widths=[WIDTHS.get(name, 1.0)]),
                            static=True)
                    rec.send_columns(entity, indexes=index,
                                     columns=rr.Scalars.columns(scalars=values))
        rec.log(MODES_ENTITY, rr.TextDocument(modes_markdown(doc), media_type="text/markdown"),
                static=True)
    finally:
        try:
            close_stream(rec, path)
        finally:
            del rec
            sweep_orphans()
    return path
