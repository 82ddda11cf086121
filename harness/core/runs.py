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

import yaml

from harness.controllers.registry import CONTROLLERS
from harness.core.monitor import LIMITS_SCHEMA, MONITOR_SCHEMA
from rig_models.faults import FaultSpec, make_fault
from rig_models.rig_file import RigConfig, load_rig, rig_from_dict
from rig_models.schema import ConfigError, Field, short_repr, validate
from rig_models.yaml_file import load_yaml

RUNS_DIR = Path(__file__).parent.parent / "runs"
ACTUATORS = ("reaction_wheel", "thruster_valves", "piezo_amplifier", "disturbance_rotor")

RUN_SCHEMA: dict[str, Any] = {
    "name": Field("str", required=True),
    "description": Field("str", default=""),
    "rig": Field("str", default="sgsrt"),
    "rig_overrides": Field("any", default=None),
    "bus": Field("str", default="virtual:sgsrt"),
    "clock": Field("str", default="lockstep", choices=("lockstep", "realtime")),
    "rate_hz": Field("number", "Hz", default=500.0, minimum=1.0, maximum=2000.0),
    # at most 30 days: a duration of 1e308 s overflowed the tick count (a traceback)
    "duration_s": Field("number", "s", required=True, exclusive_minimum=0.0,
                        maximum=30 * 24 * 3600.0),
    "heartbeat_hz": Field("number", "Hz", default=20.0, exclusive_minimum=0.0),
    "max_bus_load_percent": Field("number", "%", default=70.0, exclusive_minimum=0.0,
                                  maximum=100.0),
    "actuators": Field("any", default=["reaction_wheel"]),
    "controller": Field("any", required=True),
    "settle_band_deg": Field("number", "deg", default=0.1, exclusive_minimum=0.0),
    # windows at most 30 days too: 1e308 s overflowed the rows the recorder keeps
    "residual_window_s": Field("number", "s", default=10.0, exclusive_minimum=0.0,
                               maximum=30 * 24 * 3600.0),
    "steady_window_s": Field("number", "s", default=30.0, exclusive_minimum=0.0,
                             maximum=30 * 24 * 3600.0),
    "variants": Field("any", default=None),
    "receive_timeout_ms": Field("number", "ms", default=50.0, exclusive_minimum=0.0),
    "faults": Field("any", default=None),
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
    },
}


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


def list_runs() -> list[tuple[str, str]]:
    out = []
    for path in sorted(RUNS_DIR.glob("*.yaml")):
        raw = yaml.safe_load(path.read_text()) or {}
        out.append((path.stem, str(raw.get("description", ""))))
    return out


def run_path(name_or_path: str) -> Path:
    p = Path(name_or_path)
    if p.suffix in (".yaml", ".yml") or p.exists():
        return p
    return RUNS_DIR / f"{name_or_path}.yaml"


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
    if (not isinstance(ctrl, dict) or not isinstance(ctrl.get("type"), str)
            or ctrl["type"] not in CONTROLLERS):
        raise ConfigError(
            f"{source}: controller.type: expected one of {sorted(CONTROLLERS)}, "
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
    schema, _ = CONTROLLERS[ctrl["type"]]
    data["controller"] = validate(ctrl, schema, source, "controller")
    rig = load_rig(data["rig"])
    if data["rig_overrides"]:
        if not isinstance(data["rig_overrides"], dict):
            raise ConfigError(f"{source}: rig_overrides: expected a mapping")
        rig = rig_from_dict(_deep_merge(rig.data, data["rig_overrides"]),
                            source=f"{rig.source} + rig_overrides of {source}",
                            base_dir=rig.base_dir)
    _check_expect(data, rig, source, base_dir, check_files)
    return RunConfig(source=source, data=data, rig=rig)


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


def build_controller(run: RunConfig) -> Any:
    _, builder = CONTROLLERS[run.controller["type"]]
    try:
        controller = builder(run.controller, run.rig, run.dt_s)
    except ValueError as exc:
        raise ConfigError(f"{run.source}: controller: {exc}") from exc
    except (OverflowError, ZeroDivisionError, FloatingPointError) as exc:
        # a finite but absurd value (bandwidth_rad_s: 1e308) overflows the design's math
        keys = ", ".join(f"{k}: {v!r}" for k, v in run.controller.items()
                         if isinstance(v, int | float) and not isinstance(v, bool)
                         and abs(v) > 1e6)
        raise ConfigError(f"{run.source}: controller: its numbers are out of range ({exc}"
                          f"{'; ' + keys if keys else ''})") from exc
    return controller
