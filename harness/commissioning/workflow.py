"""`harness commission`'s runs, in order (docs/commission.md).

1. Load the rig file (once: every run and check uses it), plan both runs and check the
   moving one against every limit (``harness.core.limits``) before anything is sent.
2. The rest run (sensors only, nothing armed): on CANopen each node's identity, device
   type and scaling objects; each sensor's offset and noise. A scaling object that
   disagrees with the rig file stops here: nothing moves on a conversion known wrong.
3. The moving run (``plan``): the rig's model measured (``model``: friction, lag,
   inertia, couples, the beam's modes, biases), then each quantity against the physics of
   that measured model (``analysis``).
4. commission.json, report.html, commission.rrd (``report``); the verdict: FAIL if any
   check FAILs (a binding), else DIFFERS if the rig differs from its file beyond the
   file's tolerance, else PASS; a run stopped by a fault is ERROR (exit 3). With
   ``--write-rig`` and no FAIL, a rig file with the measured values (``rig_writer``).

Both runs go through ``execute_run`` (the session's loop, monitor, recording and CAN log,
each in its own folder under ``runs/``).
"""

from __future__ import annotations

import datetime as dt
import shutil
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from harness.bus import parse_bus
from harness.commissioning.analysis import moving_checks, rest_checks
from harness.commissioning.checks import Check, attribute_causes
from harness.commissioning.model import MeasuredModel, measure
from harness.commissioning.plan import CommissionPlan, plan_commissioning
from harness.commissioning.scaling import scaling_checks
from harness.core.paths import safe_child, safe_name
from harness.core.runs import RUN_SCHEMA, RunConfig, build_controller, virtual_bus
from harness.core.session import RunRefused, RunResult, execute_run, refuse_beyond_limits
from rig_models.rig_file import RIGS_DIR, RigConfig, load_rig
from rig_models.schema import ConfigError, validate

EXIT = {"PASS": 0, "FAIL": 1, "ERROR": 4, "DIFFERS": 7, "INTERRUPTED": 130}
"""0 PASS, 1 FAIL (a binding), 4 ERROR (a run stopped), 7 DIFFERS (every binding proved,
the rig differs from its file beyond the file's tolerance), 130 INTERRUPTED (Ctrl-C or
SIGTERM: the rig left safe, commission.json says how far it got); 2 bad input is the
command's."""


@dataclass
class Options:
    rig: str = "sgsrt"
    bus: str | None = None
    clock: str | None = None
    out: Path = Path("logs")
    devices_rig: str | None = None
    write_rig: Path | None = None  # where the measured rig file goes (``rig_writer``)
    # the command's stop request (harness.core.interrupts.StopRequest): a first Ctrl-C or
    # SIGTERM stops a run at its next tick, the rig left safe
    should_stop: Callable[[], str | None] | None = None


@dataclass
class Commissioning:
    options: Options
    plan: CommissionPlan
    folder: Path | None = None
    runs: dict[str, str] = field(default_factory=dict)
    checks: list[Check] = field(default_factory=list)
    verdict: str = "PASS"
    notes: list[str] = field(default_factory=list)
    wall_time_s: float = 0.0
    model: MeasuredModel | None = None
    written_rig: Path | None = None

    @property
    def exit_code(self) -> int:
        return EXIT[self.verdict]

    def failed(self) -> list[Check]:
        return [c for c in self.checks if c.verdict == "FAIL"]

    def differs(self) -> list[Check]:
        return [c for c in self.checks if c.verdict == "DIFFERS"]

    def measured(self) -> list[Check]:
        """The rows of the rig-file keys commissioning measured."""
        return [c for c in self.checks if c.key]

    def to_dict(self) -> dict[str, Any]:
        o = self.options
        return {"rig": o.rig, "rig_name": self.plan.rig.name, "bus": o.bus or "virtual:sgsrt",
                "devices_rig": o.devices_rig, "verdict": self.verdict,
                "exit_code": self.exit_code, "bound": list(self.plan.bound),
                "failed": [f"{c.name}: {c.check}: {c.cause}" for c in self.failed()],
                "differs": [f"{c.key}: {c.cause}" for c in self.differs()],
                "measured": {c.key: {"value": c.value, "sigma": c.sigma, "file": c.expected,
                                     "verdict": c.verdict, "unit": c.unit}
                             for c in self.measured() if c.value is not None},
                "written_rig": None if self.written_rig is None else str(self.written_rig),
                "checks": [c.to_dict() for c in self.checks], "runs": self.runs,
                "phases": [{"name": p.name, "start_s": p.start_s, "end_s": p.end_s,
                            "quiet_end_s": p.quiet_end_s} for p in self.plan.phases],
                "notes": self.notes, "wall_time_s": round(self.wall_time_s, 3)}


def _rig_ref(name: str) -> str:
    """A rig's reference the run files take: a built-in name, or an absolute path."""
    p = Path(name)
    if p.suffix in (".yaml", ".yml") or p.exists():
        return str(p.resolve())
    return name if (RIGS_DIR / f"{name}.yaml").exists() else str(p)


def output_folder(out: Path, rig_name: str) -> Path:
    stamp = dt.datetime.now(dt.UTC).strftime("%Y%m%dT%H%M%S.%fZ")
    folder = safe_child(out, f"{stamp}-commission-{safe_name(rig_name)}")
    folder.mkdir(parents=True, exist_ok=False)
    return folder


def _stopped(result: RunResult) -> str | None:
    s = result.summary
    if s["stopped_by"] == "completed":
        return None
    faults = s.get("faults") or []
    if faults:
        f = faults[0]
        return f"{f['device']}: {f['kind']}: {f['message']} at t = {f['time_s']:.3f} s"
    return f"stopped by {s['stopped_by']}: {s.get('error') or 'no reason given'}"


def _run_config(raw: dict[str, Any], source: str, rig: RigConfig) -> RunConfig:
    """A planned run on the rig already loaded: the run schema's and the controller's
    checks of ``harness.core.runs.run_from_dict`` (a planned run has no faults, variants,
    criteria or rig overrides), without reading the rig file again."""
    from harness.controllers.registry import controller_type

    data = validate(raw, RUN_SCHEMA, source)
    ctrl = data["controller"]
    data["controller"] = validate(ctrl, controller_type(ctrl["type"]).schema, source,
                                  "controller")
    if data["bus"] is None:
        data["bus"] = virtual_bus(rig.name)
    return RunConfig(source=source, data=data, rig=rig)


def commission(opts: Options, progress: Callable[[str], None] = lambda m: None
               ) -> Commissioning:
    """Raises ConfigError / RunRefused / BusSpecError (exit 2) before anything is sent."""
    start = time.perf_counter()
    rig = load_rig(opts.rig)  # the one read of the rig file: every run and check uses it
    _ = rig.binding  # a binding that does not build is refused here, naming the key
    if not rig.binding.bound:
        raise ConfigError(f"{rig.source}: every device is bound 'binding: none': nothing on "
                          "the bus to commission (devices: in the rig file)")
    device_rig = load_rig(opts.devices_rig) if opts.devices_rig else None
    if opts.write_rig is not None:
        from harness.commissioning.rig_writer import check_target

        opts.write_rig = check_target(opts.write_rig, rig, opts.rig)
    bus = opts.bus or "virtual:sgsrt"
    spec = parse_bus(bus)
    clock = opts.clock or ("lockstep" if spec.in_process else "realtime")
    if device_rig is not None and not spec.in_process:
        raise ConfigError(f"--devices-rig: the in-process virtual rig emulates another rig "
                          f"file's devices; bus {spec} is not the virtual bus")
    plan = plan_commissioning(rig, _rig_ref(opts.rig))
    rest_run = _run_config(plan.rest_run(bus, clock), "commission rest run", rig)
    moving_run = _run_config(plan.moving_run(bus, clock), "commission moving run", rig)
    refuse_beyond_limits(moving_run, build_controller(moving_run))
    c = Commissioning(opts, plan)
    c.folder = output_folder(opts.out, rig.name)
    try:
        return _runs(c, plan, rest_run, moving_run, device_rig, clock, start, progress)
    except KeyboardInterrupt:
        # a signal before a run began, or a second one while one ran (the run left the rig
        # safe on its way out): what was recorded stays, commission.json says so
        return _interrupted(c, start, "interrupted (Ctrl-C or SIGTERM) between the runs")
    except RunRefused:
        # refused before anything was sent (a CANopen set-up that failed, a bus that does
        # not open): no folder is left, as for a refused run, unless a run was recorded
        if not c.runs:
            shutil.rmtree(c.folder, ignore_errors=True)
        raise


def _interrupted(c: Commissioning, start: float, why: str) -> Commissioning:
    c.verdict = "INTERRUPTED"
    c.notes.append(f"{why}; the rig left safe, nothing judged")
    return _finish(c, start)


def _runs(c: Commissioning, plan: CommissionPlan, rest_run: Any, moving_run: Any,
          device_rig: Any, clock: str, start: float,
          progress: Callable[[str], None]) -> Commissioning:
    opts = c.options
    rig = plan.rig
    assert c.folder is not None
    runs_dir = c.folder / "runs"
    dt_s = rest_run.dt_s

    progress(f"commission 1/2: at rest ({', '.join(plan.bound)}; nothing armed) ...")
    rest = execute_run(rest_run, out_dir=runs_dir, bus=opts.bus, clock=clock,
                       show_progress=False, dry_run=True, device_rig=device_rig,
                       should_stop=opts.should_stop)
    c.runs["rest"] = str(rest.run_dir)
    if rest.summary["stopped_by"] == "interrupted":
        return _interrupted(c, start, "the rest run was interrupted (Ctrl-C or SIGTERM)")
    stop = _stopped(rest)
    if stop is not None:
        c.verdict = "ERROR"
        c.notes.append(f"the rest run stopped: {stop}; nothing was moved")
        return _finish(c, start)
    c.checks += scaling_checks(rig.binding, rest.summary.get("canopen_nodes"))
    if any(x.verdict == "FAIL" for x in c.checks):
        c.notes.append("a device's scaling object disagrees with the rig file: nothing was "
                       "moved (fix the conversion, then commission again)")
        c.checks += rest_checks(plan, rest.columns(), dt_s)
        return _finish(c, start)
    c.checks += rest_checks(plan, rest.columns(), dt_s)

    names = ", ".join(p.name for p in plan.phases)
    progress(f"commission 2/2: moving ({names}; {plan.duration_s:.1f} s of rig time) ...")
    moving = execute_run(moving_run, out_dir=runs_dir, bus=opts.bus, clock=clock,
                         show_progress=False, device_rig=device_rig,
                         should_stop=opts.should_stop)
    c.runs["moving"] = str(moving.run_dir)
    if moving.summary["stopped_by"] == "interrupted":
        return _interrupted(c, start, "the moving run was interrupted (Ctrl-C or SIGTERM)")
    faults = moving.summary.get("faults") or []
    if faults:
        # the monitor stopped the run at a reading beyond a limit or implausible: on a rig
        # being commissioned, most likely a quantity misread; what completed is judged too
        c.checks += [fault_check(f) for f in faults[:1]]
        c.notes.append(f"the monitor stopped the moving run: {_stopped(moving)}; the "
                       "excitations that ended before it are judged, the others not run")
    elif _stopped(moving) is not None:
        c.verdict = "ERROR"
        c.notes.append(f"the moving run stopped: {_stopped(moving)}")
        return _finish(c, start)
    progress("commission: the rig's model measured, each quantity judged against it ...")
    cols = moving.columns()
    c.model = measure(plan, rest.columns(), cols, dt_s)
    c.notes += c.model.notes
    c.checks += moving_checks(plan, cols, dt_s, c.model)
    c.checks += c.model.rows
    return _finish(c, start)


def fault_check(fault: dict[str, Any]) -> Check:
    """The monitor's fault as a failed check of the quantity it names."""
    device, kind = fault["device"], fault["kind"]
    quantity = {"hub_sensor": "rate" if "rate" in kind else "angle",
                "accelerometer": "accel",
                "reaction_wheel": "speed" if "speed" in kind else "torque"}.get(device, kind)
    return Check(device, quantity, "the monitor stopped the moving run", None, None, None, "",
                 None, "FAIL", f"{kind}: {fault['message']} at t = {fault['time_s']:.3f} s: "
                 "a reading beyond its limit or implausible (a misread quantity: its scale, "
                 "unit or object), or the device's own fault",
                 "the monitor's limits and plausibility (docs/faults.md)")


def _finish(c: Commissioning, start: float) -> Commissioning:
    attribute_causes(c.checks)  # a failure that follows from another's says so
    if c.verdict not in ("ERROR", "INTERRUPTED"):
        if c.failed():
            # two answers, never mixed: with a binding failing, what was measured may be
            # its misreading; the model's differences wait for the binding to be fixed
            c.verdict = "FAIL"
            for x in c.differs():
                x.verdict, x.cause = "NOT JUDGED", (
                    "not judged while a binding fails (the measurement may be its "
                    "misreading): fix the binding, then commission again; " + x.cause)
        else:
            c.verdict = "DIFFERS" if c.differs() else "PASS"
    if c.options.write_rig is not None:
        if c.verdict in ("PASS", "DIFFERS") and c.model is not None:
            from harness.commissioning.rig_writer import write_rig

            c.written_rig = write_rig(c.options.write_rig, c)
            c.notes.append(f"the measured rig file: {c.written_rig} (review it, then "
                           f"commission with --rig {c.written_rig})")
        else:
            c.notes.append(f"--write-rig: {c.options.write_rig} not written: the verdict "
                           f"is {c.verdict} (a rig file is written from a commissioning "
                           "whose bindings all passed)")
    c.wall_time_s = time.perf_counter() - start
    from harness.commissioning.report import write_outputs

    write_outputs(c)
    return c
