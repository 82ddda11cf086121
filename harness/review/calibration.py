"""``harness calibrate``'s own recording, ``calibration.rrd`` in its output folder: what a
reviewer checks in one layout (Klipper's calibration draws the spectrum with every shaper's
response overlaid; here the same questions):

- ``/final/...``: the excitation's longest free decay's spectrum with a marker per identified
  mode (``mode_<n>``) and per mode the rig model predicted (``model_<n>``);
- ``/candidates/<key>``: each candidate shaper's predicted residual, % of the unshaped slew's
  (worst over the identified bands, weighted by the unshaped slew's modal amplitudes), and
  ``/measured/<key>``: the residual measured when verified on the rig (a candidate in one
  colour in both);
- ``/verified/...`` on the ``time`` timeline (s after the manoeuvre's end + margin): the
  tip acceleration of the unshaped slew and of the recommended shaped one, raw and with the
  identified modes fitted;
- ``/calibration/result`` and ``/calibration/modes``: the recommendation and the modes view
  (``harness.review.spectrum.modes_markdown``).

The calibration object is read duck-typed (``harness.calibration.workflow.Calibration``):
this package does not import the calibration.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from harness.record.recording import close_stream
from harness.record.streams import save_with_blueprint, sweep_orphans
from harness.review.names import GREEN, GREY, ORANGE, PURPLE, SKY, VERMILLION, YELLOW
from harness.review.spectrum import (
    FINAL,
    SPECTRUM_COLOUR,
    _bars,
    _mode_markers,
    modes_markdown,
)

APPLICATION_ID = "sgsrt-harness"
RESULT = "/calibration/result"
MODES = "/calibration/modes"
SPECTRUM_VIEW = "Spectrum of the excitation's free decay (m/s^2) vs frequency (Hz)"
CANDIDATES_VIEW = "Candidates: residual, % of the unshaped slew's (predicted; measured)"
VERIFIED_VIEW = "Verified on the rig: tip acceleration after the slew (m/s^2)"


# a candidate's colour, the same in the predicted and the measured chart
CANDIDATE_COLOURS = (SKY, GREEN, PURPLE, YELLOW, ORANGE, (120, 200, 200), (200, 200, 120))


def _finite(x: Any) -> bool:
    return isinstance(x, int | float) and math.isfinite(float(x))


def calibration_blueprint(window_s: float | None = None) -> rrb.Blueprint:
    axis = None
    if window_s and window_s > 0:
        axis = rrb.TimeAxis(view_range=rrb.TimeRange(
            start=rrb.TimeRangeBoundary.absolute(seconds=0.0),
            end=rrb.TimeRangeBoundary.absolute(seconds=float(window_s) * 1.015)))
    left = rrb.Vertical(
        rrb.BarChartView(origin=FINAL, name=SPECTRUM_VIEW,
                         plot_legend=rrb.PlotLegend(corner="RightTop")),
        rrb.Horizontal(
            rrb.BarChartView(origin="/candidates", name=CANDIDATES_VIEW + ": predicted",
                             plot_legend=rrb.PlotLegend(corner="RightTop")),
            rrb.BarChartView(origin="/measured", name=CANDIDATES_VIEW + ": measured",
                             plot_legend=rrb.PlotLegend(corner="RightTop"))),
        rrb.TimeSeriesView(origin="/verified", name=VERIFIED_VIEW, axis_x=axis,
                           plot_legend=rrb.PlotLegend(corner="RightTop"),
                           defaults=[rr.SeriesLines(aggregation_policy="MinMax")]),
        row_shares=[3, 2, 3])
    right = rrb.Vertical(rrb.TextDocumentView(origin=RESULT, name="Calibration result"),
                         rrb.TextDocumentView(origin=MODES, name="Identified modes"),
                         row_shares=[1, 1])
    return rrb.Blueprint(rrb.Horizontal(left, right, column_shares=[3, 1]),
                         rrb.TimePanel(timeline="time", state="collapsed"),
                         collapse_panels=True)


def _mode_dicts(c: Any) -> list[dict[str, Any]]:
    out = []
    for i, m in enumerate(c.modes):
        d = {"freq_hz": m.omega_rad_s / (2 * math.pi), "omega_rad_s": m.omega_rad_s,
             "sigma_omega_rad_s": m.sigma_omega_rad_s, "damping_ratio": m.damping_ratio,
             "sigma_damping": m.sigma_damping, "source": {"experiment": "excitation run"}}
        # the predicted mode this one was matched to (workflow.match_predictions)
        match = next((r for r in c.matches if isinstance(r, dict)
                      and r.get("identified") == i + 1), None)
        if match is not None and _finite(match.get("predicted_omega_rad_s")):
            d["model_omega_rad_s"] = match["predicted_omega_rad_s"]
            if _finite(match.get("predicted_damping_ratio")):
                d["model_damping_ratio"] = match["predicted_damping_ratio"]
            d["model_mode"] = match.get("mode", "?")
        out.append(d)
    return out


def _result_markdown(c: Any) -> str:
    labels = {x.key: x.label for x in c.candidates}
    lines = [f"# {c.recommended and labels.get(c.recommended, c.recommended) or 'none'}"
             " recommended", "",
             f"Target {'met' if c.target_met else 'NOT met'}: {c.recommendation_note}", "",
             "Residual, % of the unshaped slew's (fitted peak after the slew):", ""]
    for x in c.candidates:
        pred = 100.0 / x.predicted_ratio if _finite(x.predicted_ratio) and x.predicted_ratio \
            else None
        row = c.verified.get(x.key)
        meas = 100.0 / row["ratio_fitted"] if row and _finite(row.get("ratio_fitted")) \
            and row["ratio_fitted"] else None
        extra = "" if x.feasible else f" (not feasible: {x.reason})"
        lines.append(f"- `{x.key}` {x.label}: predicted "
                     f"{'-' if pred is None else f'{pred:.3g} %'}, measured "
                     f"{'not verified' if meas is None else f'{meas:.3g} %'}; "
                     f"+{x.added_s:.3g} s{extra}")
    return "\n".join(lines) + "\n"


def write_calibration_rrd(c: Any, path: Path | None = None) -> Path:
    """calibration.rrd in the calibration's folder (see the module docstring)."""
    path = path or Path(c.folder) / "calibration.rrd"
    window = c.spec.window_s if getattr(c, "spec", None) is not None else None
    rec = rr.RecordingStream(APPLICATION_ID, recording_id=Path(path).parent.name)
    save_with_blueprint(rec, path, calibration_blueprint(window))
    try:
        ident = c.identification
        sp = ident.primary.spectrum
        f_top = 1.5 * max((m.omega_rad_s for m in c.modes), default=2 * math.pi) / (2 * math.pi)
        sel = (sp.freq_hz > 0) & (sp.freq_hz <= max(f_top, 1.0))
        f_max = float(sp.freq_hz[sel][-1])
        _bars(rec, f"{FINAL}/spectrum", sp.freq_hz[sel], sp.amplitude[sel], SPECTRUM_COLOUR)
        spectra = [(sp.freq_hz[sel], sp.amplitude[sel])]
        _mode_markers(rec, FINAL, c.modes, spectra, f_max)
        top = float(sp.amplitude[sel].max(initial=0.0)) or 1e-6
        for i, p in enumerate(getattr(c.plan, "predicted", []) or []):
            f = p.omega_damped_rad_s / (2 * math.pi)
            if f <= f_max:
                rec.log(f"{FINAL}/model_{i + 1}", rr.BarChart(
                    [0.5 * top], abscissa=[f], widths=[f_max / 250.0], color=GREY), static=True)
        for k, x in enumerate(c.candidates):
            colour = CANDIDATE_COLOURS[k % len(CANDIDATE_COLOURS)]
            if _finite(x.predicted_ratio) and x.predicted_ratio:
                rec.log(f"/candidates/{x.key}", rr.BarChart(
                    [100.0 / x.predicted_ratio], abscissa=[k], widths=[0.8], color=colour),
                    static=True)
            row = c.verified.get(x.key)
            if row and _finite(row.get("ratio_fitted")) and row["ratio_fitted"]:
                rec.log(f"/measured/{x.key}", rr.BarChart(
                    [100.0 / row["ratio_fitted"]], abscissa=[k], widths=[0.8], color=colour),
                    static=True)
        pairs = [("unshaped", c.baseline, (150, 90, 60), VERMILLION)]
        if c.recommended is not None and c.recommended in c.verified:
            pairs.append(("shaped", c.verified[c.recommended], (60, 110, 150), SKY))
        labels = {x.key: x.label for x in c.candidates}
        for name, row, raw_colour, fit_colour in pairs:
            if not row or "series" not in row:
                continue
            s = row["series"]
            t = np.asarray(s["t"], dtype=float)
            title = "unshaped" if name == "unshaped" else labels.get(c.recommended, "shaped")
            # the fitted residual is the reading: drawn thick over the thin, noisy raw one
            for part, values, colour, width in (("raw", s["accel"], raw_colour, 0.5),
                                                ("fitted", s["fitted"], fit_colour, 2.5)):
                entity = f"/verified/{name}/{part}"
                rec.log(entity, rr.SeriesLines(
                    names=f"{title}, {'accelerometer' if part == 'raw' else 'modes fitted'}",
                    colors=[colour], widths=[width], aggregation_policy="MinMax"),
                    static=True)
                rec.send_columns(entity, indexes=[rr.TimeColumn("time", duration=t)],
                                 columns=rr.Scalars.columns(
                                     scalars=np.asarray(values, dtype=float)))
        rec.log(RESULT, rr.TextDocument(_result_markdown(c), media_type="text/markdown"),
                static=True)
        rec.log(MODES, rr.TextDocument(modes_markdown(_mode_dicts(c), []),
                                       media_type="text/markdown"), static=True)
    finally:
        try:
            close_stream(rec, path)  # bounded: a full disk's stuck sink never hangs calibrate
        finally:
            del rec
            sweep_orphans()  # the stream dropped: its threads end
    return Path(path)
