"""The calibration report: report.md and three PNGs (matplotlib, Agg) in the folder.

* ``spectrum.png``: amplitude spectrum of every free-decay window of the excitation run,
  the identified modes (damped frequency, with +-3 sigma) and the model's predictions.
* ``sensitivity.png``: each candidate's residual vibration against frequency around every
  identified mode, the mode's band (+-max(3 sigma, 5 %)) shaded.
* ``residuals.png``: the residual tip acceleration of every verified slew over the same
  window after its own manoeuvre: raw accelerometer, the identified modes fitted to it and,
  on the virtual rig, the noise-free truth.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from harness.calibration.candidates import bands_of, baseline_controller, build
from harness.controllers.shaped_wheel_slew import Mode
from harness.controllers.thruster_two_level import damped_residual_percent
from harness.shaping.impulse_shapers import residual_vibration


def _plt() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _rel(path: str | Path, base: Path) -> str:
    return os.path.relpath(Path(path), base)


def plot_spectrum(c: Any, path: Path) -> None:
    plt = _plt()
    fig, ax = plt.subplots(figsize=(9, 4.5))
    ident = c.identification
    primary = ident.primary
    f_top = 1.5 * max(m.omega_rad_s for m in c.modes) / (2 * math.pi)
    for k, r in enumerate(ident.results):
        sp = r.spectrum
        sel = (sp.freq_hz > 0) & (sp.freq_hz <= f_top)
        is_p = r is primary
        ax.semilogy(sp.freq_hz[sel], sp.amplitude[sel], lw=1.2 if is_p else 0.6,
                    color="tab:blue" if is_p else "tab:orange", alpha=1.0 if is_p else 0.35,
                    label=("longest free decay" if is_p else
                           ("shorter free decays" if k == 0 or ident.results[0] is primary
                            and k == 1 else None)))
    for i, m in enumerate(c.modes):
        f = m.omega_rad_s * math.sqrt(1 - m.damping_ratio**2) / (2 * math.pi)
        s = 3 * m.sigma_omega_rad_s / (2 * math.pi)
        ax.axvspan(f - s, f + s, color="tab:green", alpha=0.3)
        ax.axvline(f, color="tab:green", lw=1, label="identified (+-3 sigma)" if i == 0 else None)
        ax.annotate(f"{m.omega_rad_s:.3f} rad/s\nzeta {m.damping_ratio:.3f}", (f, 1.0),
                    xycoords=("data", "axes fraction"), fontsize=7, ha="left", va="top")
    for i, p in enumerate(c.plan.predicted):
        if p.freq_hz <= f_top:
            ax.axvline(p.omega_damped_rad_s / (2 * math.pi), color="grey", ls="--", lw=0.8,
                       label="rig model's prediction" if i == 0 else None)
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel("amplitude (m/s^2)")
    ax.set_title(f"{c.plan.rig.name}: tip acceleration spectra of the free decays")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _curves(c: Any, cand: Any, ws: list[np.ndarray], zetas: list[float]) -> list[np.ndarray]:
    """Residual vibration (%) of ``cand`` as sent, at each mode's frequencies ``ws[i]`` and
    damping ``zetas[i]`` (its controller built once for all the modes)."""
    _, ctrl = build(c.spec, "plot", "", cand.controller)
    if c.options.actuator == "wheel":
        return [residual_vibration(ctrl.applied_shaper, w, zeta)
                for w, zeta in zip(ws, zetas, strict=True)]
    _, base = build(c.spec, "plot", "", baseline_controller(c.spec, c.modes))
    steps = np.diff(np.r_[0.0, ctrl.directions.astype(float), 0.0])
    k = np.flatnonzero(steps)
    tau = base.design.bang_bang_duration_s / 2
    return [damped_residual_percent(k / c.spec.rate_hz, steps[k],
                                    [Mode(float(x), zeta) for x in w], tau)
            for w, zeta in zip(ws, zetas, strict=True)]


def plot_sensitivity(c: Any, path: Path) -> None:
    plt = _plt()
    n = len(c.modes)
    fig, axes = plt.subplots(1, n, figsize=(4.2 * n, 4), squeeze=False)
    bands = bands_of(c.modes)
    cands = [x for x in c.candidates if x.feasible]
    curves = {}
    for x in cands:
        curves[x.key] = _curves(c, x, [np.linspace(0.7, 1.3, 241) * m.omega_rad_s
                                       for m in c.modes], [m.damping_ratio for m in c.modes])
    for i, (m, b) in enumerate(zip(c.modes, bands, strict=True)):
        ax = axes[0, i]
        r = np.linspace(0.7, 1.3, 241)
        for x in cands:
            ax.plot(r, curves[x.key][i], label=x.label)
        ax.axvspan(b.omega_lo_rad_s / m.omega_rad_s, b.omega_hi_rad_s / m.omega_rad_s,
                   color="grey", alpha=0.2, label="identified band")
        ax.set_yscale("log")
        ax.set_ylim(1e-3, 300)
        ax.set_xlabel(f"frequency / {m.omega_rad_s:.3f} rad/s")
        ax.set_title(f"mode {i + 1}")
        if i == 0:
            ax.set_ylabel("residual vibration (% of unshaped)")
    axes[0, 0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_residuals(c: Any, path: Path) -> None:
    plt = _plt()
    rows = [("unshaped", c.baseline)] + [(k, v) for k, v in c.verified.items()]
    labels = {x.key: x.label for x in c.candidates}
    n = len(rows)
    fig, axes = plt.subplots(2, n, figsize=(3.3 * n, 6.4), sharey="row", squeeze=False)
    for ax, zoom, (key, row) in zip(axes[0], axes[1], rows, strict=True):
        s = row["series"]
        ax.plot(s["t"], s["accel"], color="0.75", lw=0.5, label="accelerometer")
        ax.plot(s["t"], s["fitted"], color="tab:blue", lw=1.0, label="identified modes fitted")
        if s["truth"] is not None:
            n_t = min(len(s["t"]), len(s["truth"]))
            ax.plot(s["t"][:n_t], s["truth"][:n_t], color="k", ls="--", lw=0.8,
                    label="noise-free truth")
        ratio = "" if key == "unshaped" else f"\n{row['ratio_fitted']:.1f}x below unshaped"
        ax.set_title(f"{labels.get(key, key)}{ratio}", fontsize=8)
        zoom.semilogy(s["t"], np.abs(s["fitted"]) + 1e-12, color="tab:blue", lw=0.8)
        if s["truth"] is not None:
            zoom.semilogy(s["t"][:n_t], np.abs(s["truth"][:n_t]) + 1e-12, color="k", lw=0.6)
        zoom.axhline(2 * row["fitted"]["sigma_m_s2"], color="tab:red", ls=":", lw=0.8,
                     label="fit's 2 sigma")
        zoom.set_ylim(1e-7, 0.1)
        zoom.set_xlabel("time after manoeuvre + 0.1 s (s)")
    axes[0, 0].set_ylabel("tip acceleration (m/s^2)")
    axes[1, 0].set_ylabel("|fitted| (blue), |truth| (black)")
    axes[0, 0].legend(fontsize=7)
    axes[1, 0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _e(x: float | None) -> str:
    return "-" if x is None or (isinstance(x, float) and not math.isfinite(x)) else f"{x:.2e}"


def write_report(c: Any) -> Path:
    folder: Path = c.folder
    plot_spectrum(c, folder / "spectrum.png")
    plot_sensitivity(c, folder / "sensitivity.png")
    plot_residuals(c, folder / "residuals.png")
    o = c.options
    lines = [f"# Calibration: {c.plan.rig.name}, {o.actuator}", ""]
    rec = c.recommended
    if rec is not None:
        row = c.verified[rec]
        truth = (f", noise-free truth {row['ratio_truth']:.1f}x" if "ratio_truth" in row else "")
        label = next(x.label for x in c.candidates if x.key == rec)
        lines += [f"**Recommended: {label}** (`{_rel(c.run_file, folder)}`): residual "
                  f"{row['fitted']['peak_m_s2']:.3g} m/s^2 fitted, {row['ratio_fitted']:.1f}x "
                  f"below the unshaped slew{truth}; target "
                  f"{'met' if c.target_met else '**not met**'} ({c.recommendation_note}). "
                  f"Baseline: `{_rel(c.baseline_run_file, folder)}`.", ""]
    lines += ["## 1. Excitation", ""] + [f"    {x}" for x in c.plan.describe()] + [
        "", f"Recording: [{_rel(Path(c.excitation_dir) / 'run.rrd', folder)}]"
        f"({_rel(Path(c.excitation_dir) / 'run.rrd', folder)}) "
        f"(spectra: `{_rel(Path(c.excitation_dir) / 'identify.rrd', folder)}`)", "",
        "## 2. Identified modes (tip accelerometer, parametric free-decay fit, 1 sigma)", "",
        "| mode | omega (rad/s) | f (Hz) | damping | predicted (rad/s) | predicted damping |",
        "|---|---|---|---|---|---|"]
    for i, m in enumerate(c.modes):
        match = next((r for r in c.matches if r["identified"] == i + 1), None)
        pw = f"{match['predicted_omega_rad_s']:.4f}" if match else "-"
        pz = f"{match['predicted_damping_ratio']:.4f}" if match else "-"
        lines.append(f"| {i + 1} | {m.omega_rad_s:.4f} +- {m.sigma_omega_rad_s:.2g} | "
                     f"{m.omega_rad_s / (2 * math.pi):.4f} | {m.damping_ratio:.4f} +- "
                     f"{m.sigma_damping:.2g} | {pw} | {pz} |")
    lines += ["", "![spectrum](spectrum.png)", ""]
    for n in c.notes:
        lines.append(f"- {n}")
    lines += ["", "## 3. Candidates", "",
              f"Slew: {c.spec.angle_deg:g} deg, {c.spec.torque_n_m:.4g} N m "
              f"({'wheel bang-bang' if o.actuator == 'wheel' else 'valve couple'}); residual "
              f"window {c.spec.window_s:.2f} s starting 0.1 s after each slew's own end. "
              "V: residual vibration in % of the unshaped slew's, per mode; worst over each "
              "mode's band (+-max(3 sigma, 5 %) in frequency, +-3 sigma in damping). "
              "Predicted ratio: unshaped / candidate, the modes weighted by the unshaped "
              "slew's fitted residual per mode.", ""]
    valves = o.actuator == "valves"
    head = ("| candidate | added s | V nominal (%) | V worst in band (%) | predicted ratio "
            "(band worst / nominal) |")
    if valves:
        head += " impulse (N m s) | firings |"
    head += (" fitted residual +- 1 sigma (m/s^2) | ratio fitted | raw peak (m/s^2) | truth "
             "(m/s^2) | ratio truth | run |")
    lines += [head, "|" + "---|" * (head.count("|") - 1)]
    b = c.baseline
    bt = b["truth"]["peak_m_s2"] if b["truth"] else None
    base_cells = "| unshaped | 0 | 100 | 100 | 1 / 1 |" + (" - | - |" if valves else "")
    lines.append(base_cells + f" {_e(b['fitted']['peak_m_s2'])} +- "
                 f"{_e(b['fitted']['sigma_m_s2'])} | 1 | {b['raw']['peak_m_s2']:.3g} | "
                 f"{_e(bt)} | 1 | [run.rrd]({_rel(Path(b['run_dir']) / 'run.rrd', folder)}) |")
    for x in c.candidates:
        if not x.feasible:
            lines.append(f"| {x.label} | not feasible: {x.reason} |")
            continue
        row = c.verified.get(x.key)
        cells = (f"| {x.label} | {x.added_s:.3f} | "
                 + " / ".join(f"{v:.2g}" for v in x.nominal_percent) + " | "
                 + " / ".join(f"{v:.2g}" for v in x.worst_percent) + " | "
                 f"{x.predicted_ratio:.1f} / {x.predicted_nominal_ratio:.3g} |")
        if valves:
            cells += f" {x.impulse_n_m_s:.4f} | {x.firings} |"
        if row is None:
            cells += " not verified | | | | | |"
        else:
            tr = row["truth"]["peak_m_s2"] if row["truth"] else None
            noise = " (noise)" if row.get("noise_limited") else ""
            cells += (f" {_e(row['fitted']['peak_m_s2'])} +- {_e(row['fitted']['sigma_m_s2'])} | "
                      f"{row['ratio_fitted']:.1f}{noise} | {row['raw']['peak_m_s2']:.3g} | "
                      f"{_e(tr)} | "
                      f"{row.get('ratio_truth', float('nan')):.1f} | "
                      f"[run.rrd]({_rel(Path(row['run_dir']) / 'run.rrd', folder)}) |")
        lines.append(cells)
    lines += ["", "![sensitivity](sensitivity.png)", "",
              "## 4. Residual vibration on the rig", "",
              "Fitted: the identified modes' free decay fitted to the recorded residual (what "
              "the lab rig measures; a fitted peak below 2 sigma is the fit's noise, marked "
              "(noise): the window then shows only that the residual is below about 2 sigma, "
              "i.e. a ratio of at least unshaped / (2 sigma)). Raw: the "
              "accelerometer's peak, noise included. Truth: the virtual rig's noise-free tip "
              "acceleration (virtual rig only).", "", "![residuals](residuals.png)", ""]
    path = folder / "report.md"
    path.write_text("\n".join(lines) + "\n")
    return path
