"""`harness run NAME|PATH`: run a test on the (virtual) rig and record it.

Run a test on the virtual rig (default) or the lab rig. Writes logs/<UTC time>-<name>/ with
run.rrd, can.blf, config.yaml and summary.json, then judges the run by its expect: criteria
and writes verdict.json and verdict.rrd (docs/criteria.md). Progress goes to stderr; --json
prints the summary. Exit codes: 0 PASS (or NO CRITERIA: nothing judged, with a warning),
1 FAIL, 2 bad input or run refused before anything was sent, 3 ERROR by a fault the run did
not expect, 4 ERROR otherwise (exception, missing data), 5 MARGINAL, 6 INCONCLUSIVE (a
real-time run the bench did not hold in time: overruns, lateness or telemetry missing
beyond the run file's realtime limits; the verdict names whose the lost time was: host,
harness or device), 130 interrupted; with variants, the most severe.
"""

from __future__ import annotations

import argparse
import json
import sys
import traceback
from pathlib import Path

from harness.commands import examples
from harness.core.interrupts import StopRequest, stop_on_signals
from rig_models.faults import parse_fault
from rig_models.schema import ConfigError


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("run", help="run a test (built-in name or YAML path) and record it",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("run", help="built-in run name (see 'harness cases') or a run file path")
    p.add_argument("--bus", help="INTERFACE:CHANNEL, e.g. virtual:sgsrt (default: virtual:RIG, "
                   "the in-process virtual bus named after the rig), "
                   "socketcan:vcan0 / socketcan:can0 (the lab rig), or socketcand:127.0.0.1:PORT "
                   "(a virtual rig's own process; loopback only, any other host is refused)")
    p.add_argument("--clock", choices=("lockstep", "realtime"), help="override the run's clock")
    p.add_argument("--out", type=Path, default=Path("logs"), help="parent directory of the "
                   "run directory (default: ./logs)")
    p.add_argument("--duration-s", type=float, help="override the run's duration (s)")
    p.add_argument("--rig", metavar="R", help="run on this rig file (built-in name or path) "
                   "instead of the run file's, e.g. sgsrt-canopen (the lab's CANopen devices)")
    p.add_argument("--devices-rig", metavar="R2",
                   help="on the in-process virtual bus, give the virtual rig the devices and "
                   "physics of rig file R2 while the harness reads them through --rig's (a "
                   "rig file checked against the rig it describes, e.g. a mis-bound copy)")
    p.add_argument("--variant", action="append", metavar="NAME",
                   help="run only this variant of a run file with variants (e.g. beta-0.8 of "
                   "case-a); repeatable. Default: every variant in turn")
    p.add_argument("--json", action="store_true", help="print the summary as JSON on stdout")
    p.add_argument("--quiet", action="store_true", help="no progress output")
    p.add_argument("--fault", action="append", metavar="KIND@AT_S[+DURATION_S][:DEVICE][=VALUE]",
                   help="inject a fault in the in-process virtual rig, e.g. "
                   "silent_sensor@5:hub_sensor (repeatable; kinds: 'harness faults')")
    p.add_argument("--dry-run", action="store_true",
                   help="read every sensor, never send a command frame (actuators stay at rest)")
    p.add_argument("--rig-process", action="store_true",
                   help="real-time runs on the virtual bus: the virtual rig's own process "
                   "serves socketcand on 127.0.0.1 (TCP, the lab's kind of transport) instead "
                   "of the default Unix-domain socket (run file realtime.virtual_rig)")
    p.add_argument("--view", nargs="?", const="rerun+http://127.0.0.1:9876/proxy",
                   metavar="URL", help="also stream to a Rerun viewer you started with "
                   "'rerun --bind 127.0.0.1' (default URL rerun+http://127.0.0.1:9876/proxy)")
    p.epilog = examples(
        "harness run slew-rw-zv",
        "harness run case-a --variant beta-0.8 --json",
        "harness run slew-rw --fault silent_sensor@5:hub_sensor",
        "harness run slew-rw --bus socketcan:can0 --rig sgsrt-canopen")
    p.set_defaults(func=cmd_run)


def cmd_run(args: argparse.Namespace) -> int:
    summaries = []
    with stop_on_signals() as stop:
        try:
            return _run_all(args, stop, summaries)
        except KeyboardInterrupt as exc:
            # a signal before the run began (nothing sent), while its limit plan was
            # checked (nothing sent), or a third one while its files were closed (the rig
            # already left safe): one line, exit 130
            from harness.core.limits import PlanInterrupted

            when = ("before the first frame, in the limit plan; nothing sent"
                    if isinstance(exc, PlanInterrupted) else "while closing the run"
                    if stop.begun else "before the run began; nothing sent")
            print(f"harness: {stop.reason or 'interrupted'}: stopped {when}", file=sys.stderr)
            return 130


def _run_all(args: argparse.Namespace, stop: StopRequest, summaries: list) -> int:
    # python-can, numpy, scipy and Rerun only when a run starts (start-up of `harness --help`)
    import can

    from harness.bus import BusSpecError
    from harness.bus.rig_process import RigProcessError
    from harness.core.loop import ControllerError
    from harness.core.runs import load_run
    from harness.core.session import RunRefused, execute_run
    from harness.record.output import OutputError

    codes: list[int] = []
    try:
        if args.duration_s is not None and not args.duration_s > 0:
            raise ConfigError(f"--duration-s {args.duration_s:g}: expected a duration > 0 s")
        overrides = {"duration_s": args.duration_s} if args.duration_s is not None else None
        if args.rig:
            overrides = {**(overrides or {}), "rig": args.rig}
        if args.devices_rig:
            overrides = {**(overrides or {}), "devices_rig": args.devices_rig}
        if args.view:
            check_viewer_listening(check_view_url(args.view))
        base = load_run(args.run, overrides)
        faults = [parse_fault(f) for f in args.fault or []]
        variants = base.data["variants"] or {}
        if not isinstance(variants, dict):
            raise ConfigError(f"{base.source}: variants: expected a mapping NAME: overrides")
        names = args.variant or list(variants) or [None]
        for name in names:
            if name is not None and name not in variants:
                raise ConfigError(f"--variant {name}: {base.source} has variants "
                                  f"{sorted(variants, key=str) or 'none'}")
        runs = []
        for name in names:  # every variant checked (criteria included) before any runs
            run = base
            if name is not None:
                over = dict(variants[name])
                over["name"] = f"{base.name}-{name}"
                over.update(overrides or {})  # --duration-s and --rig win over the variant's
                run = load_run(args.run, over)
            runs.append((name, run))
        for name, run in runs:
            if name is not None:
                print(f"harness: {run.name}", file=sys.stderr)
            try:  # execute_run begins the run (stop.begin) once its plan is checked
                result = execute_run(run, out_dir=args.out, bus=args.bus, clock=args.clock,
                                     live_view_url=args.view, show_progress=not args.quiet,
                                     dry_run=args.dry_run, faults=faults, should_stop=stop,
                                     rig_process=args.rig_process)
            except (ConfigError, BusSpecError, RunRefused, RigProcessError):
                raise
            except Exception as exc:  # the run raised (controller, driver): judged ERROR
                run_dir = getattr(exc, "run_dir", None)
                if isinstance(exc, OutputError):  # the disk, not the run: never judged
                    print(f"harness: the run stopped, the rig left safe: {exc}",
                          file=sys.stderr)
                    codes.append(4)
                    break
                if isinstance(exc, can.CanError):  # the bus failed, not our code: one line
                    rig_log = Path(run_dir) / "rig.log" if run_dir is not None else None
                    seen = f" (the virtual rig's own log: {rig_log})" \
                        if rig_log is not None and rig_log.exists() else ""
                    print(f"harness: the run stopped: the bus failed: {exc}{seen}",
                          file=sys.stderr)
                elif isinstance(exc, ControllerError):  # named, one line; the detail on file
                    kept = _keep_traceback(run_dir, exc)
                    print(f"harness: the run stopped, the rig left safe: {exc}"
                          + (f" (traceback in {kept})" if kept else ""), file=sys.stderr)
                else:
                    traceback.print_exc()
                if run_dir is None:
                    return 4
                codes.append(_judge(run_dir, None))
                stopped = _read_summary(Path(run_dir))
                if stopped is not None:  # --json prints the ERROR run's summary too
                    stopped["run_dir"] = str(run_dir)
                    summaries.append(stopped)
                break
            s = result.summary
            s["run_dir"] = str(result.run_dir)
            summaries.append(s)
            settled = "never within the settle band" if s.get("settle_time_s") is None \
                else f"within the settle band from t = {_g(s['settle_time_s'])} s to the end"
            seq = s.get("sequence") if isinstance(s.get("sequence"), dict) else None
            steps = ""
            if seq is not None:  # a sequence's targets are its steps': their own measures
                settled = ""
                steps = "sequence: " + "; ".join(
                    f"{st.get('name')} {st.get('outcome')}" for st in seq.get("steps") or [])
            print(f"harness: {s['run']} {s['stopped_by']}: final angle error "
                  # settle_time_s is a run time, not the settles criterion's delay after the
                  # profile's end: said so, the two no longer read as one number
                  f"{_g(s['final_angle_error_deg'])} deg, {settled}{steps}, "
                  f"residual tip accel {_g(s['residual_tip_accel_m_s2'])} m/s^2"
                  + (f", steady tip accel amplitude {s['steady_tip_accel_amplitude_m_s2']:.4f}"
                     " m/s^2" if "steady_tip_accel_amplitude_m_s2" in s else "")
                  + f", {s['real_time_factor']}x real time; recording in {result.run_dir}",
                  file=sys.stderr)
            warned = {k: n for k, n in (s.get("monitor_warnings") or {}).items() if n}
            if warned:
                print("harness: monitor warnings: " + ", ".join(
                    f"{k} {n}" for k, n in warned.items()) + " (events under /events/monitor)",
                      file=sys.stderr)
            ctrl = s.get("controller") or {}
            if ctrl.get("over_budget"):
                print(f"harness: controller {ctrl['type']} of {ctrl['distribution']} overran "
                      f"its budget of {ctrl['step_budget_ms']:.3g} ms a tick in "
                      f"{ctrl['ticks_over_budget']} of {s['ticks']} ticks (step() "
                      f"{ctrl['step_mean_ms']:.3g} ms on average, {ctrl['step_max_ms']:.3g} ms "
                      "at most)", file=sys.stderr)
            for f in s.get("faults", []):
                print(f"harness: FAULT {f['device']}: {f['kind']}: {f['message']} at "
                      f"t = {f['time_s']:.3f} s; actuators commanded safe", file=sys.stderr)
            codes.append(_judge(result.run_dir, s))
            if s["stopped_by"] != "completed":
                break
    except (ConfigError, BusSpecError, RunRefused, RigProcessError) as exc:
        print(f"harness: {exc}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(summaries[0] if len(summaries) == 1 else summaries, indent=2))
    return worst_exit(codes)


VIEW_SCHEMES = ("rerun+http", "rerun+https", "rerun")


def check_view_url(url: str) -> str:
    """``url`` if it names a Rerun viewer on this machine's loopback; else ``ConfigError``.
    The URL is parsed, not searched: its host is the one the connection goes to, so a
    query, path or user part naming 127.0.0.1 does not make another host acceptable."""
    import ipaddress
    from urllib.parse import urlsplit

    why = None
    try:
        parts = urlsplit(url)
        host = parts.hostname or ""
        parts.port  # noqa: B018 - raises ValueError on a port out of range
    except ValueError as exc:
        why = f"not a URL ({exc})"
    else:
        if parts.scheme.lower() not in VIEW_SCHEMES:
            why = f"scheme {parts.scheme!r} (expected rerun+http://127.0.0.1:PORT/proxy)"
        elif parts.username is not None or parts.password is not None:
            why = "a user part is not accepted"
        elif host != "localhost":
            try:
                loopback = ipaddress.ip_address(host).is_loopback
            except ValueError:
                loopback = False
            if not loopback:
                why = f"host {host or '(none)'!r} is not this machine's loopback"
    if why is not None:
        raise ConfigError(f"--view {url!r}: {why}; the live view stays on 127.0.0.1 "
                          "(start the viewer with 'rerun --bind 127.0.0.1')")
    return url


def check_viewer_listening(url: str, timeout_s: float = 2.0) -> None:
    """A viewer answers at ``url``'s host and port, or ``ConfigError`` before the run:
    Rerun's gRPC sink to an address where nothing listened held the end of the run."""
    import socket
    from urllib.parse import urlsplit

    parts = urlsplit(url)
    port = parts.port or 9876
    try:
        with socket.create_connection((parts.hostname, port), timeout=timeout_s):
            return
    except OSError as exc:
        raise ConfigError(f"--view {url}: no viewer answers at {parts.hostname}:{port} "
                          f"({exc.strerror or exc}); start one with 'rerun --bind 127.0.0.1' "
                          "or run without --view") from None


EXIT_ORDER = (130, 3, 4, 1, 6, 5, 0)
"""Most severe first: the exit code of several runs (variants) is the most severe one's."""


def worst_exit(codes: list[int]) -> int:
    return min(codes, key=EXIT_ORDER.index, default=0)


def _keep_traceback(run_dir: Path | None, exc: BaseException) -> Path | None:
    """The controller's traceback in the run folder (``traceback.txt``) for its author; the
    terminal gets one line."""
    if run_dir is None:
        return None
    path = Path(run_dir) / "traceback.txt"
    try:
        path.write_text("".join(traceback.format_exception(exc)))
    except OSError:
        return None
    return path


def _read_summary(run_dir: Path) -> dict | None:
    try:
        data = json.loads((run_dir / "summary.json").read_text())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def _judge(run_dir: Path, summary: dict | None) -> int:
    """Judge the finished run (run.rrd and can.blf are closed), write verdict.json and
    verdict.rrd, print the verdict; its exit code."""
    # imported when used: start-up of `harness --help`
    from harness.testing import NO_CRITERIA, JudgeInputError, format_block, judge_run, write_verdict

    try:
        verdict = judge_run(run_dir)
    except (ConfigError, JudgeInputError) as exc:
        print(f"harness: cannot judge {run_dir}: {exc}", file=sys.stderr)
        return 4
    path = write_verdict(verdict, run_dir)
    print(format_block(verdict, path), file=sys.stderr)
    if verdict.verdict == NO_CRITERIA:
        print(f"harness: WARNING: NO CRITERIA: {run_dir.name} ran but nothing was judged (its "
              "run file has no expect:); exit 0 says it completed, not that it passed. Add "
              "criteria (docs/criteria.md)", file=sys.stderr)
    from harness.history.record import record_verdict  # the results database

    record_verdict(run_dir, verdict.to_dict())
    if summary is not None:
        summary["verdict"] = verdict.verdict
    return verdict.exit_code


def _g(x: object) -> str:
    """A summary number for the status line: 4 significant digits, '-' when absent."""
    return "-" if x is None else f"{x:.4g}" if isinstance(x, float) else str(x)
