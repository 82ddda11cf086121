"""The identification in a recording (``identify.rrd``): spectra as bar charts over frequency
in Hz, every identified mode as its own series (its name, frequency and damping in the
legend, so labels never overlap), the FFT peaks, and the modes as a markdown table.

``/final/...``: the longest (final) free decay's spectrum, its FFT peaks and a marker per
mode (``mode_<n>``: Rerun 0.41's bar charts take no legend name, so the legend shows the
whole entity path, kept short; each mode's frequency and damping are in the modes view).
``/short/...``: per experiment of short windows (repetitions of one burst) the mean of their
spectra (``mean_<k>``, named in the modes view), with the mode markers again.
``/identify/modes``: the modes view,
every value labelled: undamped and damped frequency (the spectrum peaks and the markers sit at
the damped one), damping, their 1-sigma uncertainties, the model's values and the
difference. A mode's marker is a bar at its damped frequency reaching 15 % above the highest
spectrum of its view within 2 % of that frequency (at least 15 % of the view's highest
bar), so it stands above its peak and is seen even where the mode has decayed; each mode
has its own colour, none the spectrum's.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from harness.identification.windows import MultiWindowResult
from harness.record.recording import APPLICATION_ID, close_stream
from harness.record.streams import save_with_blueprint, sweep_orphans
from harness.review.layouts import blueprint_for_run_dir, layout_for_run, spectrum_views

# short roots: Rerun 0.41's bar-chart legend is the whole entity path
FINAL = "/final"
SHORT = "/short"
MODES_ENTITY = "/identify/modes"
SPECTRUM_COLOUR = (40, 90, 180)
PEAK_COLOUR = (20, 20, 20)
WINDOW_COLOURS = ((120, 120, 120), (255, 150, 40), (70, 170, 90), (150, 90, 200))
MODE_COLOURS = ((230, 40, 40), (0, 170, 90), (240, 160, 0), (190, 90, 230), (0, 190, 210),
                (160, 110, 60), (250, 110, 180), (150, 200, 40))


def _band(freq_hz: np.ndarray, f_top_hz: float) -> np.ndarray:
    return freq_hz <= max(10.0, 3.0 * f_top_hz)


def _bars(rec: rr.RecordingStream, entity: str, f: np.ndarray, a: np.ndarray,
          colour: Sequence[int], width: float | None = None) -> None:
    if width is None:
        width = float(np.median(np.diff(f))) if len(f) > 1 else 0.01
    rec.log(entity, rr.BarChart(np.asarray(a, dtype=float), abscissa=np.asarray(f, dtype=float),
                                widths=np.full(len(f), width), color=colour), static=True)


def _mode_markers(rec: rr.RecordingStream, base: str, modes: Sequence[Any],
                  spectra: Sequence[tuple[np.ndarray, np.ndarray]], f_max: float) -> None:
    width = f_max / 250.0
    for i, m in enumerate(modes):
        zeta = float(m.damping_ratio)
        f = m.omega_rad_s * math.sqrt(max(1.0 - zeta * zeta, 0.0)) / (2 * math.pi)
        local = [a[np.abs(fs - f) <= 0.02 * f + 2 * np.median(np.diff(fs))].max(initial=0.0)
                 for fs, a in spectra if len(fs) > 1]
        top = max(float(a.max(initial=0.0)) for _, a in spectra)
        height = max(1.15 * max([*local, 0.0]), 0.15 * top) or 1e-6
        name = mode_entity(i)
        rec.log(f"{base}/{name}", rr.BarChart([height], abscissa=[f], widths=[width],
                                               color=MODE_COLOURS[i % len(MODE_COLOURS)]),
                static=True)


def mode_entity(i: int) -> str:
    """The short entity (and legend) name of mode ``i`` (0-based): ``mode_1``."""
    return f"mode_{i + 1}"


def _pct(a: float, b: float) -> str:
    return f"{100.0 * (a / b - 1.0):+.2f} %" if b else "-"


MODES_LEGEND = ("f: undamped natural frequency; fd: damped frequency, f sqrt(1 - zeta^2), where "
                "the spectrum peaks and the marker `mode_<n>` stands; zeta: damping ratio; "
                "+-: one standard deviation (1 sigma).")


def modes_markdown(modes: Sequence[Mapping[str, Any]], notes: Sequence[str]) -> str:
    """The modes view, two lines a mode so that it fits its panel: the identified undamped
    frequency and damping with their 1-sigma uncertainties and the damped frequency; then the
    difference from the model and the model's values, the FFT peak and the source; the
    legend and the notes after every mode."""
    lines = ["# Identified modes", ""]
    for i, m in enumerate(modes):
        f = float(m["freq_hz"])
        zeta = float(m["damping_ratio"])
        fd = f * math.sqrt(max(1.0 - zeta * zeta, 0.0))
        sigma_f = float(m["sigma_omega_rad_s"]) / (2 * math.pi)
        lines.append(f"- **Mode {i + 1}** `{mode_entity(i)}`: f = {f:.4f} +- {sigma_f:.4f} Hz "
                     f"({m['omega_rad_s']:.4f} rad/s), zeta = {zeta:.4f} +- "
                     f"{float(m['sigma_damping']):.4f}, fd = {fd:.4f} Hz")
        more = []
        model = m.get("model_omega_rad_s")
        if model is not None:
            mf = float(model) / (2 * math.pi)
            mz = m.get("model_damping_ratio")
            more.append(f"identified - model: f {_pct(f, mf)}"
                        + ("" if mz is None else f", zeta {_pct(zeta, float(mz))}")
                        + f" (model mode {m.get('model_mode', '?')}: f = {mf:.4f} Hz"
                        + ("" if mz is None else f", zeta = {float(mz):.4f}") + ")")
        fft = m.get("fft_peak_omega_rad_s")
        if fft is not None:
            more.append(f"FFT peak {fft / (2 * math.pi):.4f} Hz"
                        + (" (rough)" if m.get("fft_rough") else ""))
        source = m.get("source") or {}
        if source.get("experiment"):
            more.append(f"from: {source['experiment']}")
        if more:
            lines.append("  " + "; ".join(more))
    lines += ["", MODES_LEGEND]
    if notes:
        lines += ["", "Notes:", "", *[f"- {n}" for n in notes]]
    return "\n".join(lines) + "\n"


def identify_blueprint(run_dir: Path, cfg: Mapping[str, Any] | None) -> rrb.Blueprint:
    """The run's own layout (so identify.rrd and run.rrd agree, whatever order they are
    opened in), or the identification alone for a record without a run."""
    if cfg:
        if (run_dir / "config.yaml").exists():
            return blueprint_for_run_dir(run_dir)
        return layout_for_run(cfg)
    spec, windows, table = spectrum_views()
    return rrb.Blueprint(rrb.Horizontal(rrb.Vertical(spec, windows), table,
                                        column_shares=[3, 1]), collapse_panels=True)


def write_identify_rrd(path: Path, run_dir: Path, result: MultiWindowResult,
                       modes: Sequence[Mapping[str, Any]] | None = None,
                       cfg: Mapping[str, Any] | None = None) -> Path:
    """identify.rrd (see the module docstring). ``modes``: the command's mode dicts (with the
    model's values when known) for the table; ``cfg``: the run's config.yaml, for its
    layout. The recording id is the run directory's name, as run.rrd's."""
    rec = rr.RecordingStream(APPLICATION_ID, recording_id=run_dir.name)
    save_with_blueprint(rec, path, identify_blueprint(run_dir, cfg))
    try:
        f_top = max((m.freq_hz for m in result.modes), default=1.0)
        primary = result.primary
        sp = primary.spectrum
        sel = _band(sp.freq_hz, f_top)
        f_max = float(sp.freq_hz[sel][-1])
        _bars(rec, f"{FINAL}/spectrum", sp.freq_hz[sel], sp.amplitude[sel],
              SPECTRUM_COLOUR)
        if primary.fft_peaks:
            _bars(rec, f"{FINAL}/fft_peaks",
                  np.array([p.freq_hz for p in primary.fft_peaks]),
                  np.array([p.amplitude for p in primary.fft_peaks]), PEAK_COLOUR,
                  width=f_max / 400.0)
        primary_spectra = [(sp.freq_hz[sel], sp.amplitude[sel])]
        _mode_markers(rec, FINAL, result.modes, primary_spectra, f_max)
        k_primary = result.results.index(primary)
        short: list[tuple[np.ndarray, np.ndarray]] = []
        means: list[str] = []
        for e, idx in enumerate(result.experiments):
            idx = tuple(i for i in idx if i != k_primary)
            if not idx:
                continue
            f0 = result.results[idx[0]].spectrum.freq_hz
            sel0 = _band(f0, f_top)
            amps = [np.interp(f0[sel0], result.results[i].spectrum.freq_hz,
                              result.results[i].spectrum.amplitude) for i in idx]
            mean = np.mean(amps, axis=0)
            _bars(rec, f"{SHORT}/mean_{len(short) + 1}", f0[sel0], mean,
                  WINDOW_COLOURS[len(short) % len(WINDOW_COLOURS)])
            means.append(f"`{SHORT}/mean_{len(short) + 1}`: the mean spectrum of "
                         f"{result.experiment_label(e)}")
            short.append((f0[sel0], mean))
        if short:
            _mode_markers(rec, SHORT, result.modes, short,
                          max(float(f[-1]) for f, _ in short))
        rec.log(MODES_ENTITY, rr.TextDocument(
            modes_markdown(modes if modes is not None else result.to_dict()["modes"],
                           [*means, *result.notes]), media_type="text/markdown"), static=True)
    finally:
        try:
            close_stream(rec, path)  # bounded: a full disk's stuck sink never hangs identify
        finally:
            del rec
            sweep_orphans()  # the stream dropped: its threads end
    return path
