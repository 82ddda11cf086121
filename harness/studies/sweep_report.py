"""What ``harness sweep`` (and the ``xu2018`` study) make of a lambda x beta sweep
(``harness.studies.sweep``): the paper's laws measured on the surface (``analyse``), and the
output folder (``write_sweep``) with ``sweep.csv``, ``maps.png``, ``curves.png``, ``sweep.rrd``
(the maps as tensors and one curve per beta against lambda, with its layout) and
``summary.json``. Kept apart from ``harness.studies.sweep``, which the sweep's worker processes
import: they need neither Matplotlib nor Rerun.
"""

from __future__ import annotations

import datetime as dt
import json
from pathlib import Path
from typing import Any

import numpy as np

from harness.record.recording import close_stream
from harness.record.streams import save_with_blueprint, sweep_orphans
from harness.studies.sweep import SweepSpec

OUTPUTS = ("tip_accel_m_s2", "tip_deflection_m")


def analyse(lambdas: np.ndarray, betas: np.ndarray, amps: np.ndarray) -> dict[str, Any]:
    """The paper's laws, measured on our surface."""
    out: dict[str, Any] = {}
    for o, name in enumerate(OUTPUTS):
        best = betas[np.argmin(amps[:, :, o], axis=1)]
        mean_over_beta = amps[:, :, o].mean(axis=1)
        peaks = [float(lambdas[i]) for i in range(1, len(lambdas) - 1)
                 if mean_over_beta[i] > mean_over_beta[i - 1]
                 and mean_over_beta[i] >= mean_over_beta[i + 1]]
        above = lambdas > 0.5
        out[name] = {
            "best_beta_per_lambda": dict(zip(map(float, lambdas), map(float, best),
                                             strict=True)),
            "best_beta_median_lambda_gt_0.5": float(np.median(best[above])) if above.any()
            else None,
            "share_lambda_gt_0.5_with_best_beta_in_0.6_0.85": float(np.mean(
                (best[above] >= 0.6 - 1e-9) & (best[above] <= 0.85 + 1e-9))) if above.any()
            else None,
            "resonance_lambdas": peaks,
        }
    return out


def save_plots(path_maps: Path, path_curves: Path, lambdas: np.ndarray, betas: np.ndarray,
               amps: np.ndarray, reference: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5))
    for o, (ax, title) in enumerate(zip(axes, ("tip acceleration amplitude (m/s^2)",
                                               "tip deflection amplitude (m)"), strict=True)):
        im = ax.pcolormesh(lambdas, betas, np.log10(amps[:, :, o].T), shading="nearest")
        ax.set_xlabel(f"lambda = w_m / w_ref ({reference} mode 1)")
        ax.set_ylabel("beta = U / A")
        ax.set_title(f"log10 {title}")
        fig.colorbar(im, ax=ax)
        best = betas[np.argmin(amps[:, :, o], axis=1)]
        ax.plot(lambdas, best, "w.-", lw=1, label="min over beta")
        ax.legend(loc="upper right")
    fig.tight_layout()
    fig.savefig(path_maps, dpi=110)
    plt.close(fig)
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5))
    for o, ax in enumerate(axes):
        for j, b in enumerate(betas):
            ax.semilogy(lambdas, amps[:, j, o], label=f"beta {b:.2f}")
        ax.set_xlabel(f"lambda ({reference} mode 1)")
        ax.set_ylabel(OUTPUTS[o])
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path_curves, dpi=110)
    plt.close(fig)


SWEEP_TIMELINE = "lambda_x1000"


def sweep_colours(n: int) -> list[tuple[int, int, int]]:
    """One colour per beta, from low (dark blue) to high (yellow) on viridis: the same beta
    has the same colour in every plot (the viewer's own colours change between plots)."""
    import matplotlib

    cmap = matplotlib.colormaps["viridis"]
    return [tuple(int(255 * x) for x in cmap(k / max(n - 1, 1))[:3]) for k in range(n)]


def sweep_blueprint(lambdas: np.ndarray | None = None, maps_png: bool = False) -> object:
    """The sweep's layout (harness.review.layouts.study_layout): per output, the amplitude
    and its log10 against lambda (one curve per beta) over the whole lambda range, the
    lambda x beta maps (maps.png, with their colour scales, when given; the raw tensors
    else), and the description."""
    from harness.review.layouts import study_layout

    curves = {}
    for out, title in zip(OUTPUTS, ("tip acceleration amplitude (m/s^2)",
                                    "tip deflection amplitude (m)"), strict=True):
        curves[f"{title[0].upper()}{title[1:]} vs lambda x 1000, one curve per beta"] = [
            f"/sweep/curves/{out}/**"]
        curves[f"log10 {title} vs lambda x 1000"] = [f"/sweep/log10/{out}/**"]
    x_range = None
    if lambdas is not None and len(lambdas):
        lo, hi = float(lambdas[0]) * 1000, float(lambdas[-1]) * 1000
        pad = 0.02 * (hi - lo)
        x_range = (int(round(lo - pad)), int(round(hi + pad)))
    maps = {"log10 amplitude maps, lambda x beta, with their colour scales (maps.png)":
            "/sweep/maps"} if maps_png else None
    tensors = None if maps_png else {
        "Tip acceleration amplitude map (m/s^2) [lambda x beta]": "/sweep/map/tip_accel_m_s2",
        "Tip deflection amplitude map (m) [lambda x beta]": "/sweep/map/tip_deflection_m"}
    return study_layout(curves, SWEEP_TIMELINE, texts={"Sweep": "/sweep/about"},
                        tensors=tensors, x_range=x_range, images=maps)


def save_rrd(path: Path, name: str, lambdas: np.ndarray, betas: np.ndarray,
             amps: np.ndarray, maps_png: Path | None = None) -> None:
    import rerun as rr

    rec = rr.RecordingStream("sgsrt-harness", recording_id=name)
    with_maps = maps_png is not None and maps_png.is_file()
    save_with_blueprint(rec, path, sweep_blueprint(lambdas, with_maps))
    if with_maps:
        rec.log("/sweep/maps", rr.EncodedImage(path=maps_png), static=True)
    colours = sweep_colours(len(betas))
    for o, out in enumerate(OUTPUTS):
        rec.log(f"/sweep/map/{out}", rr.Tensor(amps[:, :, o], dim_names=["lambda", "beta"]),
                static=True)
        for j, b in enumerate(betas):
            index = [rr.TimeColumn(SWEEP_TIMELINE, sequence=np.round(lambdas * 1000)
                                   .astype(np.int64))]
            rec.send_columns(f"/sweep/curves/{out}/beta_{b:.2f}", indexes=index,
                             columns=rr.Scalars.columns(scalars=amps[:, j, o]))
            rec.send_columns(f"/sweep/log10/{out}/beta_{b:.2f}", indexes=index,
                             columns=rr.Scalars.columns(scalars=np.log10(amps[:, j, o])))
            for kind in ("curves", "log10"):  # the legend: "beta 0.60", not the path
                rec.log(f"/sweep/{kind}/{out}/beta_{b:.2f}",
                        rr.SeriesLines(names=f"beta {b:.2f}", colors=[colours[j]]),
                        static=True)
    rec.log("/sweep/about", rr.TextDocument(
        f"# Sweep {name}\n\nx axis: the `{SWEEP_TIMELINE}` timeline, lambda = w_m / w_ref "
        f"times 1000 ({lambdas[0]:g} to {lambdas[-1]:g}, {len(lambdas)} points, all in "
        f"view); one curve per beta = U / A ({betas[0]:g} to {betas[-1]:g}, {len(betas)} "
        "values), coloured from dark blue (lowest beta) to yellow (highest) in every plot. "
        "Maps: log10 of each amplitude over lambda x beta with their colour scales "
        "(maps.png; the raw arrays are under /sweep/map).", media_type="text/markdown"),
        static=True)
    try:
        close_stream(rec, path)  # bounded: a full disk's stuck sink never hangs the sweep
    finally:
        del rec
        sweep_orphans()  # the stream dropped: its threads end


def write_sweep(out: Path, spec: SweepSpec, amps: np.ndarray, reference: str,
                run_facts: dict[str, Any]) -> dict[str, Any]:
    """``<out>/<UTC time>-sweep/`` with every file of the sweep; its summary (``run_facts``:
    wall time, workers, engine, put before the laws) as written to summary.json."""
    lambdas, betas, w_ref = spec.lambdas, spec.betas, spec.omega_ref_rad_s
    stamp = dt.datetime.now(dt.UTC).strftime("%Y%m%dT%H%M%S.%fZ")
    out_dir = out / f"{stamp}-sweep"
    out_dir.mkdir(parents=True)
    with (out_dir / "sweep.csv").open("w") as f:
        f.write("lambda,beta,rotor_speed_rad_s,disturbance_amplitude_n_m,"
                "tip_accel_amplitude_m_s2,tip_deflection_amplitude_m\n")
        for i, lam in enumerate(lambdas):
            w = lam * w_ref
            for j, b in enumerate(betas):
                f.write(f"{lam:.6g},{b:.6g},{w:.6g},{spec.amplitude_n_m(w):.6g},"
                        f"{amps[i, j, 0]:.6g},{amps[i, j, 1]:.6g}\n")
    save_plots(out_dir / "maps.png", out_dir / "curves.png", lambdas, betas, amps, reference)
    save_rrd(out_dir / "sweep.rrd", out_dir.name, lambdas, betas, amps,
             maps_png=out_dir / "maps.png")
    summary = {"grid": [len(lambdas), len(betas)], "reference": reference,
               "omega_ref_rad_s": w_ref, **run_facts, "out_dir": str(out_dir),
               "laws": analyse(lambdas, betas, amps)}
    (out_dir / "summary.json").write_text(json.dumps(summary, indent=2))
    return summary
