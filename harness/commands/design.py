"""`harness design lhhl|hllh|evaluate`: two-amplitude fuel-efficient shapers (Parman 2022).

    harness design lhhl --inertia-kg-m2 17731 --torque-n-m 8 --angle-deg 3 \\
        --mode 0.3354:0.001 1.082:1 [--json]
    harness design evaluate --times 0 1.24 3.27 ... --amplitudes 0.5 -0.5 1 ... \\
        --inertia-kg-m2 17731 --torque-n-m 8 [--angle-deg 3] [--mode 0.3354:0.001 ...] [--json]

Amplitudes are in units of the high torque T; the low level is T/2.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from typing import TYPE_CHECKING

from harness.commands import examples

if TYPE_CHECKING:
    from harness.shaping.two_amplitude import SequenceReport


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser(
        "design",
        help="design or evaluate a two-amplitude fuel-efficient shaper (LHHL / HLLH)",
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.epilog = examples(
        "harness design lhhl --inertia-kg-m2 17731 --torque-n-m 8 --angle-deg 3 --mode"
        " 0.3354:0.001 1.082:1",
        "harness design evaluate --times 0 1 2 3 --amplitudes 1 -1 -1 1 --inertia-kg-m2 100"
        " --torque-n-m 1")
    kinds = parser.add_subparsers(dest="design_kind", metavar="KIND")
    for kind in ("lhhl", "hllh"):
        p = kinds.add_parser(kind, help=f"shortest {kind.upper()} sequence meeting mode limits")
        _add_plant_args(p)
        p.add_argument("--angle-deg", type=float, required=True, help="desired rotation (deg)")
        p.add_argument(
            "--mode",
            action="extend",
            nargs="+",
            required=True,
            metavar="FREQ_RAD_S:VMAX_PERCENT",
            help="a mode to suppress and its residual-vibration limit, e.g. 0.3354:0.001",
        )
        p.add_argument("--starts", type=int, default=128, help="multi-start count (default 128)")
        p.add_argument("--seed", type=int, default=0, help="seed of the Sobol starts")
        p.add_argument("--max-t8-s", type=float, default=None, help="bound of the searched box")
        p.add_argument(
            "--grid-points", type=int, default=200, help="dense scan points per side (0: off)"
        )
        p.add_argument("--json", action="store_true", help="print machine-readable results")
        p.set_defaults(func=_run_design, kind=kind.upper())
    e = kinds.add_parser("evaluate", help="report V, angle, fuel and impulse of any sequence")
    _add_plant_args(e)
    e.add_argument("--times", type=float, nargs="+", required=True, help="impulse times (s)")
    e.add_argument(
        "--amplitudes", type=float, nargs="+", required=True, help="impulse amplitudes (units of T)"
    )
    e.add_argument(
        "--angle-deg", type=float, default=None, help="bang-bang reference angle (default: own)"
    )
    e.add_argument(
        "--mode",
        action="extend",
        nargs="+",
        default=[],
        metavar="FREQ_RAD_S[:VMAX_PERCENT]",
        help="frequencies at which to report V (with optional limits)",
    )
    e.add_argument("--json", action="store_true", help="print machine-readable results")
    e.set_defaults(func=_run_evaluate)
    parser.set_defaults(func=lambda args: (parser.print_help(sys.stderr), 2)[1])


def _add_plant_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--inertia-kg-m2", type=float, required=True, help="axis inertia (kg m^2)")
    p.add_argument("--torque-n-m", type=float, required=True, help="high torque level T (N m)")


def _run_design(args: argparse.Namespace) -> int:
    # numpy and scipy only when designing (start-up of `harness --help`)
    from harness.shaping.two_amplitude import ModeConstraint, design_two_amplitude

    try:
        modes = [ModeConstraint.parse(m) for m in args.mode]
        print(f"searching {args.kind} ({args.starts} starts + dense scan) ...", file=sys.stderr)
        design = design_two_amplitude(
            args.kind,
            inertia_kg_m2=args.inertia_kg_m2,
            torque_n_m=args.torque_n_m,
            angle_rad=math.radians(args.angle_deg),
            modes=modes,
            n_starts=args.starts,
            seed=args.seed,
            max_t8_s=args.max_t8_s,
            grid_points=args.grid_points,
        )
    except ValueError as exc:
        print(f"harness design: {exc}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(design.to_dict(), indent=2))
        return 0
    s = design.search
    print(
        f"{design.kind}: t2 = {design.t2_s:.4f} s, b = {design.b_s:.4f} s, "
        f"c = {design.c_s:.4f} s, d = {design.d_s:.4f} s"
    )
    _print_report(design.report)
    grid = (
        "off"
        if s.grid_t8_s is None and s.grid_points == 0
        else (f"{s.grid_t8_s:.3f} s" if s.grid_t8_s is not None else "nothing found")
    )
    print(
        f"search: {s.n_feasible}/{s.n_starts} starts feasible, {s.n_agree} within "
        f"{s.agree_tol_s * 1e3:.0f} ms of the best; dense scan ({s.grid_points} points x "
        f"{s.grid_step_t8_s:.3f} s steps) first feasible t8 = {grid}"
        f"{' (improved the result)' if s.improved_by_grid else ''}"
    )
    return 0


def _run_evaluate(args: argparse.Namespace) -> int:
    # numpy and scipy only when evaluating (start-up of `harness --help`)
    from harness.shaping.two_amplitude import ModeConstraint, evaluate_sequence

    try:
        freqs: list[float] = []
        limits: list[float] = []
        for text in args.mode:
            if ":" in text:
                m = ModeConstraint.parse(text)
                freqs.append(m.freq_rad_s)
                limits.append(m.vmax_percent)
            else:
                freqs.append(float(text))
        if limits and len(limits) != len(freqs):
            raise ValueError("give a limit for every --mode or for none")
        report = evaluate_sequence(
            args.times,
            args.amplitudes,
            inertia_kg_m2=args.inertia_kg_m2,
            torque_n_m=args.torque_n_m,
            freqs_rad_s=freqs,
            vmax_percent=limits or None,
            reference_angle_rad=None if args.angle_deg is None else math.radians(args.angle_deg),
        )
    except ValueError as exc:
        print(f"harness design evaluate: {exc}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(report.to_dict(), indent=2))
    else:
        _print_report(report)
    return 0


def _print_report(r: SequenceReport) -> None:
    print("times (s):  " + " ".join(f"{t:.3f}" for t in r.times_s))
    print("amplitudes: " + " ".join(f"{a:+.2f}" for a in r.amplitudes))
    angle_deg = math.degrees(r.angle_rad)
    ref_deg = math.degrees(r.reference_angle_rad)
    print(
        f"angle = {angle_deg:.4f} deg (reference {ref_deg:.4f} deg, bang-bang "
        f"{r.bang_bang_duration_s:.3f} s), final rate = {r.final_rate_rad_s:.2e} rad/s"
    )
    print(
        f"t8 = {r.t8_s:.3f} s, fuel on {r.fuel_on_time_s:.3f} s (high {r.high_on_time_s:.3f} s, "
        f"low {r.low_on_time_s:.3f} s), impulse = {r.impulse_n_m_s:.2f} N m s"
    )
    limits = r.vmax_percent or (None,) * len(r.mode_freqs_rad_s)
    for w, v, lim in zip(r.mode_freqs_rad_s, r.residual_percent, limits, strict=True):
        status = "" if lim is None else (f"  (limit {lim:g} %: {'met' if v <= lim else 'NOT met'})")
        print(f"V({w:g} rad/s) = {v:.5f} %{status}")
