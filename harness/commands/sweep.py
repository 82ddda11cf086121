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
import json
import os
import sys
import time
from pathlib import Path

from harness.commands import examples
from harness.engine import CLUSTER_ENV


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("sweep", help="residual vibration over lambda x beta on the rig model",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter,
                       epilog=examples("harness sweep",
                                       "harness sweep --n-lambda 60 --n-beta 15 --workers 2",
                                       "harness sweep --reference constrained --json"))
    p.add_argument("--rig", default="sgsrt", help="rig name or YAML path (default sgsrt)")
    p.add_argument("--lambda-min", type=float, default=0.3,
                   help="lowest frequency ratio lambda = w_m / w_ref (default 0.3)")
    p.add_argument("--lambda-max", type=float, default=3.2,
                   help="highest frequency ratio lambda (default 3.2)")
    p.add_argument("--n-lambda", type=int, default=30,
                   help="lambdas, evenly spaced from --lambda-min to --lambda-max (default 30)")
    p.add_argument("--beta-min", type=float, default=0.3,
                   help="lowest amplitude ratio beta = U / A, the wheel's square wave over "
                   "the disturbance (default 0.3)")
    p.add_argument("--beta-max", type=float, default=1.0,
                   help="highest amplitude ratio beta (default 1.0)")
    p.add_argument("--n-beta", type=int, default=8,
                   help="betas, evenly spaced from --beta-min to --beta-max (default 8)")
    p.add_argument("--reference", choices=("hub_free", "constrained"), default="hub_free",
                   help="lambda = w_m / mode 1 of this kind (default hub_free: where the rig "
                   "resonates)")
    p.add_argument("--mass-kg", type=float, default=0.4,
                   help="the rotor's eccentric mass m_m (default 0.4 kg)")
    p.add_argument("--eccentricity-m", type=float, default=0.04,
                   help="the eccentric mass's offset sigma_m (default 0.04 m)")
    p.add_argument("--dish-radius-m", type=float, default=0.6,
                   help="the rotor's distance from the hub axis P_m (default 0.6 m)")
    p.add_argument("--workers", type=int, default=os.cpu_count() or 1,
                   help="processes (default: every core)")
    p.add_argument("--cluster", metavar="tcp://HOST:8786",
                   help=f"run on this Dask scheduler's workers (default ${CLUSTER_ENV}, if "
                   "set; see docs/suites.md)")
    p.add_argument("--out", type=Path, default=Path("logs"),
                   help="where the sweep's folder is made (default logs)")
    p.add_argument("--json", action="store_true", help="summary JSON on stdout")
    p.set_defaults(func=cmd_sweep)


MAX_SWEEP_POINTS = 1_000_000
"""The largest grid (lambdas x betas): the default is 30 x 30; a grid of 10^5 x 10^5 asked
for arrays of 149 GiB and ended in a traceback."""

SWEEP_BYTES_PER_POINT = 16
"""What a grid point's results take (two float64: rotor speed and disturbance amplitude)."""


def cmd_sweep(args: argparse.Namespace) -> int:
    # numpy, scipy, Matplotlib and Rerun only when a sweep runs (start-up of `harness --help`)
    import numpy as np

    from harness.engine import EngineError, make_engine
    from harness.studies.sweep import SweepSpec, run_sweep
    from harness.studies.sweep_report import OUTPUTS, write_sweep
    from rig_models.rig_file import load_rig
    from rig_models.schema import ConfigError

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
    summary = write_sweep(args.out, spec, amps, args.reference,
                          {"wall_time_s": round(wall, 2), "workers": engine.workers,
                           "engine": engine.name})
    out_dir = summary["out_dir"]
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
