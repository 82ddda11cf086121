"""`harness commission`: prove the rig file's bindings by the physics (docs/commission.md).

Sensors at rest, then a short, bounded, scripted excitation of every bound device; the
rig's model measured from it (friction, lag, inertia, couples, the beam's modes, biases);
a verdict per device and quantity against the physics of that measured model (value,
expected, limit, margin) and per measured rig-file key, in commission.json, report.html
and commission.rrd. Exit codes: 0 PASS, 1 FAIL (a binding; a fault the monitor raises is a
failed check of the quantity it names), 2 bad input or refused (nothing sent), 4 an error,
7 DIFFERS (every binding proved, the rig differs from its file beyond the file's
tolerance), 130 interrupted.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

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

The rig's model is measured from the same runs (the wheel's friction from its coast-down
and its torque lag, the hub's inertia from the momentum exchange, each valve's couple, the
beam's modes from a ring-down, the sensors' biases) and each quantity is judged against
the physics with those measurements in it. A rig that differs from its file beyond the
file's tolerances (its inertia, its beam's damping, ...) is no binding error: the verdict
is DIFFERS (exit 7), naming each key, the file's value and the measured one;
--write-rig FILE then writes the rig file with the measured values to review.

exit codes: 0 PASS, 1 FAIL (a binding), 2 bad input (nothing sent), 4 error,
7 DIFFERS (the rig differs from its file), 130 interrupted

example:
  harness commission --rig sgsrt-canopen
  harness commission --rig my-rig.yaml --bus socketcan:can0 --write-rig my-rig.measured.yaml
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
    p.add_argument("--write-rig", type=Path, metavar="FILE",
                   help="write a rig file (FILE.yaml: extends the rig under test) with the "
                   "measured model values, each with its 1-sigma, when no binding fails; "
                   "review it, then commission with --rig FILE")
    p.add_argument("--json", action="store_true", help="the result as JSON on stdout")
    p.set_defaults(func=cmd_commission)


def cmd_commission(args: argparse.Namespace) -> int:
    """Ctrl-C and SIGTERM as ``harness run`` takes them (harness.core.interrupts): before a
    run begins, at once; during one, at its next tick, the rig left safe; exit 130 with
    commission.json marked INTERRUPTED."""
    from harness.commissioning.workflow import Options
    from harness.core.interrupts import stop_on_signals

    with stop_on_signals() as stop:
        opts = Options(rig=args.rig, bus=args.bus, clock=args.clock, out=args.out,
                       devices_rig=args.devices_rig, write_rig=args.write_rig,
                       should_stop=stop)
        return _commission(args, opts)


def _commission(args: argparse.Namespace, opts: Any) -> int:
    from harness.bus import BusSpecError
    from harness.commissioning.workflow import commission
    from harness.core.session import RunRefused
    from harness.record.output import OutputError
    from rig_models.schema import ConfigError

    try:
        result = commission(opts, lambda m: print(m, file=sys.stderr, flush=True))
    except (ConfigError, RunRefused, BusSpecError, ValueError) as exc:
        print(f"harness commission: {exc}", file=sys.stderr)
        return 2
    except OutputError as exc:
        print(f"harness commission: {exc}", file=sys.stderr)
        return 4
    except KeyboardInterrupt:  # before anything began: nothing sent
        print("harness commission: interrupted before a run began; nothing sent",
              file=sys.stderr)
        return 130
    except Exception as exc:  # a run raised (a driver, the bus): one line, the runs kept
        where = getattr(exc, "run_dir", None)
        print(f"harness commission: error: {type(exc).__name__}: {exc}"
              + (f" (recording in {where})" if where else ""), file=sys.stderr)
        return 4
    from harness.commissioning.report import _fmt

    if args.json:
        from harness.commissioning.report import _jsonable

        print(json.dumps(_jsonable(result.to_dict()), indent=2))
    else:
        for c in result.checks:
            if c.verdict in ("FAIL", "NOT RUN") or (c.verdict == "DIFFERS"
                                                    and result.verdict == "DIFFERS"):
                value = "-" if c.value is None else f"{c.value:.4g}"
                sigma = "" if c.sigma is None else f" +- {c.sigma:.2g}"
                print(f"{c.verdict} {c.name}: {c.check}: value {value}{sigma}, expected "
                      f"{_fmt(c.expected)}, limit {_fmt(c.limit)}: {c.cause or c.why}")
        for n in result.notes:
            print(f"note: {n}")
        judged = [c for c in result.checks if c.verdict in ("PASS", "FAIL") and not c.key]
        n_pass = sum(c.verdict == "PASS" for c in judged)
        model = [c for c in result.checks if c.key and c.verdict in ("PASS", "DIFFERS")]
        n_same = sum(c.verdict == "PASS" for c in model)
        print(f"{result.verdict}: {n_pass} of {len(judged)} binding checks passed, {n_same} of "
              f"{len(model)} measured rig-file values within the file's tolerance "
              f"({result.wall_time_s:.1f} s); report: {Path(result.folder) / 'report.html'}")
    return result.exit_code
