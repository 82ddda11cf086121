"""`harness replay PATH [--rig R] [--rate-hz F] [--check] [--strict] [--rrd OUT.rrd]
[--json]`: replay a CAN log through the harness's own drivers.

PATH is a run directory (its ``can.blf``, rig and rate from its ``config.yaml``) or a CAN log
file python-can reads (``.blf``, ``.asc``, candump ``.log``: e.g. a capture of the real rig),
decoded for the rig ``--rig`` (built-in name or rig file, default ``sgsrt``; it gives the
devices' SYNC dividers and limits) at ``--rate-hz`` (default 500). The log is split into ticks
at each SYNC (0x080); each tick's telemetry goes through the same drivers as in a run, which
rebuild the tick's RigState; the command frames the harness sent are decoded with the DBC.
Printed: frames per id (DBC name, sent by the harness or by the devices), malformed frames,
unknown ids, error frames, SYNC gaps (a tick not the previous plus one), the devices' sequence
errors (a frame counter that did not advance by one) and missing telemetry.

``--check`` (run directories only) rebuilds the run's controller from ``config.yaml`` as
``harness run`` does, steps it on the replayed states and compares its commands, after the
drivers' clamping and encoding, with the logged command frames tick by tick (integer signals
exactly, scaled signals within one quantisation step). The safe commands the harness sends
when a run ends (completed, fault, interrupted) are recognised and not compared; a last tick
whose commands never went out is skipped with the reason. The run's fault monitor is re-run
on the replayed ticks (the same checks on the same driver state) and its first fault, if any,
is compared with summary.json's (tick, device, kind). ``--rrd OUT.rrd`` writes the replayed
telemetry and the logged commands as scalar channels on the ``time`` timeline (tick x dt).

``--strict``: a capture to accept, not just to read: unknown ids, malformed or error frames,
SYNC gaps, missing telemetry or sequence errors are named and exit 1.

Exit status: 0 replayed (and, with --check, every compared tick matches and the monitor
agrees; with --strict, the log is clean), 1 the commands or the monitor's fault differ (or,
with --strict, the log is not clean), 2 bad input (missing or unreadable
file, --check without a run directory).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from harness.commands import examples
from rig_models.schema import ConfigError

if TYPE_CHECKING:
    from harness.core.replay import CheckResult, ReplayRecording
    from rig_models.rig_file import RigConfig


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("replay", help="replay a run's CAN log (or a capture) through the "
                       "drivers; --check its controller's determinism",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("path", type=Path, help="run directory, or a CAN log (.blf, .asc, .log)")
    p.add_argument("--rig", help="rig (built-in name or file) of a bare log (default sgsrt); "
                   "a run directory uses the rig in its config.yaml")
    p.add_argument("--rate-hz", type=float, help="loop rate of a bare log (default 500 Hz); "
                   "a run directory uses its config.yaml")
    p.add_argument("--check", action="store_true", help="rebuild the run's controller and "
                   "compare its commands with the logged ones (run directories only)")
    p.add_argument("--rrd", type=Path, metavar="OUT.rrd",
                   help="write the replayed telemetry and commands to a Rerun recording")
    p.add_argument("--strict", action="store_true", help="exit 1 when the log has unknown "
                   "ids, malformed or error frames, SYNC gaps, missing telemetry or sequence "
                   "errors (a capture to accept, not just to read)")
    p.add_argument("--json", action="store_true", help="JSON on stdout")
    p.epilog = examples(
        "harness replay logs/20260101T120000.000000Z-slew-rw --check",
        "harness replay capture.blf --rig sgsrt --rate-hz 500 --rrd replay.rrd")
    p.set_defaults(func=cmd_replay)


def _stage(text: str) -> None:
    print(f"harness replay: {text} ...", file=sys.stderr, flush=True)


def cmd_replay(args: argparse.Namespace) -> int:
    # python-can, the drivers, the loop and Rerun only when replaying (start-up of
    # `harness --help`)
    from harness.core.replay import (
        MonitorReplay,
        ReplayChecker,
        ReplayError,
        apply_monitor,
        load_run_dir,
        replay_log,
        report_dict,
    )
    from rig_models.rig_file import load_rig

    path: Path = args.path
    result: CheckResult | None = None
    writer: ReplayRecording | None = None
    rig_cfg: RigConfig | None = None
    try:
        if not path.exists():
            raise ReplayError(f"{path}: no such file or directory")
        if path.is_dir():
            run, summary = load_run_dir(path)
            if args.rig or args.rate_hz:
                print("harness replay: --rig/--rate-hz ignored: the run directory's "
                      "config.yaml gives its rig and rate", file=sys.stderr)
            monitor = checker = None
            if args.check:
                monitor = MonitorReplay(run, realtime=summary.get("clock") == "realtime",
                                        dry_run=bool(summary.get("dry_run", False)))
                checker = ReplayChecker(run, dry_run=bool(summary.get("dry_run", False)))
            writer = _writer(args.rrd, path / "can.blf")
            _stage(f"reading and replaying {path / 'can.blf'}"
                   + (", checking the controller" if args.check else ""))
            # one pass, tick by tick: nothing of the capture is kept (bounded memory)
            replay = replay_log(path / "can.blf", run.rig, run.dt_s, keep_ticks=False,
                                on_tick=_each(monitor, checker, writer))
            rig_name, rig_cfg = run.rig.name, run.rig
        else:
            if args.check:
                raise ReplayError(f"{path}: --check needs a run directory (with config.yaml "
                                  "and can.blf), not a log file")
            if args.rate_hz is not None and not args.rate_hz > 0:
                raise ReplayError(f"--rate-hz: expected a number > 0 (Hz), got {args.rate_hz}")
            rig = load_rig(args.rig or "sgsrt")
            checker = None
            writer = _writer(args.rrd, path)
            _stage(f"reading and replaying {path}")
            replay = replay_log(path, rig, 1.0 / (args.rate_hz or 500.0), keep_ticks=False,
                                on_tick=_each(writer))
            rig_name, rig_cfg = rig.name, rig
        if writer is not None:
            writer.close()
            writer = None
        if not replay.n_ticks:
            raise ReplayError(f"{replay.source}: no SYNC frame (0x080): not a log of a "
                              "harness run")
        if checker is not None:
            result = checker.finish()
            result.stopped_by = summary.get("stopped_by")
            result.summary_ticks = summary.get("ticks")
            apply_monitor(result, monitor, summary)
    except (ReplayError, ConfigError, OSError) as exc:
        print(f"harness replay: {exc}", file=sys.stderr)
        return 2
    finally:
        if writer is not None:  # the replay stopped part way: what was written stays
            writer.close()
    report = report_dict(replay, rig_name, result, rig_cfg)
    if args.rrd is not None:
        report["rrd"] = str(args.rrd)
    problems = replay.strict_problems() if args.strict else []
    if args.strict:
        report["strict_problems"] = problems
    if args.json:
        print(json.dumps(report, indent=2))
    else:
        print_report(report)
    if problems:
        print(f"harness replay --strict: {'; '.join(problems)}", file=sys.stderr)
    return 1 if problems or (result is not None and not result.consistent) else 0


def _writer(rrd: Path | None, source: Path) -> ReplayRecording | None:
    """The recording ``--rrd`` asks for; ``ReplayError`` naming it when it cannot be a
    file there (a directory, a folder that does not exist, a file Rerun cannot create)."""
    from harness.core.replay import (  # see cmd_replay
        ReplayError,
        ReplayRecording,
        replay_recording_name,
    )

    if rrd is None:
        return None
    if rrd.is_dir():
        raise ReplayError(f"--rrd {rrd}: a directory; expected a file name such as "
                          f"{rrd / 'replay.rrd'}")
    if not rrd.parent.is_dir():
        raise ReplayError(f"--rrd {rrd}: the folder {rrd.parent} does not exist")
    try:
        return ReplayRecording(rrd, replay_recording_name(source))
    except RuntimeError as exc:  # Rerun's file sink could not create the file
        raise ReplayError(f"--rrd {rrd}: cannot write: {exc}") from None


def _each(*consumers: Any) -> Any:
    """One ``on_tick`` calling every consumer given (None skipped) in order."""
    live = [c for c in consumers if c is not None]
    if not live:
        return None

    def on_tick(iface: Any, t: Any) -> None:
        for consume in live:
            consume(iface, t)
    return on_tick


def print_report(r: dict[str, Any]) -> None:
    print(f"{r['log']}: rig {r['rig']}, {r['rate_hz']:g} Hz, {r['ticks']} ticks "
          f"({r['first_tick']}..{r['last_tick']}, {r['duration_s']:.3f} s), "
          f"{r['total_frames']} frames")
    print(f"{'id':>6}  {'frame':<10} {'from':<8} {'frames':>8}")
    for f in r["frames"]:
        print(f"{f['id']:>6}  {f['name']:<10} {f['from']:<8} {f['frames']:>8}")
    seq = ", ".join(f"{k} {v}" for k, v in r["sequence_errors"].items()) or "0"
    bad = ", ".join(f"{k} {v}" for k, v in r["malformed_by_frame"].items())
    print(f"malformed {r['malformed']}{f' ({bad})' if bad else ''}, unknown ids "
          f"{r['unknown_ids']}, error frames {r['error_frames']}"
          f"{' (bus-off)' if r['bus_off'] else ''}, SYNC gaps {r['sync_gaps']}, sequence "
          f"errors {seq}, missing telemetry {r['missing_telemetry']}, frames before the "
          f"first SYNC {r['before_first_sync']}")
    c = r.get("check")
    if c is None:
        return
    print(f"check: {c['ticks_compared']} ticks compared, {c['ticks_matching']} matching "
          f"({c['ticks_identical']} byte-identical); run {c['stopped_by'] or '?'}, "
          f"{c['summary_ticks'] if c['summary_ticks'] is not None else '?'} ticks in "
          "summary.json; " + ("no safe commands in the log" if c["safe_commands_tick"] is None
                               else f"safe commands in tick {c['safe_commands_tick']}"))
    if c["summary_ticks"] is not None and c["summary_ticks"] != r["ticks"]:
        print(f"check: note: the log has {r['ticks']} ticks, summary.json "
              f"{c['summary_ticks']}: is this log the run's?")
    for s in c["skipped"]:
        print(f"check: tick {s['tick']} not compared: {s['reason']}")
    mon = c["monitor"]
    rep, logd = mon["replayed_first_fault"], mon["logged_first_fault"]

    def fault(f: dict[str, Any] | None) -> str:
        return "none" if f is None else f"{f['device']}: {f['kind']} at tick {f['tick']}"

    print(f"check: fault monitor re-run: {fault(rep)}; summary.json: {fault(logd)}"
          f"{'' if mon['consistent'] else '  <- MISMATCH'}")
    m = c["first_mismatch"]
    if m is None:
        if mon["consistent"]:
            print("check: consistent: the controller gives the logged commands and the "
                  "monitor the logged fault")
        return
    print(f"check: MISMATCH: first at tick {m['tick']} (t = {m['time_s']:.3f} s), "
          f"{m['frame']}: {m['detail']}")
    print(f"  logged:   {m['logged']}")
    print(f"  replayed: {m['replayed']}")
