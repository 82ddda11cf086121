"""`harness run NAME|PATH`: run a test on the (virtual) rig and record it."""

from __future__ import annotations

import argparse
import json
import signal
import sys
from pathlib import Path

from harness.bus import BusSpecError
from harness.runs import load_run
from harness.session import RunRefused, execute_run
from rig_models.schema import ConfigError


def _sigterm_to_interrupt(signum: int, frame: object) -> None:
    raise KeyboardInterrupt


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("run", help="run a test (built-in name or YAML path) and record it",
                       description="Run a test on the virtual rig (default) or the lab rig. "
                       "Writes logs/<UTC time>-<name>/ with run.rrd, can.blf, config.yaml and "
                       "summary.json. Progress goes to stderr; --json prints the summary.")
    p.add_argument("run", help="built-in run name (see 'harness cases') or a run file path")
    p.add_argument("--bus", help="INTERFACE:CHANNEL, e.g. virtual:sgsrt (default), "
                   "socketcan:vcan0, socketcand:127.0.0.1:29536")
    p.add_argument("--clock", choices=("lockstep", "realtime"), help="override the run's clock")
    p.add_argument("--out", type=Path, default=Path("logs"), help="parent directory of the "
                   "run directory (default: ./logs)")
    p.add_argument("--duration-s", type=float, help="override the run's duration (s)")
    p.add_argument("--json", action="store_true", help="print the summary as JSON on stdout")
    p.add_argument("--quiet", action="store_true", help="no progress output")
    p.add_argument("--dry-run", action="store_true",
                   help="read every sensor, never send a command frame (actuators stay at rest)")
    p.add_argument("--view", nargs="?", const="rerun+http://127.0.0.1:9876/proxy",
                   metavar="URL", help="also stream to a Rerun viewer you started with "
                   "'rerun --bind 127.0.0.1' (default URL rerun+http://127.0.0.1:9876/proxy)")
    p.set_defaults(func=cmd_run)


def cmd_run(args: argparse.Namespace) -> int:
    previous = signal.signal(signal.SIGTERM, _sigterm_to_interrupt)
    try:
        overrides = {"duration_s": args.duration_s} if args.duration_s else None
        run = load_run(args.run, overrides)
        if args.view and "127.0.0.1" not in args.view and "localhost" not in args.view:
            raise ConfigError(f"--view {args.view}: the live view stays on 127.0.0.1")
        result = execute_run(run, out_dir=args.out, bus=args.bus, clock=args.clock,
                             live_view_url=args.view, show_progress=not args.quiet,
                             dry_run=args.dry_run)
    except (ConfigError, BusSpecError, RunRefused) as exc:
        print(f"harness: {exc}", file=sys.stderr)
        return 2
    finally:
        signal.signal(signal.SIGTERM, previous)
    s = result.summary
    if args.json:
        print(json.dumps(s, indent=2))
    print(f"harness: {s['run']} {s['stopped_by']}: final angle error "
          f"{s['final_angle_error_deg']} deg, settle {s['settle_time_s']} s, "
          f"residual tip accel {s['residual_tip_accel_m_s2']} m/s^2, "
          f"{s['real_time_factor']}x real time; recording in {result.run_dir}", file=sys.stderr)
    return 0 if s["stopped_by"] == "completed" else 130
