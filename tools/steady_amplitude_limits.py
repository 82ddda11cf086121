"""Where case-a's and case-b's ``steady_amplitude`` limits come from (harness/runs/case-*.yaml).

Each variant (beta 0.6 / 0.8 / 1.0) is run on the virtual rig once per noise seed (the rig
file's ``noise_seed``: 1001, 1002, ..., as ``harness history scatter`` does, whose
``predict`` this reuses with its cache under ``LOGS/scatter/``), and its steady tip
acceleration amplitude's mean and standard deviation printed with the limit they give:

    limit = mean + 3 std, rounded up to 0.1 mm/s^2

i.e. the amplitude our model gives at this beta, beyond which a run's amplitude is a real
change, not another noise draw (the same 3 sigma as ``harness history scatter``'s
"beyond"). Beside it, the degradation each case's limit must catch (``DEGRADED``), run over
``--degraded-seeds`` seeds: its mean, smallest value and how many of its standard
deviations its mean lies beyond the limit. tests/test_builtin_criteria_fail.py runs the
same degradations (noise seed 1) and expects FAIL.

Why not paper 003's Table 2 amplitudes: they are 3-10 times above what our model gives even
without compensation, so they could not fail (docs/criteria.md). Under 2 minutes a variant on
one core (15 runs of 100 s in lockstep), cached:

    .venv/bin/python tools/steady_amplitude_limits.py [--seeds 10] [--degraded-seeds 5]
        [--logs logs] [--case case-a ...] [--variant beta-0.8 ...] [--json]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:  # run as a script from anywhere
    sys.path.insert(0, str(ROOT))

MEASURE = "steady_tip_accel_amplitude_m_s2"
CRITERION = "steady_amplitude"
K_SIGMA = 3.0
RESOLUTION_M_S2 = 1e-4
CASES = ("case-a", "case-b")


def _stronger(beta: float) -> dict[str, Any]:
    return {"controller": {"beta": round(1.25 * beta, 6)}}


def _off(beta: float) -> dict[str, Any]:
    return {"controller": {"compensate": False}}


DEGRADED: dict[str, tuple[str, Callable[[float], dict[str, Any]]]] = {
    # case A: the compensation off is no degradation by amplitude (at beta 0.8 our model
    # gives the same amplitude with it as without, and less without it than at beta 1.0:
    # the square wave's edges shake the hub as much as the fundamental it cancels), so its
    # limits must catch a gain changed instead
    "case-a": ("the compensation's torque 25 % high (a wheel torque constant or the "
               "disturbance law's gain wrong: beta x 1.25)", _stronger),
    # case B: near resonance the compensation halves the amplitude at every beta
    "case-b": ("the compensation off (controller.compensate false): the rotor's "
               "disturbance alone", _off),
}
"""Per case: what the degradation stands for, and the run overrides it makes from the
variant's beta."""


def case_run(case: str, variant: str | None,
             extra: Callable[[float], dict[str, Any]] | None = None) -> Any:
    """The run file's variant as ``harness run CASE --variant VARIANT`` runs it (None: the
    run file without its variants), with ``extra(beta)``'s overrides on top (a
    degradation)."""
    from harness.core.runs import _deep_merge, load_run

    over: dict[str, Any] = {"variants": None}
    if variant is not None:
        over = {**load_run(case).data["variants"][variant], "name": f"{case}-{variant}"}
    run = load_run(case, over)
    if extra is None:
        return run
    return load_run(case, _deep_merge(over, extra(float(run.controller["beta"]))))


def _measured_only(run: Any) -> dict[str, Any]:
    """The run's data with one criterion on the measure (its limit unused: only the value is
    read), so the cache's key does not change when the run file's limits do."""
    data = {k: v for k, v in run.data.items() if k != "variants"}
    data["expect"] = {CRITERION: {"measure": MEASURE, "max_m_s2": 1.0,
                                  "why": "measured, not judged"}}
    return data


def scatter(run: Any, logs: Path, seeds: int, label: str) -> dict[str, Any]:
    from harness.history.scatter import CACHE_DIR, cache_key, predict

    data = _measured_only(run)
    rig = dict(run.rig.data)
    cache = logs / CACHE_DIR / f"{cache_key(data, rig, seeds)}.json"
    got = predict(data, rig, cache, seeds,
                  progress=lambda m: print(f"{label}: {m}", file=sys.stderr))
    return got["criteria"][CRITERION]


def marginal_of(std: float) -> float:
    """One std (two significant digits): within it of the limit, another noise draw could
    fail, so the verdict is MARGINAL."""
    return float(f"{std:.2g}")


def limit_of(mean: float, std: float) -> float:
    """mean + 3 std, rounded up to the resolution the run files write."""
    steps = math.ceil((mean + K_SIGMA * std) / RESOLUTION_M_S2 - 1e-9)
    return round(steps * RESOLUTION_M_S2, 6)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--seeds", type=int, default=10)
    p.add_argument("--degraded-seeds", type=int, default=5)
    p.add_argument("--logs", type=Path, default=Path("logs"))
    p.add_argument("--case", action="append", choices=CASES)
    p.add_argument("--variant", action="append")
    p.add_argument("--json", action="store_true")
    args = p.parse_args(argv)
    if args.seeds < 2 or args.degraded_seeds < 2:
        p.error("--seeds and --degraded-seeds: at least 2 (a standard deviation)")
    from harness.core.runs import load_run

    rows = []
    for case in args.case or CASES:
        what, extra = DEGRADED[case]
        for variant in load_run(case).data["variants"]:
            if args.variant and variant not in args.variant:
                continue
            run = case_run(case, variant)
            s = scatter(run, args.logs, args.seeds, f"{case}[{variant}]")
            limit = limit_of(s["mean"], s["std"])
            d = scatter(case_run(case, variant, extra), args.logs, args.degraded_seeds,
                        f"{case}[{variant}] degraded")
            rows.append({"case": case, "variant": variant,
                         "beta": float(run.controller["beta"]), "mean_m_s2": s["mean"],
                         "std_m_s2": s["std"], "seeds": s["n"], "limit_m_s2": limit,
                         "marginal_m_s2": marginal_of(s["std"]),
                         "degraded": what, "degraded_mean_m_s2": d["mean"],
                         "degraded_std_m_s2": d["std"], "degraded_min_m_s2": min(d["values"]),
                         "degraded_z": (d["mean"] - limit) / d["std"] if d["std"] else None})
    if args.json:
        print(json.dumps(rows, indent=2))
        return 0
    print(f"steady tip acceleration amplitude (m/s^2), noise seeds 1001-{1000 + args.seeds}; "
          f"limit = mean + {K_SIGMA:g} std, rounded up to {RESOLUTION_M_S2:g}")
    print()
    print("| case | beta | mean | std | limit (max_m_s2) | marginal_m_s2 | degraded mean | "
          "degraded std | degraded min | degraded mean beyond the limit (its std) |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        z = "-" if r["degraded_z"] is None else f"{r['degraded_z']:+.1f}"
        print(f"| {r['case']} | {r['beta']:g} | {r['mean_m_s2']:.5f} | {r['std_m_s2']:.5f} | "
              f"{r['limit_m_s2']:.4f} | {r['marginal_m_s2']:g} | {r['degraded_mean_m_s2']:.5f} | "
              f"{r['degraded_std_m_s2']:.5f} | {r['degraded_min_m_s2']:.5f} | {z} |")
    print()
    for case in dict.fromkeys(r["case"] for r in rows):
        print(f"{case} degraded: {DEGRADED[case][0]}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
