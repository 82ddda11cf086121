"""The identification in a recording (``identify.rrd``): spectra as bar charts over frequency
in Hz, every identified mode as its own series (its name, frequency and damping in the
legend, so labels never overlap), the FFT peaks, and the modes as a markdown table.

``/identify/spectrum/...``: the longest (final) free decay's spectrum, its FFT peaks and a
marker per mode (``mode_<n>_<f>_Hz_zeta_<damping>``). ``/identify/windows/...``: per
experiment of short windows (repetitions of one burst) the mean of their spectra, with the
mode markers again. ``/identify/modes``: the table. A mode's marker is a bar at its damped
frequency reaching 15 % above the highest spectrum of its view within 2 % of that frequency
(at least 15 % of the view's highest bar), so it stands above its peak and is seen even
where the mode has decayed.
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
from harness.record.recording import APPLICATION_ID
from harness.review.layouts import blueprint_for_run_dir, layout_for_run, spectrum_views

SPECTRUM_COLOUR = (40, 90, 180)
PEAK_COLOUR = (20, 20, 20)
WINDOW_COLOURS = ((120, 120, 120), (255, 150, 40), (70, 170, 90), (150, 90, 200))
MODE_COLOURS = ((220, 30, 30), (0, 150, 0), (230, 120, 0), (150, 0, 200), (0, 140, 190),
                (120, 80, 40))


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
        f = m.omega_damped_rad_s / (2 * math.pi)
        local = [a[np.abs(fs - f) <= 0.02 * f + 2 * np.median(np.diff(fs))].max(initial=0.0)
                 for fs, a in spectra if len(fs) > 1]
        top = max(float(a.max(initial=0.0)) for _, a in spectra)
        height = max(1.15 * max([*local, 0.0]), 0.15 * top) or 1e-6
        name = f"mode_{i + 1}_{f:.4f}_Hz_zeta_{m.damping_ratio:.4f}"
        rec.log(f"{base}/{name}", rr.BarChart([height], abscissa=[f], widths=[width],
                                               color=MODE_COLOURS[i % len(MODE_COLOURS)]),
                static=True)


def modes_markdown(modes: Sequence[Mapping[str, Any]], notes: Sequence[str]) -> str:
    lines = ["# Identified modes", "",
             "| mode | f (Hz) | omega (rad/s) | +- | zeta | +- | FFT peak (rad/s) | "
             "model (rad/s) | from |", "|---|---|---|---|---|---|---|---|---|"]
    for i, m in enumerate(modes):
        fft = m.get("fft_peak_omega_rad_s")
        model = m.get("model_omega_rad_s")
        lines.append(
            f"| {i + 1} | {m['freq_hz']:.4f} | {m['omega_rad_s']:.4f} | "
            f"{m['sigma_omega_rad_s']:.4f} | {m['damping_ratio']:.4f} | "
            f"{m['sigma_damping']:.4f} | {'-' if fft is None else f'{fft:.4f}'}"
            f"{' (rough)' if m.get('fft_rough') else ''} | "
            f"{'-' if model is None else f'{model:.4f}'} | {m['source']['experiment']} |")
    if notes:
        lines += ["", *[f"- {n}" for n in notes]]
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
    rec.save(str(path), default_blueprint=identify_blueprint(run_dir, cfg))
    try:
        f_top = max((m.freq_hz for m in result.modes), default=1.0)
        primary = result.primary
        sp = primary.spectrum
        sel = _band(sp.freq_hz, f_top)
        f_max = float(sp.freq_hz[sel][-1])
        _bars(rec, "/identify/spectrum/amplitude", sp.freq_hz[sel], sp.amplitude[sel],
              SPECTRUM_COLOUR)
        if primary.fft_peaks:
            _bars(rec, "/identify/spectrum/fft_peaks",
                  np.array([p.freq_hz for p in primary.fft_peaks]),
                  np.array([p.amplitude for p in primary.fft_peaks]), PEAK_COLOUR,
                  width=f_max / 400.0)
        primary_spectra = [(sp.freq_hz[sel], sp.amplitude[sel])]
        _mode_markers(rec, "/identify/spectrum", result.modes, primary_spectra, f_max)
        k_primary = result.results.index(primary)
        short: list[tuple[np.ndarray, np.ndarray]] = []
        for e, idx in enumerate(result.experiments):
            idx = tuple(i for i in idx if i != k_primary)
            if not idx:
                continue
            f0 = result.results[idx[0]].spectrum.freq_hz
            sel0 = _band(f0, f_top)
            amps = [np.interp(f0[sel0], result.results[i].spectrum.freq_hz,
                              result.results[i].spectrum.amplitude) for i in idx]
            mean = np.mean(amps, axis=0)
            label = result.experiment_label(e).replace(" ", "_").replace("/", "_per_")
            _bars(rec, f"/identify/windows/mean_of_{label}", f0[sel0], mean,
                  WINDOW_COLOURS[len(short) % len(WINDOW_COLOURS)])
            short.append((f0[sel0], mean))
        if short:
            _mode_markers(rec, "/identify/windows", result.modes, short,
                          max(float(f[-1]) for f, _ in short))
        rec.log("/identify/modes", rr.TextDocument(
            modes_markdown(modes if modes is not None else result.to_dict()["modes"],
                           result.notes), media_type="text/markdown"), static=True)
    finally:
        rec.flush()
        rec.disconnect()
    return path
