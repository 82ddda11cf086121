"""Run files: YAML descriptions of one test on the rig.

Built-in runs live in `harness/runs/`; `harness cases` lists them. Every run file is checked
against RUN_SCHEMA (and its controller section against the controller type's schema) before
anything is sent on the bus.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from harness.controllers.registry import controller_names, controller_type
from harness.core.builtin_runs import RUNS_DIR as RUNS_DIR  # where the built-in runs are
from harness.core.builtin_runs import list_runs, run_path
from harness.core.monitor import LIMITS_SCHEMA, MONITOR_SCHEMA
from rig_models.faults import FaultSpec, make_fault
from rig_models.rig_file import RigConfig, load_rig, rig_from_dict
from rig_models.schema import ConfigError, Field, short_repr, validate
from rig_models.yaml_file import load_yaml

ACTUATORS = ("reaction_wheel", "thruster_valves", "piezo_amplifier", "disturbance_rotor")

RUN_SCHEMA: dict[str, Any] = {
    "name": Field("str", required=True),
    "description": Field("str", default=""),
    "rig": Field("str", default="sgsrt"),
    "rig_overrides": Field("any", default=None),
    # on the in-process virtual bus: the rig file whose devices and physics the virtual rig
    # has, where the run's own rig file is the one under test (a lab's file against the rig
    # it describes); empty: the run's own
    "devices_rig": Field("str", default=""),
    # default: the in-process virtual bus named after the rig (``virtual:sgsrt-canopen``)
    "bus": Field("str", default=None),
    "clock": Field("str", default="lockstep", choices=("lockstep", "realtime")),
    "rate_hz": Field("number", "Hz", default=500.0, minimum=1.0, maximum=2000.0),
    # who sends SYNC in real time: the loop ("loop"), or the kernel's broadcast manager
    # ("kernel", SocketCAN only; each tick starts when its SYNC is read back)
    "sync_source": Field("str", default="loop", choices=("loop", "kernel")),
    # at most 30 days: a duration of 1e308 s overflowed the tick count (a traceback)
    "duration_s": Field("number", "s", required=True, exclusive_minimum=0.0,
                        maximum=30 * 24 * 3600.0),
    "heartbeat_hz": Field("number", "Hz", default=20.0, exclusive_minimum=0.0),
    "max_bus_load_percent": Field("number", "%", default=70.0, exclusive_minimum=0.0,
                                  maximum=100.0),
    "actuators": Field("any", default=["reaction_wheel"]),
    "controller": Field("any", required=True),
    # the controller's step() time per tick; default STEP_BUDGET_FRACTION of the period
    "controller_budget_ms": Field("number", "ms", default=None, exclusive_minimum=0.0),
    "settle_band_deg": Field("number", "deg", default=0.1, exclusive_minimum=0.0),
    # windows at most 30 days too: 1e308 s overflowed the rows the recorder keeps
    "residual_window_s": Field("number", "s", default=10.0, exclusive_minimum=0.0,
                               maximum=30 * 24 * 3600.0),
    "steady_window_s": Field("number", "s", default=30.0, exclusive_minimum=0.0,
                             maximum=30 * 24 * 3600.0),
    "variants": Field("any", default=None),
    "receive_timeout_ms": Field("number", "ms", default=50.0, exclusive_minimum=0.0),
    "faults": Field("any", default=None),
    # a test that reacts: steps evaluated in the tick (harness.sequences, docs/sequences.md)
    "sequence": Field("any", default=None),
    # values a sequence names as ${name}; a suite's matrix sweeps them (variables.NAME)
    "variables": Field("any", default=None),
    "expect": Field("any", default=None),
    "monitor": MONITOR_SCHEMA,
    "limits": LIMITS_SCHEMA,
    # real-time measures, requested by default on the real-time clock (docs/realtime.md);
    # a refused one is a warning recorded in the summary. Set a key false to opt out.
    "realtime": {
        "sched_fifo": Field("bool", default=True),
        "priority": Field("int", default=50, minimum=1, maximum=98),
        "pin_cpu": Field("bool", default=True),
        "cpu": Field("int", default=-1, minimum=-1),
        "lock_memory": Field("bool", default=True),
        "gc_freeze": Field("bool", default=True),
        # the virtual rig in a real-time run on the virtual bus: "auto" (the measured best,
        # REALTIME_RIG_DEFAULT), "thread" (in the harness's process), "process-unix" (its
        # own process over a Unix-domain socket), "process-tcp" (own process, socketcand)
        "virtual_rig": Field("str", default="auto",
                             choices=("auto", "thread", "process-unix", "process-tcp")),
        "rig_priority": Field("int", default=49, minimum=0, maximum=98),
        "rig_cpu": Field("int", default=-1, minimum=-1),
        # the bench's health: limits of the timing criteria every real-time run is judged by
        # (harness.testing.bench; beyond one the run is INCONCLUSIVE). Defaults: the line
        # 'harness rt-check' draws for a host that cannot hold its rate (docs/criteria.md)
        "max_overruns_percent": Field("number", "% of ticks", default=1.0, minimum=0.0,
                                      maximum=100.0),
        "max_lateness_p99_period_percent": Field("number", "% of the period", default=50.0,
                                                 minimum=0.0),
        "max_missing_held_percent": Field("number", "% of the telemetry frames due",
                                          default=1.0, minimum=0.0, maximum=100.0),
    },
}


STEP_BUDGET_FRACTION = 0.1
"""A controller's default time per tick, as a fraction of the loop period (0.2 ms at
500 Hz): the loop keeps ``harness.core.loop.RESERVE_FRACTION`` (0.3) of the period after the
telemetry for the controller, the commands and the recording."""

OVER_BUDGET_TICKS_FRACTION = 0.01
"""A controller is named as over its budget when more than this fraction of its ticks took
longer: a step now and then is stretched by the host (the process preempted in the call),
a slow controller is slow in every tick of a phase."""


@dataclass(frozen=True)
class RunConfig:
    source: str
    data: dict[str, Any]
    rig: RigConfig

    @property
    def name(self) -> str:
        return self.data["name"]

    @property
    def dt_s(self) -> float:
        return 1.0 / self.data["rate_hz"]

    @property
    def n_ticks(self) -> int:
        return int(round(self.data["duration_s"] * self.data["rate_hz"])) + 1

    @property
    def controller(self) -> dict[str, Any]:
        return self.data["controller"]

    @property
    def step_budget_s(self) -> float:
        """The controller's time per tick (s): the run file's or the default."""
        budget_ms = self.data.get("controller_budget_ms")
        return budget_ms / 1e3 if budget_ms is not None else STEP_BUDGET_FRACTION * self.dt_s

    @property
    def faults(self) -> list[FaultSpec]:
        raw = self.data["faults"] or []
        if not isinstance(raw, list):
            raise ConfigError(f"{self.source}: faults: expected a list")
        return [make_fault(f, f"{self.source}: faults[{i}]") for i, f in enumerate(raw)]

    @property
    def actuators(self) -> tuple[str, ...]:
        return tuple(self.data["actuators"])

    def resolved(self) -> dict[str, Any]:
        """Everything the run used, rig included (written beside the recording)."""
        return {"run": self.data, "rig": self.rig.data, "run_source": self.source,
                "rig_source": self.rig.source}


def _deep_merge(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    out = copy.deepcopy(base)
    for k, v in over.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = _deep_merge(out[k], v)
        else:
            out[k] = v
    return out


def load_run(name_or_path: str, overrides: dict[str, Any] | None = None) -> RunConfig:
    path = run_path(name_or_path)
    if not path.exists():
        names = ", ".join(n for n, _ in list_runs())
        raise ConfigError(f"run {name_or_path}: not found (built-in runs: {names})")
    raw = load_yaml(path, "run file")
    if overrides:
        raw = _deep_merge(raw or {}, overrides)
    return run_from_dict(raw, source=f"run file {path.name}", base_dir=path.parent)


def run_from_dict(raw: Any, source: str = "run", base_dir: Path | None = None,
                  check_files: bool = True) -> RunConfig:
    """A checked RunConfig. ``base_dir``: where relative paths in the run (an ``expect:``
    baseline) start (default: the working directory); ``check_files=False`` does not
    require a baseline to exist (re-reading a run directory's config.yaml)."""
    data = validate(raw, RUN_SCHEMA, source)
    actuators = data["actuators"]
    if not isinstance(actuators, list) or not all(a in ACTUATORS for a in actuators):
        raise ConfigError(
            f"{source}: actuators: expected a list from {list(ACTUATORS)}, got {actuators!r}")
    ctrl = data["controller"]
    names = controller_names()  # the registered types (built-in and installed plugins)
    if (not isinstance(ctrl, dict) or not isinstance(ctrl.get("type"), str)
            or ctrl["type"] not in names):
        raise ConfigError(
            f"{source}: controller.type: expected one of {names}, "
            f"got {ctrl.get('type') if isinstance(ctrl, dict) else ctrl!r}")
    if data["faults"] is not None and not isinstance(data["faults"], list):
        raise ConfigError(f"{source}: faults: expected a list of {{kind, at_s, ...}}")
    for i, f in enumerate(data["faults"] or []):
        make_fault(f, f"{source}: faults[{i}]")
    variants = data["variants"]
    if variants is not None:
        if not isinstance(variants, dict):
            raise ConfigError(f"{source}: variants: expected a mapping NAME: {{key: value, "
                              f"...}}, got {short_repr(variants)}")
        for vname, over in variants.items():
            if not isinstance(over, dict):
                raise ConfigError(f"{source}: variants.{vname}: expected a mapping of the "
                                  f"run's keys to override, got {short_repr(over)}")
    data["controller"] = validate(ctrl, controller_type(ctrl["type"]).schema, source,
                                  "controller")
    rig = load_rig(data["rig"])
    if data["variables"] is not None and not data["sequence"]:
        raise ConfigError(f"{source}: variables: only a sequence reads them (${{name}}); "
                          "this run has no sequence")
    if data["rig_overrides"]:
        if not isinstance(data["rig_overrides"], dict):
            raise ConfigError(f"{source}: rig_overrides: expected a mapping")
        rig = rig_from_dict(_deep_merge(rig.data, data["rig_overrides"]),
                            source=f"{rig.source} + rig_overrides of {source}",
                            base_dir=rig.base_dir)
    _check_timing(data, rig, source)
    if data["sequence"] is not None:
        sequence_spec(data, rig, source)
    _check_expect(data, rig, source, base_dir, check_files)
    if data["bus"] is None:
        data["bus"] = virtual_bus(rig.name)
    return RunConfig(source=source, data=data, rig=rig)


RECEIVE_TIMEOUT_MAX_S = 1.0
"""The longest a tick waits for telemetry (``receive_timeout_ms``): a bus that answers
later than this has stopped, and a tick that waited longer would be deaf to Ctrl-C and to
the devices' watchdogs (the default watchdog trips after 0.25 s)."""


def _check_timing(data: dict[str, Any], rig: RigConfig, source: str) -> None:
    """Every wait bounded, every heartbeat in time: ``receive_timeout_ms`` at most
    ``RECEIVE_TIMEOUT_MAX_S``; the heartbeat's period shorter than the devices' watchdog
    (``watchdog.heartbeat_timeout_s``) and a CANopen node's consumer time, or the devices
    go safe between two heartbeats and the drive is blamed for it."""
    timeout_ms = data["receive_timeout_ms"]
    if timeout_ms > RECEIVE_TIMEOUT_MAX_S * 1e3:
        raise ConfigError(f"{source}: receive_timeout_ms: {timeout_ms:g} ms: at most "
                          f"{RECEIVE_TIMEOUT_MAX_S * 1e3:g} ms (a tick never waits longer "
                          "for its telemetry)")
    period_s = 1.0 / data["heartbeat_hz"]
    limits = [(float(rig.data["watchdog"]["heartbeat_timeout_s"]),
               f"{rig.source}'s watchdog.heartbeat_timeout_s")]
    if rig.binding.canopen is not None:
        limits.append((rig.data["bus"]["heartbeat_consumer_ms"] / 1e3,
                       f"{rig.source}'s bus.heartbeat_consumer_ms"))
    for limit_s, where in limits:
        if not period_s < limit_s:
            raise ConfigError(
                f"{source}: heartbeat_hz: {data['heartbeat_hz']:g} Hz is a heartbeat every "
                f"{period_s * 1e3:.0f} ms, not within {where} of {limit_s * 1e3:.0f} ms: "
                "the devices would go safe between two heartbeats; raise heartbeat_hz above "
                f"{1.0 / limit_s:g} Hz")


def virtual_bus(rig_name: str) -> str:
    """The in-process virtual bus of a rig, named after it (``virtual:sgsrt-canopen``): a
    run on it says which rig answered."""
    name = "".join(ch if ch.isalnum() or ch in "-_." else "-" for ch in str(rig_name))
    return f"virtual:{name.strip('-') or 'rig'}"


def _check_expect(data: dict[str, Any], rig: RigConfig, source: str, base_dir: Path | None,
                  check_files: bool) -> None:
    """Refuse bad criteria (``expect:``, and the rig's ``expect_overrides``) before anything
    is sent; relative baselines are made absolute so config.yaml can be judged anywhere."""
    if data["expect"] is None and not rig.data.get("expect_overrides"):
        return
    # the verdict layer sits above the run files: imported here, not at module level
    from harness.testing.criteria import apply_overrides, parse_criteria, resolve_baselines
    data["expect"] = resolve_baselines(data["expect"], base_dir or Path.cwd())
    expect = apply_overrides(data["expect"], rig.data.get("expect_overrides"), rig.source)
    parse_criteria(expect, source, check_files=check_files)


def rig_devices(rig: RigConfig) -> frozenset[str]:
    """The devices the rig file binds (telemetry or commands)."""
    return frozenset(rig.binding.bound)


def sequence_spec(data: dict[str, Any], rig: RigConfig, source: str) -> Any:
    """The run's checked ``sequence:`` (``harness.sequences.spec.SequenceSpec``)."""
    from harness.sequences.quantities import quantities_for
    from harness.sequences.spec import parse_sequence

    def can_inject(fault: FaultSpec, where: str) -> None:
        from rig_models.virtual_rig import check_fault_insertion

        try:
            check_fault_insertion(rig, [fault])
        except ConfigError as exc:
            raise ConfigError(f"{where}: {exc}") from None

    spec = parse_sequence(data["sequence"], data["variables"], source,
                          tuple(data["actuators"]), quantities_for(rig_devices(rig)),
                          can_inject)
    for step in spec.all_steps:  # a step's own controller: its type and keys, now
        if step.controller is not None:
            step_controller_section(step.controller, f"{step.where}.controller")
    return spec


def build_controller(run: RunConfig) -> Any:
    """The run's controller; with a ``sequence:``, wrapped by the sequence's runner
    (``harness.sequences.runner.SequenceRunner``), which the loop then calls."""
    controller = _build_controller(run)
    if run.data.get("sequence") is None:
        return controller
    from harness.sequences.quantities import quantities_for
    from harness.sequences.runner import SequenceRunner

    spec = sequence_spec(run.data, run.rig, run.source)
    if not callable(getattr(controller, "retarget", None)):
        for step in spec.all_steps:
            for a, where in [(step.actions, step.where)] + [(w.actions, f"{w.where}.do")
                                                           for w in step.when]:
                if a.slew_rad is not None or a.hold:
                    key = "slew" if a.slew_rad is not None else "hold"
                    raise ConfigError(
                        f"{where}.{key}: the run's controller ({run.controller['type']}) "
                        "cannot retarget (it has no retarget(angle_rad, t_s)); pd_wheel can")
    import math

    own = {}
    for step in spec.all_steps:
        if step.controller is not None:
            where = f"{step.where}.controller"
            section = step_controller_section(step.controller, where)
            own[step.index] = build_section(section, run, where.split(": ", 1)[-1])
    return SequenceRunner(spec, controller, quantities_for(rig_devices(run.rig)),
                          math.radians(run.data["settle_band_deg"]), run.dt_s, own)


def step_controller_section(raw: dict[str, Any], where: str) -> dict[str, Any]:
    """A sequence step's ``controller:`` section checked against its type's schema."""
    names = controller_names()
    if raw.get("type") not in names:
        raise ConfigError(f"{where}.type: expected one of {names}, got {raw.get('type')!r}")
    source, _, path = where.partition(": ")
    return validate(raw, controller_type(raw["type"]).schema, source, path)


def _build_controller(run: RunConfig) -> Any:
    return build_section(run.controller, run, "controller")


def build_section(section: dict[str, Any], run: RunConfig, where: str) -> Any:
    """A controller from a validated ``controller:`` section (the run's, or a sequence
    step's), named ``where`` in the errors: its factory's failures are one-line
    ``ConfigError``s before anything is sent."""
    ctype = controller_type(section["type"])
    try:
        controller = ctype.build(section, run.rig, run.dt_s)
    except ValueError as exc:
        raise ConfigError(f"{run.source}: {where}: {exc}") from exc
    except (OverflowError, ZeroDivisionError, FloatingPointError) as exc:
        # a finite but absurd value (bandwidth_rad_s: 1e308) overflows the design's math
        keys = ", ".join(f"{k}: {v!r}" for k, v in section.items()
                         if isinstance(v, int | float) and not isinstance(v, bool)
                         and abs(v) > 1e6)
        raise ConfigError(f"{run.source}: {where}: its numbers are out of range ({exc}"
                          f"{'; ' + keys if keys else ''})") from exc
    except KeyboardInterrupt:
        raise  # Ctrl-C before the run began (harness.core.interrupts): nothing sent
    except BaseException as exc:  # SystemExit too: a plugin's exit is no run
        if ctype.builtin and isinstance(exc, Exception):
            raise
        # a plugin's own failure: named, one line, before anything is sent
        raise ConfigError(f"{run.source}: {where}: {ctype.describe()} failed to build: "
                          f"{type(exc).__name__}: {exc}") from exc
    if not callable(getattr(controller, "step", None)):
        raise ConfigError(f"{run.source}: {where}: {ctype.describe()} returned "
                          f"{type(controller).__name__}, which has no step(state) method")
    return controller


def controller_summary(run: RunConfig, stats: Any) -> dict[str, Any]:
    """summary.json's ``controller``: which type ran (its distribution and entry point) and
    its step() time per tick against its budget (``stats``: the loop's ``LoopStats``)."""
    ctype = controller_type(run.controller["type"])
    ticks = stats.ticks
    over = stats.steps_over_budget
    return {
        "type": ctype.name,
        "distribution": ctype.distribution,
        "entry_point": ctype.entry_point,
        "step_budget_ms": run.step_budget_s * 1e3,
        "step_mean_ms": stats.step_total_s / ticks * 1e3 if ticks else 0.0,
        "step_max_ms": stats.step_max_s * 1e3,
        "ticks_over_budget": over,
        "over_budget": over > OVER_BUDGET_TICKS_FRACTION * ticks,
    }
