"""`harness sweep`: residual vibration over frequency ratio x amplitude ratio (paper 003,
Figures 6-9) on the rig model, on every core
(or on a Dask cluster: ``--cluster tcp://HOST:8786`` or ``$SGSRT_CLUSTER``, see
docs/suites.md).

Writes ``<out>/<UTC time>-sweep/`` with ``sweep.csv``, ``sweep.rrd`` (the maps as tensors and
one curve per beta against lambda), ``maps.png``, ``curves.png`` and ``summary.json`` (where
the minimum over beta lies for each lambda, and where the resonances are).
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from harness.engine import CLUSTER_ENV, EngineError, make_engine
from harness.record.recording import close_stream
from harness.record.streams import save_with_blueprint, sweep_orphans
from harness.studies.sweep import SweepSpec, run_sweep
from rig_models.rig_file import load_rig
from rig_models.schema import ConfigError

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
        sweep_orphans()  # the stream dropped: its threads end (issue 23)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("sweep", help="residual vibration over lambda x beta on the rig model",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--rig", default="sgsrt")
    p.add_argument("--lambda-min", type=float, default=0.3)
    p.add_argument("--lambda-max", type=float, default=3.2)
    p.add_argument("--n-lambda", type=int, default=30)
    p.add_argument("--beta-min", type=float, default=0.3)
    p.add_argument("--beta-max", type=float, default=1.0)
    p.add_argument("--n-beta", type=int, default=8)
    p.add_argument("--reference", choices=("hub_free", "constrained"), default="hub_free",
                   help="lambda = w_m / mode 1 of this kind (default hub_free: where the rig "
                   "resonates)")
    p.add_argument("--mass-kg", type=float, default=0.4, help="eccentric mass m_m")
    p.add_argument("--eccentricity-m", type=float, default=0.04, help="sigma_m")
    p.add_argument("--dish-radius-m", type=float, default=0.6, help="P_m")
    p.add_argument("--workers", type=int, default=os.cpu_count() or 1,
                   help="processes (default: every core)")
    p.add_argument("--cluster", metavar="tcp://HOST:8786",
                   help=f"run on this Dask scheduler's workers (default ${CLUSTER_ENV}, if "
                   "set; see docs/suites.md)")
    p.add_argument("--out", type=Path, default=Path("logs"))
    p.add_argument("--json", action="store_true", help="summary JSON on stdout")
    p.set_defaults(func=cmd_sweep)


MAX_SWEEP_POINTS = 1_000_000
"""The largest grid (lambdas x betas): the default is 30 x 30; a grid of 10^5 x 10^5 asked
for arrays of 149 GiB and ended in a traceback."""

SWEEP_BYTES_PER_POINT = 16
"""What a grid point's results take (two float64: rotor speed and disturbance amplitude)."""


def cmd_sweep(args: argparse.Namespace) -> int:
    try:
        if args.n_lambda < 2 or args.n_beta < 2:
            raise ConfigError("--n-lambda and --n-beta must be >= 2")
        points = args.n_lambda * args.n_beta
        if points > MAX_SWEEP_POINTS:
            raise ConfigError(
                f"--n-lambda {args.n_lambda} x --n-beta {args.n_beta}: {points} grid points "
                f"(about {points * SWEEP_BYTES_PER_POINT / 2**30:.0f} GiB of results), more "
                f"than the {MAX_SWEEP_POINTS} a sweep may have")
        if not 0 < args.lambda_min < args.lambda_max:
            raise ConfigError("--lambda-min must be > 0 and < --lambda-max")
        if not 0 <= args.beta_min < args.beta_max:
            raise ConfigError("--beta-min must be >= 0 and < --beta-max")
        rig = load_rig(args.rig)
        engine = make_engine(args.cluster, args.workers, preload=("harness.studies.sweep",))
    except (ConfigError, EngineError) as exc:
        print(f"harness sweep: {exc}", file=sys.stderr)
        return 2
    model = rig.plant
    w_ref = float(model.hub_free_modes()[0][0] if args.reference == "hub_free"
                  else rig.beam_modes.omega_rad_s[0])
    lambdas = np.linspace(args.lambda_min, args.lambda_max, args.n_lambda)
    betas = np.linspace(args.beta_min, args.beta_max, args.n_beta)
    spec = SweepSpec(lambdas, betas, w_ref, args.mass_kg, args.eccentricity_m,
                     args.dish_radius_m)
    t0 = time.perf_counter()

    def progress(done: int, total: int) -> None:
        print(f"harness sweep: {done}/{total} lambdas ({time.perf_counter() - t0:.0f} s)",
              file=sys.stderr, flush=True)

    print(f"harness sweep: {args.n_lambda} x {args.n_beta} grid, w_ref {w_ref:.4f} rad/s "
          f"({args.reference}), {engine.name}", file=sys.stderr)
    try:
        amps = run_sweep(model, spec, progress=progress, engine=engine)
    finally:
        engine.close()
    wall = time.perf_counter() - t0
    stamp = dt.datetime.now(dt.UTC).strftime("%Y%m%dT%H%M%S.%fZ")
    out_dir = args.out / f"{stamp}-sweep"
    out_dir.mkdir(parents=True)
    with (out_dir / "sweep.csv").open("w") as f:
        f.write("lambda,beta,rotor_speed_rad_s,disturbance_amplitude_n_m,"
                "tip_accel_amplitude_m_s2,tip_deflection_amplitude_m\n")
        for i, lam in enumerate(lambdas):
            w = lam * w_ref
            for j, b in enumerate(betas):
                f.write(f"{lam:.6g},{b:.6g},{w:.6g},{spec.amplitude_n_m(w):.6g},"
                        f"{amps[i, j, 0]:.6g},{amps[i, j, 1]:.6g}\n")
    save_plots(out_dir / "maps.png", out_dir / "curves.png", lambdas, betas, amps,
               args.reference)
    save_rrd(out_dir / "sweep.rrd", out_dir.name, lambdas, betas, amps,
             maps_png=out_dir / "maps.png")
    summary = {"grid": [args.n_lambda, args.n_beta], "reference": args.reference,
               "omega_ref_rad_s": w_ref, "wall_time_s": round(wall, 2),
               "workers": engine.workers, "engine": engine.name, "out_dir": str(out_dir),
               "laws": analyse(lambdas, betas, amps)}
    (out_dir / "summary.json").write_text(json.dumps(summary, indent=2))
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        for name in OUTPUTS:
            law = summary["laws"][name]
            print(f"{name}: median best beta for lambda > 0.5 = "
                  f"{law['best_beta_median_lambda_gt_0.5']:.2f}; share of lambda > 0.5 with "
                  f"best beta in [0.6, 0.85] = "
                  f"{law['share_lambda_gt_0.5_with_best_beta_in_0.6_0.85']:.2f}; "
                  f"resonances near lambda = {law['resonance_lambdas']}")
    print(f"harness sweep: {wall:.1f} s; results in {out_dir}", file=sys.stderr)
    return 0
