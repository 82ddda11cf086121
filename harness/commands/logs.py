"""`harness logs [--logs DIR] [--last N] [--failed] [--json]`: the recorded runs, how each ended
and its verdict.

One line per run directory under ``--logs`` (default ``./logs``) at any depth (the runs of a
suite, a calibration or a study included, with the folder each belongs to in the ``in``
column), oldest first (directory names start with the UTC time): the rig (its name;
``--json`` adds its hash and each device's binding), the bus and the clock, simulated time,
how it stopped (completed, fault, interrupted, error), a sequence's steps (how many passed,
the first that did not), the first fault, the final angle
error and residual tip acceleration where the run has them, the real-time factor, and the
verdict of its ``verdict.json`` (PASS, MARGINAL,
INCONCLUSIVE, FAIL, ERROR, NO CRITERIA; ``-`` if the run
was never judged: see ``harness judge``). A directory without a readable ``summary.json``
(the harness was killed, or the file was damaged) is listed as such: its ``run.rrd`` and
``can.blf`` hold what was written.

``--failed`` lists only the failures: runs judged FAIL, ERROR or INCONCLUSIVE, and runs
without a
verdict.json that did not complete (a fault, an exception, an interruption, no summary):
judged, each of those would be ERROR. A completed run never judged is not listed.
Exit 0, or 1 if there is no run.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from harness.commands import examples
from harness.record.summary_file import read_summary


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("logs", help="list the recorded runs and how each ended",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--logs", type=Path, default=Path("logs"), help="logs directory (./logs)")
    p.add_argument("--last", type=int, default=0, metavar="N", help="only the newest N runs")
    p.add_argument("--failed", action="store_true", help="only runs judged FAIL, ERROR or "
                   "INCONCLUSIVE, and unjudged runs that did not complete")
    p.add_argument("--json", action="store_true", help="the list as JSON on stdout")
    p.epilog = examples(
        "harness logs --last 10",
        "harness logs --failed --json")
    p.set_defaults(func=cmd_logs)


RUN_FILES = ("config.yaml", "run.rrd", "can.blf")


def run_dirs(logs: Path) -> list[Path]:
    """Every run directory under ``logs`` at any depth (a suite's, a calibration's, a
    study's own logs), oldest first: run folders' names start with their UTC time, so the
    order is by name whatever the nesting. A run directory is not searched further; hidden
    folders (pytest's cache) and symbolic links are not followed."""
    found: list[Path] = []
    stack = [logs]
    while stack:
        here = stack.pop()
        try:
            subs = [p for p in here.iterdir() if p.is_dir() and not p.is_symlink()
                    and not p.name.startswith(".")]
        except OSError:
            continue
        for p in subs:
            if any((p / f).exists() for f in RUN_FILES):
                found.append(p)
            else:
                stack.append(p)
    return sorted(found, key=lambda p: (p.name, str(p)))


def group_of(run_dir: Path, logs: Path) -> str | None:
    """The suite, calibration or study folder a run belongs to: its parent's path under
    ``logs`` (None for a run directly under it)."""
    try:
        rel = run_dir.parent.relative_to(logs)
    except ValueError:
        return None
    return None if str(rel) in ("", ".") else rel.as_posix()


def collect(logs: Path) -> list[dict[str, Any]]:
    rows: list[dict[str, Any]] = []
    if not logs.is_dir():
        return rows
    for run_dir in run_dirs(logs):
        row: dict[str, Any] = {"dir": str(run_dir), "group": group_of(run_dir, logs),
                               **_verdict(run_dir)}
        path = run_dir / "summary.json"
        try:
            s, problems = read_summary(path)
        except FileNotFoundError:
            row["status"] = "no summary.json (killed?)"
            rows.append(row)
            continue
        except (OSError, ValueError) as exc:
            row["status"] = f"unreadable summary.json ({exc})"
            rows.append(row)
            continue
        if not isinstance(s, dict):
            row["status"] = "unreadable summary.json (not a JSON object)"
            rows.append(row)
            continue
        faults = s.get("faults") or []
        row.update({
            "run": s.get("run"), **_rig(run_dir, s), "clock": s.get("clock"),
            "bus": s.get("bus"),
            "simulated_s": s.get("simulated_time_s"), "ticks": s.get("ticks"),
            "status": s.get("stopped_by") or "?", "dry_run": bool(s.get("dry_run")),
            "first_fault": _fault_text(faults[0]) if faults else None,
            "error": s.get("error"),
            "final_angle_error_deg": s.get("final_angle_error_deg"),
            "residual_tip_accel_m_s2": s.get("residual_tip_accel_m_s2"),
            "real_time_factor": s.get("real_time_factor"),
            "steps": _steps(s),
        })
        if problems:  # a hand-edited summary: listed with what is wrong, the others too
            row["status"] = f"{row['status']} ({'; '.join(problems)})"
        rows.append(row)
    return rows


def _rig(run_dir: Path, s: dict[str, Any]) -> dict[str, Any]:
    """The run's rig as its summary names it (``rig_models.rig_file.rig_identity``); a
    summary from before it did: the rig's name from config.yaml, no hash."""
    if isinstance(s.get("rig"), str):
        return {"rig": s["rig"], "rig_sha256": s.get("rig_sha256"),
                "binding": s.get("binding")}
    import yaml

    name = None
    path = run_dir / "config.yaml"
    try:
        if path.stat().st_size <= CONFIG_MAX_BYTES:
            cfg = yaml.safe_load(path.read_text())
            rig = cfg.get("rig") if isinstance(cfg, dict) else None
            name = rig.get("name") if isinstance(rig, dict) else None
    except (OSError, ValueError, yaml.YAMLError):
        name = None
    return {"rig": name if isinstance(name, str) else None, "rig_sha256": None,
            "binding": None}


CONFIG_MAX_BYTES = 4 << 20
"""A config.yaml larger than this is not read for its rig's name (a hand-made file)."""


def _verdict(run_dir: Path) -> dict[str, Any]:
    try:
        v = json.loads((run_dir / "verdict.json").read_text())
    except (OSError, ValueError):
        return {"verdict": None, "verdict_reason": None}
    if not isinstance(v, dict):
        return {"verdict": None, "verdict_reason": None}
    return {"verdict": v.get("verdict"), "verdict_reason": v.get("reason")}


def is_failure(row: dict[str, Any]) -> bool:
    """Judged FAIL, ERROR or INCONCLUSIVE, or not judged and not completed."""
    if row.get("verdict"):
        return row["verdict"] in ("FAIL", "ERROR", "INCONCLUSIVE")
    return row.get("status") != "completed"


def _steps(s: dict[str, Any]) -> list[dict[str, Any]] | None:
    """A sequence's steps (name, outcome, when it ended), None for a run without one."""
    seq = s.get("sequence")
    if not isinstance(seq, dict) or not isinstance(seq.get("steps"), list):
        return None
    return [{"name": st.get("name"), "outcome": st.get("outcome"),
             "ended_s": st.get("ended_s")} for st in seq["steps"] if isinstance(st, dict)]


def steps_text(steps: list[dict[str, Any]] | None) -> str:
    """``3/3 PASS``, or the first step that did not pass: ``1/3 PASS; slew out TIMEOUT``."""
    if not steps:
        return "-"
    passed = sum(st.get("outcome") == "PASS" for st in steps)
    text = f"{passed}/{len(steps)} PASS"
    bad = [st for st in steps if st.get("outcome") not in ("PASS", "SKIPPED")]
    if bad:
        text += f"; {bad[0].get('name')} {bad[0].get('outcome')}"
    return text


def _fault_text(f: Any) -> str:
    if isinstance(f, dict):
        return (f"{f.get('device', '?')}: {f.get('kind', '?')}: {f.get('message', '')} "
                f"(t = {float(f.get('time_s', 0.0)):.3f} s)")
    return str(f)


def _num(v: Any, fmt: str) -> str:
    return "-" if v is None else format(v, fmt)


def cmd_logs(args: argparse.Namespace) -> int:
    if args.last < 0:
        print(f"harness logs: --last: expected N >= 0, got {args.last}", file=sys.stderr)
        return 2
    rows = collect(args.logs)
    if args.last:
        rows = rows[-args.last:]
    if args.failed:
        if not rows:
            print(f"harness logs: no run directories under {args.logs}", file=sys.stderr)
            return 1
        rows = [r for r in rows if is_failure(r)]
        if not rows:
            if args.json:
                print("[]")
            print("harness logs: no failed runs", file=sys.stderr)
            return 0
    if args.json:
        print(json.dumps(rows, indent=2))
    if not rows:
        print(f"harness logs: no run directories under {args.logs}", file=sys.stderr)
        return 1
    if args.json:
        return 0
    w = max(len("run directory"), *(len(Path(r["dir"]).name) for r in rows))
    g = max(len("in"), *(len(r.get("group") or "-") for r in rows))
    rw = max(len("rig"), *(len(str(r.get("rig") or "-")) for r in rows))
    bw = max(len("bus"), *(len(str(r.get("bus") or "-")) for r in rows))
    sw = max(len("steps"), *(len(steps_text(r.get("steps"))) for r in rows))
    print(f"{'run directory':<{w}} {'in':<{g}} {'verdict':<12} {'rig':<{rw}} {'bus':<{bw}} "
          f"{'clock':<9} {'sim s':>7} "
          f"{'status':<12} {'steps':<{sw}} {'final err deg':>13} {'resid m/s^2':>11} "
          f"{'x real':>7}  first fault / error")
    for r in rows:
        name = Path(r["dir"]).name
        group = r.get("group") or "-"
        verdict = r.get("verdict") or "-"
        if "run" not in r:
            print(f"{name:<{w}} {group:<{g}} {verdict:<12} {r['status']}")
            continue
        status = r["status"] + (" (dry)" if r["dry_run"] else "")
        print(f"{name:<{w}} {group:<{g}} {verdict:<12} {str(r['rig'] or '-'):<{rw}} "
              f"{str(r['bus'] or '-'):<{bw}} {str(r['clock'] or '-'):<9} "
              f"{_num(r['simulated_s'], '7.2f')} "
              f"{status:<12} {steps_text(r.get('steps')):<{sw}} "
              f"{_num(r['final_angle_error_deg'], '13.2e')} "
              f"{_num(r['residual_tip_accel_m_s2'], '11.4f')} "
              f"{_num(r['real_time_factor'], '7.1f')}  "
              f"{r['first_fault'] or r['error'] or ''}")
    return 0
