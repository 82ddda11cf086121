"""`harness commission`: prove the rig file's bindings by the physics (docs/commission.md).

Sensors at rest, then a short, bounded, scripted excitation of every bound device; a
verdict per device and quantity (value, expected, limit, margin) in commission.json,
report.html and commission.rrd. Exit codes as ``harness run``'s: 0 PASS, 1 FAIL, 2 bad
input or refused (nothing sent), 4 an error, 130 interrupted (a fault the monitor raises
is a failed check of the quantity it names: 1).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

DESCRIPTION = """\
Commission a rig: prove that every bound quantity means what the rig file says, by the
physics. Before anything moves, on CANopen: each node's identity, device type and its own
scaling objects (CiA 402 rated torque, CiA 406 measuring units) against the rig file's
conversions. At rest: each sensor's offset and noise against the rig file's noise specs.
Moving (small wheel torque pulses of both signs, one pulse per valve, a chirp per piezo
channel, the rotor): wheel speed against the torque's integral, hub rate against the
torque and the wheel's momentum, the angle against the rate's integral, each valve's
impulse, each piezo sensor against its drive, the tip accelerometer against the model's
ring-down. A miss names the quantity and the likely cause (a factor of 1000, 2 pi,
180/pi, a sign, an offset). Every excitation is checked against the run's and the rig's
limits first.

example:
  harness commission --rig sgsrt-canopen
  harness commission --rig my-rig.yaml --bus socketcan:can0
"""


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser("commission", help="prove a rig file's bindings by the physics: "
                       "every bound device excited briefly, a verdict per quantity",
                       description=DESCRIPTION,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--rig", default="sgsrt", metavar="R",
                   help="rig file (built-in name or path; default sgsrt)")
    p.add_argument("--bus", help="INTERFACE:CHANNEL (default virtual:sgsrt, the in-process "
                   "virtual rig); socketcan:can0 for the lab's rig")
    p.add_argument("--clock", choices=("lockstep", "realtime"),
                   help="default: lockstep on the virtual bus, real time otherwise")
    p.add_argument("--out", type=Path, default=Path("logs"),
                   help="parent of the commissioning folder (default logs/)")
    p.add_argument("--devices-rig", metavar="R2",
                   help="the in-process virtual rig's devices and physics from this rig "
                   "file instead (a lab's devices as they are, against the rig file under "
                   "test; the virtual bus only)")
    p.add_argument("--json", action="store_true", help="the result as JSON on stdout")
    p.set_defaults(func=cmd_commission)


def cmd_commission(args: argparse.Namespace) -> int:
    from harness.bus import BusSpecError
    from harness.commissioning.workflow import Options, commission
    from harness.core.session import RunRefused
    from harness.record.output import OutputError
    from rig_models.schema import ConfigError

    opts = Options(rig=args.rig, bus=args.bus, clock=args.clock, out=args.out,
                   devices_rig=args.devices_rig)
    try:
        result = commission(opts, lambda m: print(m, file=sys.stderr, flush=True))
    except (ConfigError, RunRefused, BusSpecError, ValueError) as exc:
        print(f"harness commission: {exc}", file=sys.stderr)
        return 2
    except OutputError as exc:
        print(f"harness commission: {exc}", file=sys.stderr)
        return 4
    except KeyboardInterrupt:
        print("harness commission: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # a run raised (a driver, the bus): one line, the runs kept
        where = getattr(exc, "run_dir", None)
        print(f"harness commission: error: {type(exc).__name__}: {exc}"
              + (f" (recording in {where})" if where else ""), file=sys.stderr)
        return 4
    if args.json:
        from harness.commissioning.report import _jsonable

        print(json.dumps(_jsonable(result.to_dict()), indent=2))
    else:
        for c in result.checks:
            if c.verdict in ("FAIL", "NOT RUN"):
                value = "-" if c.value is None else f"{c.value:.4g}"
                print(f"{c.verdict} {c.name}: {c.check}: value {value}, expected "
                      f"{c.expected}, limit {c.limit}: {c.cause or c.why}")
        for n in result.notes:
            print(f"note: {n}")
        judged = [c for c in result.checks if c.verdict in ("PASS", "FAIL")]
        n_pass = sum(c.verdict == "PASS" for c in judged)
        print(f"{result.verdict}: {n_pass} of {len(judged)} checks passed "
              f"({result.wall_time_s:.1f} s); report: {Path(result.folder) / 'report.html'}")
    return result.exit_code
