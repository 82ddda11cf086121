"""`harness calibrate [--bus I:C] [--rig R] [--actuator wheel|valves] [--angle-deg A]
[--out DIR] [--json] [--dry-run]`: from the rig's vibration to a verified shaped slew.

1. Excite and identify: square-wave bursts of the actuator at each mode the rig file's model
   predicts (the prediction only places the excitation), each followed by a free decay long
   enough for the predicted damping, repeated until the Cramer-Rao bound says the frequency
   and damping will be known well; then the modes are identified from the tip accelerometer
   as `harness identify` does (frequency, damping, 1 sigma). An excitation beyond a device
   limit (wheel torque or speed, valve minimum on-time, accelerometer range, bus load) is
   refused; a mode the excitation cannot reach (above the accelerometer's Nyquist frequency,
   too fast for the loop or the valves, too weak against the accelerometer's noise) or that
   the identification does not find is named with the reason.
2. Design candidates over the identified modes: wheel ZV, ZVD, EI (5 %) and SI (specified
   insensitivity: 5 % over each mode's band), one per mode, convolved; valves damped LHHL and
   HLLH (lowest two modes) with and without a ZV for the higher modes, made by the valves'
   PWM. Each is scored by its worst residual vibration over each mode's band (+-max(3 sigma,
   5 %) in frequency, +-3 sigma in damping), its added duration, and for the valves fuel and
   firings.
3. Verify on the rig: the unshaped slew and every candidate; residual = the identified modes
   fitted to the recorded residual (and the raw peak; the noise-free truth on the virtual
   rig). Recommended: the cheapest candidate (wheel: added duration; valves: fuel, then
   duration) whose fitted residual is `--target-ratio` (default 10) times below the unshaped
   slew's (or below `--target-m-s2`) and whose predicted worst case over the bands is too.
4. Outputs in `--out` (default logs/) / `<UTC time>-calibrate-<rig>-<actuator>/`:
   `recommended.yaml` and `baseline.yaml` (run files for `harness run`), `candidates/*.yaml`,
   `report.md` with `spectrum.png`, `sensitivity.png`, `residuals.png` and a table linking
   every recording (`runs/*/run.rrd`), `results.json`. `--json` prints the results (keys
   `run_file`, `baseline_run_file`, `identified_modes`, `candidates`, ...). Progress goes to
   stderr.

On the default bus (`virtual:RIG`, named after the rig) every run is lockstep against the
in-process virtual rig of `--rig`; on another bus (the lab rig) the runs are real time.
`--dry-run` prints the excitation plan and sends nothing. Exit status: 0 a recommendation
meets the target, 1 none does (the best is still written), 2 bad input or a refused
excitation, 3 a fault stopped a run, 4 another error.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from harness.commands import examples
from rig_models.schema import ConfigError


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("calibrate", help="excite, identify, design and verify a shaped slew "
                       "in one command", description=__doc__,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--bus", help="INTERFACE:CHANNEL (default virtual:RIG, the in-process "
                   "virtual rig of --rig, lockstep; any other bus runs in real time)")
    p.add_argument("--rig", default="sgsrt", help="rig name or YAML path (default sgsrt)")
    p.add_argument("--actuator", choices=("wheel", "valves"), default="wheel",
                   help="the actuator that excites and slews (default wheel)")
    p.add_argument("--angle-deg", type=float,
                   help="slew angle (deg; default 20 with the wheel, 5 with the valves)")
    p.add_argument("--out", type=Path, default=Path("logs"),
                   help="parent of the calibration folder (default logs/)")
    p.add_argument("--rate-hz", type=float, default=500.0, help="loop rate (default 500 Hz)")
    p.add_argument("--target-ratio", type=float, default=10.0,
                   help="residual target: this many times below the unshaped slew (default 10)")
    p.add_argument("--target-m-s2", type=float,
                   help="residual target as an absolute fitted peak (m/s^2) instead")
    p.add_argument("--excite-torque-n-m", type=float,
                   help="wheel torque of the excitation bursts (N m; default 90 %% of the "
                   "wheel's maximum, lowered for its speed limit and the accelerometer's range)")
    p.add_argument("--max-verify", type=int,
                   help="verify at most N candidates (default: every feasible one)")
    p.add_argument("--dry-run", action="store_true",
                   help="print the excitation plan (and its run file) and send nothing")
    p.add_argument("--json", action="store_true", help="results as JSON on stdout")
    p.epilog = examples(
        "harness calibrate",
        "harness calibrate --actuator valves --angle-deg 5 --json",
        "harness calibrate --bus socketcan:can0 --dry-run")
    p.set_defaults(func=cmd_calibrate)


def _progress(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def cmd_calibrate(args: argparse.Namespace) -> int:
    # the loop, python-can, numpy and scipy only when calibrating (start-up of `harness --help`)
    import yaml

    from harness.bus import BusSpecError
    from harness.calibration.workflow import (
        CalibrationError,
        Options,
        _jsonable,
        calibrate,
        plan_run_dict,
    )
    from harness.core.session import RunRefused

    if args.max_verify is not None and args.max_verify < 1:
        print(f"harness calibrate: --max-verify: expected >= 1, got {args.max_verify}",
              file=sys.stderr)
        return 2
    opts = Options(rig=args.rig, actuator=args.actuator, angle_deg=args.angle_deg,
                   out=args.out, bus=args.bus, rate_hz=args.rate_hz,
                   target_ratio=args.target_ratio, target_m_s2=args.target_m_s2,
                   excite_torque_n_m=args.excite_torque_n_m, dry_run=args.dry_run,
                   max_verify=args.max_verify)
    try:
        result = calibrate(opts, _progress)
    except (ConfigError, RunRefused, BusSpecError, ValueError) as exc:
        print(f"harness calibrate: {exc}", file=sys.stderr)
        return 2
    except CalibrationError as exc:
        print(f"harness calibrate: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print("harness calibrate: interrupted", file=sys.stderr)
        return 130
    if args.dry_run:
        if args.json:
            print(json.dumps(_jsonable(dict(result.to_dict(),
                                            excitation_run=plan_run_dict(result))), indent=2))
        else:
            print("\n".join(result.plan.describe()))
            print("\nexcitation run file (nothing sent):\n")
            print(yaml.safe_dump(plan_run_dict(result), sort_keys=False))
        return 0
    data = _jsonable(result.to_dict())
    if result.folder is not None:
        from harness.history.record import record_calibration  # results database

        record_calibration(result.folder, data)
    if args.json:
        print(json.dumps(data, indent=2))
    else:
        for n in result.notes:
            print(f"note: {n}")
        print(f"report: {result.report}")
        print(f"baseline run file: {result.baseline_run_file}")
        if result.recommended is not None:
            row = result.verified[result.recommended]
            print(f"recommended: {result.recommended} ({row['ratio_fitted']:.1f}x below "
                  f"unshaped, fitted"
                  + (f"; truth {row['ratio_truth']:.1f}x" if "ratio_truth" in row else "")
                  + f"): {result.run_file}")
        print(f"target {'met' if result.target_met else 'NOT met'}: "
              f"{result.recommendation_note}")
    return 0 if result.target_met else 1
