"""The job behind each suite case, run by an engine worker (this process, a local process
or a Dask worker): run + judge (+ identify), probe, or study, returning plain data.

``run_case(case, out_dir, ship, bus)`` returns::

    {"case": id, "kind": ..., "worker": "host:pid" | "dask:tcp://...", "wall_s": float,
     "run_dir": "<dir name>" | None, "summary": {...} | None,
     "items": {item name: {"verdict", "reason", "criteria", "exit_code", ...}},
     "files": {"<run dir>/<file>": bytes}   # only when ship (no shared file system)}

Nothing is raised for a failing test: an exception becomes an ERROR item with its message.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
import traceback
import uuid
from pathlib import Path
from typing import Any

from harness.core.paths import safe_child
from harness.engine import current_worker, stop_requested
from harness.testing.checks import combine, judge_checks
from harness.testing.outcome import EXIT, item_result, require_criteria
from harness.testing.suite import Case


def _error(message: str, exit_code: int = 4) -> dict[str, Any]:
    return item_result("ERROR", message, exit_code=exit_code)


def _with_checks(base: dict[str, Any], checks: list[dict[str, Any]]) -> dict[str, Any]:
    """A judged result with extra criteria (``check:``) added."""
    if not checks:
        return base
    criteria = [*base.get("criteria", []), *checks]
    verdict, reason = combine(criteria)
    if verdict == base["verdict"]:
        reason = base["reason"] if verdict != "PASS" else reason
    exit_code = base["exit_code"] if verdict == base["verdict"] else EXIT[verdict]
    return {**base, "verdict": verdict, "reason": reason, "criteria": criteria,
            "exit_code": exit_code}


def _judge(run_dir: Path) -> dict[str, Any]:
    """The verdict layer's judgement of the run (writes verdict.json and verdict.rrd)."""
    from harness.testing.judge import judge_run, write_verdict

    v = judge_run(run_dir)
    write_verdict(v, run_dir)
    return {**v.to_dict(), "exit_code": v.exit_code}


def private_channel(rig: str = "sgsrt") -> str:
    """A virtual bus of this job's own, named after its rig (``virtual:job-HEX-sgsrt-dbc2``).
    python-can's virtual channels are per process: a worker running two jobs at once (a Dask
    worker with several threads) must not join them on one channel. (The job's hex never
    ends the name: the BLF writer reads trailing digits as a channel number.)"""
    from harness.core.runs import virtual_bus

    return f"virtual:job-{uuid.uuid4().hex[:12]}-{virtual_bus(rig).partition(':')[2]}"


def _run(case: Case, out_dir: Path, bus: str | None,
         clock: str | None = None) -> tuple[dict[str, Any], Path | None]:
    from harness.bus import BusSpecError, parse_bus
    from harness.bus.rig_process import RigProcessError
    from harness.core.runs import load_run
    from harness.core.session import RunRefused, execute_run
    from rig_models.schema import ConfigError

    items: dict[str, Any] = {}
    try:
        run = load_run(case.run, case.overrides)
        if parse_bus(bus or run.data["bus"]).in_process:
            bus = private_channel(run.rig.name)
            clock = None
        else:  # a rig in its own process, or the real one: its own time, unless the rig is
            clock = clock or "realtime"  # a virtual one in lockstep (--clock lockstep)
        result = execute_run(run, out_dir=out_dir, bus=bus, clock=clock, show_progress=False,
                             should_stop=stop_requested)
    except (ConfigError, BusSpecError, RunRefused, RigProcessError) as exc:
        items[case.id] = _error(f"run refused: {exc}", exit_code=2)
        return items, None
    except Exception as exc:  # the run raised (controller, driver): judged ERROR if it left
        run_dir = getattr(exc, "run_dir", None)  # a run directory, else reported as is
        if run_dir is None:
            raise
        items[case.id] = _judge_or_error(Path(run_dir), f"{type(exc).__name__}: {exc}")
        return items, Path(run_dir)
    run_dir = result.run_dir
    summary = result.summary
    judged = _judge_or_error(run_dir)
    checks = judge_checks(case.checks, summary)
    items[case.id] = _with_checks(judged, checks)
    if case.identify is not None:
        name = f"identify[{case.id}]"
        if summary.get("stopped_by") != "completed":
            items[name] = _error(f"the run did not complete ({summary.get('stopped_by')})")
        else:
            try:
                from harness.core.identify import identify_run  # an identify item only

                ident = identify_run(run_dir, **case.identify)
                (run_dir / "identify.json").write_text(json.dumps(ident, indent=2,
                                                                  default=float))
                crit = judge_checks(case.identify_checks, ident)
                verdict, reason = combine(crit, "identified, no criteria")
                items[name] = item_result(verdict, reason, crit,
                                          modes=_modes_table(ident))
            except Exception as exc:  # noqa: BLE001
                items[name] = _error(f"identify: {type(exc).__name__}: {exc}")
    return items, run_dir


def _judge_or_error(run_dir: Path, raised: str = "") -> dict[str, Any]:
    try:
        judged = _judge(run_dir)
    except Exception as exc:  # noqa: BLE001 - reported as the test's ERROR
        judged = _error(f"judge: {type(exc).__name__}: {exc}")
    if raised and judged["verdict"] != "ERROR":
        judged = {**judged, "verdict": "ERROR", "reason": f"the run raised {raised}",
                  "exit_code": 4}
    return judged


def _modes_table(ident: dict[str, Any]) -> list[dict[str, Any]]:
    keys = ("omega_rad_s", "sigma_omega_rad_s", "damping_ratio", "sigma_damping",
            "model_omega_rad_s", "omega_error_percent", "model_damping_ratio",
            "damping_error_percent")
    return [{k: float(m[k]) for k in keys if k in m} for m in ident.get("modes", [])]


def run_probe(opts: dict[str, Any], bus: str | None, rig: str = "sgsrt",
              clock: str | None = None) -> dict[str, Any]:
    """The pre-flight probe (``harness probe``) as a JSON document; ``clock`` "lockstep" on
    a bus: against a virtual rig in lockstep (``harness virtual-rig --lockstep``)."""
    from harness.bus import open_bus, parse_bus
    from harness.core.probe import probe
    from rig_models.rig_file import load_rig
    from rig_models.virtual_rig import VirtualRig

    rig_cfg = load_rig(opts.get("rig", rig))
    spec = parse_bus(bus or "virtual:sgsrt")
    if spec.in_process:
        spec = parse_bus(private_channel(rig_cfg.name))
    rate = float(opts.get("rate_hz", 100.0))
    buses = [open_bus(spec)]
    try:
        pump = None
        if spec.in_process:
            buses.append(open_bus(spec))
            pump = VirtualRig(rig_cfg, buses[1], 1.0 / rate).service
        res = probe(buses[0], rig_cfg, rate, float(opts.get("duration_s", 2.0)),
                    bus_name=str(spec), pump=pump,
                    realtime=pump is None and clock != "lockstep",
                    settle_s=float(opts.get("settle_s", 0.5)),
                    receive_timeout_s=float(opts.get("receive_timeout_ms", 5.0)) / 1e3)
    finally:
        for b in buses:
            b.shutdown()
    return res.to_dict()


def probe_verdict(report: dict[str, Any]) -> dict[str, Any]:
    bad = [d for d in report["devices"] if not d["ok"]]
    problems = [f"{d['device']}: {d['status']}" for d in bad]
    if report["unknown_ids"]:
        problems.append(f"{report['unknown_ids']} frames with unknown ids")
    if report["error_frames"]:
        problems.append(f"{report['error_frames']} error frames")
    if report["bus_off"]:
        problems.append("bus-off")
    crit = {"name": "every device answers, clean bus", "kind": "probe",
            "value": len(problems), "unit": "problems", "limit": {"max": 0},
            "margin": -len(problems), "worst_time_s": None,
            "verdict": "PASS" if report["ok"] else "FAIL",
            "message": "; ".join(problems) or
            f"{len(report['devices'])} devices answered {report['ticks']} SYNCs"}
    return item_result(crit["verdict"], crit["message"] if problems else
                       f"probe OK on {report['bus']}", [crit])


def _study(case: Case, out_dir: Path) -> dict[str, Any]:
    """The study as a subprocess whose working directory is a folder of its own inside the
    suite's output folder, so whatever it writes (its runs under ./logs) stays there."""
    cmd = [sys.executable, "-m", "harness", "study", case.study, "--json", *case.study_args]
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
    workdir = safe_child(out_dir, f"study-{case.id}")
    workdir.mkdir(parents=True, exist_ok=True)
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=case.timeout_s,
                              env=env, check=False, cwd=workdir)
    except subprocess.TimeoutExpired:
        return _error(f"study {case.study}: no answer within {case.timeout_s:g} s")
    if proc.returncode != 0:
        tail = (proc.stderr.strip().splitlines() or ["(no message)"])[-1]
        return _error(f"harness study {case.study} exited {proc.returncode}: {tail}",
                      exit_code=2 if proc.returncode == 2 else 4)
    try:
        doc = json.loads(proc.stdout)
    except json.JSONDecodeError as exc:
        return _error(f"harness study {case.study} --json: not JSON ({exc})")
    crit = judge_checks(case.checks, doc)
    verdict, reason = combine(crit, "study completed, no criteria")
    return item_result(verdict, reason, crit, document=doc)


def run_case(case: Case, out_dir: str, ship: bool = False,
             bus: str | None = None, clock: str | None = None) -> dict[str, Any]:
    t0 = time.perf_counter()
    out: dict[str, Any] = {"case": case.id, "kind": case.kind, "worker": current_worker(),
                           "run_dir": None, "summary": None, "items": {}, "files": {}}
    tmp = Path(tempfile.mkdtemp(prefix="sgsrt-case-")) if ship else None
    try:
        if case.kind == "run":
            items, run_dir = _run(case, tmp or Path(out_dir), bus, clock)
            out["items"] = items
            if run_dir is not None:
                out["run_dir"] = run_dir.name
                summary_path = run_dir / "summary.json"
                if summary_path.exists():
                    out["summary"] = json.loads(summary_path.read_text())
                if tmp is not None:
                    out["files"] = {f"{run_dir.name}/{p.name}": p.read_bytes()
                                    for p in sorted(run_dir.iterdir()) if p.is_file()}
        elif case.kind == "probe":
            report = run_probe(case.probe, bus, clock=clock)
            res = probe_verdict(report)
            res = _with_checks(res, judge_checks(case.checks, report))
            out["items"] = {case.id: {**res, "document": report}}
        elif case.kind == "study":
            out["items"] = {case.id: _study(case, tmp or Path(out_dir))}
        else:  # pragma: no cover - the suite loader allows no other kind
            raise ValueError(f"unknown case kind {case.kind}")
    except Exception as exc:  # noqa: BLE001 - every failure becomes the test's ERROR
        tb = traceback.format_exc(limit=6)
        out["items"] = {name: _error(f"{type(exc).__name__}: {exc}", exit_code=4)
                        | {"traceback": tb} for name in case.item_names}
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
    out["items"] = require_criteria(out["items"], case.require_criteria)
    out["wall_s"] = round(time.perf_counter() - t0, 3)
    return out
