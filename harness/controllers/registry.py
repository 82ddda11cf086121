"""Controller types a run file can name: the registry, and the harness's simpler types.

A controller type is found by name in the entry point group ``sgsrt_harness.controllers``
(``name = "module:factory"`` in an installed package's pyproject.toml): the harness's own
types are registered there by its pyproject.toml like any plugin's. The factory declares its
run-file schema beside it (``harness.controllers.api.controller_factory``) and is called with
the validated section, the rig and the loop period; it returns an object with ``reset()`` and
``step(state) -> RigCommand`` (docs/controllers.md). Names are read without importing
anything; a type's module is imported when a run names it.

Imports: ``harness.state``, ``harness.controllers.*``, ``rig_models``, the standard library.
"""

from __future__ import annotations

import importlib.metadata
import math
import re
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from harness.controllers.api import (
    TYPE_FIELD,
    Controller,
    ControllerFactory,
    controller_factory,
)
from harness.controllers.pd_wheel import PDWheelController
from harness.controllers.slew_profile import CycloidalSlew
from harness.state import RigCommand, RigState
from rig_models.rig_file import RigConfig
from rig_models.schema import ConfigError, Field

__all__ = ["BUILTIN_ENTRY_POINTS", "ENTRY_POINT_GROUP", "REGISTRY", "Controller",
           "ControllerEntry", "ControllerRegistry", "ControllerType", "Field",
           "controller_names", "controller_type"]

ENTRY_POINT_GROUP = "sgsrt_harness.controllers"
"""The entry point group a package registers its controller types in."""

HARNESS_DISTRIBUTION = "sgsrt-harness"

BUILTIN_ENTRY_POINTS: dict[str, str] = {
    "chirp": "harness.controllers.excitation:build_chirp",
    "commission_script": "harness.controllers.commission_script:build_commission_script",
    "hold": "harness.controllers.registry:build_hold",
    "multisine": "harness.controllers.excitation:build_multisine",
    "pd_wheel": "harness.controllers.registry:build_pd_wheel",
    "shaped_wheel_slew": "harness.controllers.shaped_wheel_slew:build_shaped_wheel_slew",
    "square_wave": "harness.controllers.registry:build_square_wave",
    "thruster_pd_pwpf": "harness.controllers.thruster_slew:build_thruster_slew",
    "thruster_two_level": "harness.controllers.thruster_two_level:build_thruster_two_level",
    "valve_bursts": "harness.controllers.valve_bursts:build_valve_bursts",
    "wheel_bursts": "harness.controllers.registry:build_wheel_bursts",
    "wheel_pulse": "harness.controllers.registry:build_wheel_pulse",
}
"""The harness's own entries in the group, exactly as its pyproject.toml declares them (a test
keeps the two equal). Read from here too, so that a source checkout run without installing
it (or installed before a type was added) still has every built-in type."""


def _canonical(distribution: str) -> str:
    return re.sub(r"[-_.]+", "-", distribution).lower()


@dataclass(frozen=True)
class ControllerEntry:
    """One registered name, not yet imported: ``value`` is ``module:factory``."""

    name: str
    value: str
    distribution: str

    def describe(self) -> str:
        return f"{self.distribution} ({self.name} = {self.value!r})"


@dataclass(frozen=True)
class ControllerType:
    """A loaded controller type: its run-file schema and its factory."""

    name: str
    schema: Mapping[str, Any]
    build: ControllerFactory
    distribution: str = HARNESS_DISTRIBUTION
    entry_point: str = ""

    @property
    def builtin(self) -> bool:
        return _canonical(self.distribution) == HARNESS_DISTRIBUTION

    def describe(self) -> str:
        return f"controller type {self.name!r} of {self.distribution} ({self.entry_point})"


def discover(group: str = ENTRY_POINT_GROUP,
             builtins: Mapping[str, str] = BUILTIN_ENTRY_POINTS) -> dict[str, ControllerEntry]:
    """Every name in ``group`` (the built-ins first), nothing imported. A name two
    distributions declare is a ``ConfigError`` naming both: which one a run meant cannot be
    told. The harness's own installed entries repeat ``builtins`` (its metadata may be older
    than the source it runs: the source's table wins)."""
    found = {name: ControllerEntry(name, value, HARNESS_DISTRIBUTION)
             for name, value in builtins.items()}
    for ep in importlib.metadata.entry_points(group=group):
        dist = ep.dist.name if ep.dist is not None else "an unnamed distribution"
        entry = ControllerEntry(ep.name, ep.value, dist)
        old = found.get(ep.name)
        if old is None:
            found[ep.name] = entry
        elif _canonical(old.distribution) != _canonical(dist):
            raise ConfigError(
                f"controller type {ep.name!r} is declared twice, by {old.describe()} and by "
                f"{entry.describe()}: uninstall one of the two or rename its entry point")
    return found


def load_entry(entry: ControllerEntry) -> ControllerType:
    """Import an entry's factory and check its declared schema; a failure is a one-line
    ``ConfigError`` naming the entry point, never a traceback."""
    where = f"controller plugin {entry.name!r} of {entry.distribution} (entry point " \
            f"{entry.name} = {entry.value!r} in group {ENTRY_POINT_GROUP})"
    try:
        factory = importlib.metadata.EntryPoint(entry.name, entry.value,
                                                ENTRY_POINT_GROUP).load()
    except Exception as exc:  # any error of a plugin's import: its name, not a traceback
        first = (str(exc).splitlines() or [""])[0]
        raise ConfigError(f"{where}: cannot be loaded: {type(exc).__name__}: {first}") \
            from exc
    if not callable(factory):
        raise ConfigError(f"{where}: {entry.value} is not callable (expected a factory "
                          "(section, rig, dt_s) -> controller)")
    schema = getattr(factory, "schema", None)
    if not isinstance(schema, Mapping):
        raise ConfigError(f"{where}: its factory declares no run-file schema (decorate it "
                          "with harness.controllers.api.controller_factory(SCHEMA))")
    problem = _schema_problem(schema, "")
    if problem:
        raise ConfigError(f"{where}: its schema: {problem}")
    if "type" not in schema:
        schema = {"type": TYPE_FIELD, **schema}
    return ControllerType(entry.name, schema, factory, entry.distribution, entry.value)


def _schema_problem(schema: Mapping[str, Any], path: str) -> str | None:
    for key, spec in schema.items():
        here = f"{path}{key}"
        if not isinstance(key, str):
            return f"{here!r}: a key must be a string"
        if isinstance(spec, Mapping):
            problem = _schema_problem(spec, here + ".")
            if problem:
                return problem
        elif not isinstance(spec, Field):
            return f"{here}: expected a rig_models.schema.Field or a mapping of them, " \
                   f"got {type(spec).__name__}"
    if path == "" and "type" in schema and schema["type"] != TYPE_FIELD:
        return "type: must be Field('str', required=True) (the registry's own key)"
    return None


class ControllerRegistry:
    """The controller types of one entry point group: names discovered once, a type
    imported when first asked for. ``add`` registers an in-process type (tests, notebooks)."""

    def __init__(self, group: str = ENTRY_POINT_GROUP,
                 builtins: Mapping[str, str] = BUILTIN_ENTRY_POINTS) -> None:
        self.group = group
        self.builtins = builtins
        self._entries: dict[str, ControllerEntry] | None = None
        self._types: dict[str, ControllerType] = {}

    def entries(self) -> dict[str, ControllerEntry]:
        if self._entries is None:
            self._entries = discover(self.group, self.builtins)
        return self._entries

    def names(self) -> list[str]:
        return sorted(set(self.entries()) | set(self._types))

    def get(self, name: str) -> ControllerType:
        ctype = self._types.get(name)
        if ctype is None:
            entry = self.entries().get(name)
            if entry is None:
                raise ConfigError(f"controller type {name!r}: not registered (known: "
                                  f"{', '.join(self.names())})")
            ctype = self._types[name] = load_entry(entry)
        return ctype

    def add(self, ctype: ControllerType) -> None:
        if ctype.name in self.names():
            raise ConfigError(f"controller type {ctype.name!r} is registered already")
        self._types[ctype.name] = ctype

    def discard(self, name: str) -> None:
        self._types.pop(name, None)

    def refresh(self) -> None:
        """Discover again (after installing or removing a package in this process)."""
        self._entries = None
        self._types.clear()


REGISTRY = ControllerRegistry()


def controller_names() -> list[str]:
    """The names a run file's ``controller.type`` may take (``ConfigError`` on a clash)."""
    return REGISTRY.names()


def controller_type(name: str) -> ControllerType:
    """The registered type ``name``, imported (``ConfigError`` naming a plugin that fails)."""
    return REGISTRY.get(name)


class HoldController:
    """Commands nothing (all actuators at rest): free decay, sensor checks."""

    def reset(self) -> None:
        pass

    def step(self, state: RigState) -> RigCommand:
        return RigCommand()


@controller_factory({})
def build_hold(c: dict[str, Any], rig: RigConfig, dt_s: float) -> HoldController:
    return HoldController()


PD_WHEEL_SCHEMA = {
    "type": Field("str", required=True),
    "angle_deg": Field("number", "deg", required=True),
    "start_s": Field("number", "s", default=1.0, minimum=0.0),
    "slew_duration_s": Field("number", "s", default=0.0, minimum=0.0),
    "torque_fraction": Field("number", default=0.8, exclusive_minimum=0.0, maximum=1.0),
    "bandwidth_rad_s": Field("number", "rad/s", default=0.4, exclusive_minimum=0.0),
    "damping_ratio": Field("number", default=0.9, exclusive_minimum=0.0),
    "feedforward": Field("bool", default=True),
}


@controller_factory(PD_WHEEL_SCHEMA)
def build_pd_wheel(c: dict[str, Any], rig: RigConfig, dt_s: float) -> PDWheelController:
    inertia = rig.plant.inertia_kg_m2
    t_max = rig.section("reaction_wheel")["max_torque_n_m"]
    angle = math.radians(c["angle_deg"])
    if c["slew_duration_s"] > 0:
        profile = CycloidalSlew(angle, c["slew_duration_s"], c["start_s"])
    else:
        profile = CycloidalSlew.shortest(angle, c["torque_fraction"] * t_max / inertia,
                                         c["start_s"])
    return PDWheelController.from_bandwidth(profile, inertia, c["bandwidth_rad_s"],
                                            c["damping_ratio"], t_max, c["feedforward"])


class WheelPulse:
    """A rectangular wheel torque pulse, then nothing: excites the beam for a free decay."""

    def __init__(self, torque_n_m: float, start_s: float, width_s: float) -> None:
        self.torque_n_m, self.start_s, self.width_s = torque_n_m, start_s, width_s

    def reset(self) -> None:
        pass

    def step(self, state: RigState) -> RigCommand:
        on = self.start_s <= state.time_s < self.start_s + self.width_s
        return RigCommand(wheel_torque_n_m=self.torque_n_m if on else 0.0)


@controller_factory({
    "type": Field("str", required=True),
    "torque_n_m": Field("number", "N m", default=0.065),
    "start_s": Field("number", "s", default=0.5, minimum=0.0),
    "width_s": Field("number", "s", default=1.0, exclusive_minimum=0.0),
})
def build_wheel_pulse(c: dict[str, Any], rig: RigConfig, dt_s: float) -> WheelPulse:
    return WheelPulse(c["torque_n_m"], c["start_s"], c["width_s"])


SQUARE_WAVE_SCHEMA = {
    "type": Field("str", required=True),
    "frequency_ratio": Field("number", default=1.0, exclusive_minimum=0.0),
    "beta": Field("number", default=0.8, minimum=0.0),
    "compensate": Field("bool", default=True),
    # lambda = rotor speed / this reference natural frequency, named explicitly
    "reference_frequency": {
        "mode": Field("str", default="constrained", choices=("constrained", "hub_free", "given")),
        "index": Field("int", default=1, minimum=1),
        "omega_rad_s": Field("number", "rad/s", default=0.0, minimum=0.0),
    },
}


def reference_omega(ref: dict[str, Any], rig: RigConfig) -> float:
    """The reference natural frequency a run names (model mode or a given value)."""
    if ref["mode"] == "given":
        if ref["omega_rad_s"] <= 0:
            raise ValueError("reference_frequency.omega_rad_s must be > 0 with mode: given")
        return float(ref["omega_rad_s"])
    freqs = (rig.beam_modes.omega_rad_s if ref["mode"] == "constrained"
             else rig.plant.hub_free_modes()[0])
    if ref["index"] > len(freqs):
        raise ValueError(f"reference_frequency.index {ref['index']} > {len(freqs)} modes")
    return float(freqs[ref["index"] - 1])


@controller_factory(SQUARE_WAVE_SCHEMA)
def build_square_wave(c: dict[str, Any], rig: RigConfig, dt_s: float) -> Any:
    from harness.controllers.square_wave import DisturbanceLaw, SquareWaveCompensator

    dr = rig.section("disturbance_rotor")
    omega_m = c["frequency_ratio"] * reference_omega(c["reference_frequency"], rig)
    if omega_m > dr["max_speed_rad_s"]:
        raise ValueError(f"rotor speed {omega_m:.3f} rad/s exceeds disturbance_rotor."
                         f"max_speed_rad_s {dr['max_speed_rad_s']}")
    law = DisturbanceLaw(dr["mass_kg"], dr["eccentricity_m"], dr["dish_radius_m"])
    return SquareWaveCompensator(c["beta"], law, omega_m, dt_s,
                                 rig.section("reaction_wheel")["max_torque_n_m"],
                                 c["compensate"])


class WheelBursts:
    """Square-wave wheel torque bursts, one after the other (each +-T at a frequency for a
    whole number of cycles, zero mean), then nothing: resonant excitation of chosen modes
    before a free decay. A burst may be followed by ``free_decay_s`` seconds of zero torque
    before the next one, so that a fast-decaying mode rings down on its own before the
    slower modes are excited (``harness identify`` analyses each such gap as its own free
    decay), and repeated (run file ``repeat: N``: N identical bursts, each with its gap).
    ``end_s`` is when the excitation stops; ``free_intervals`` are the gaps (t0, t1, nominal
    omega of the burst before)."""

    def __init__(self, torque_n_m: float, start_s: float,
                 bursts: list[tuple[float, int]] | list[tuple[float, int, float]]) -> None:
        self.torque_n_m = torque_n_m
        self.segments: list[tuple[float, float, float]] = []  # (t0, t1, omega)
        # (t0, t1, nominal omega of the burst before): zero-torque gaps between bursts
        self.free_intervals: list[tuple[float, float, float]] = []
        t = start_s
        for burst in bursts:
            omega, cycles = burst[0], burst[1]
            free_s = float(burst[2]) if len(burst) > 2 else 0.0
            if not omega > 0 or cycles < 1 or not free_s >= 0:
                raise ValueError(f"bursts: omega_rad_s must be > 0, cycles >= 1 and "
                                 f"free_decay_s >= 0, got {omega}, {cycles}, {free_s}")
            dur = cycles * 2 * math.pi / omega
            self.segments.append((t, t + dur, omega))
            t += dur
            if free_s > 0:
                self.free_intervals.append((t, t + free_s, omega))
                t += free_s
        if self.free_intervals and self.free_intervals[-1][1] == t:
            # a gap after the last burst is just part of the final free decay
            t = self.free_intervals.pop()[0]
        self.end_s = t
        self.last_omega_rad_s = self.segments[-1][2]

    def reset(self) -> None:
        pass

    def torque(self, t_s: float) -> float:
        for t0, t1, omega in self.segments:
            if t0 <= t_s < t1:
                return self.torque_n_m if math.sin(omega * (t_s - t0)) >= 0 else -self.torque_n_m
        return 0.0

    def step(self, state: RigState) -> RigCommand:
        return RigCommand(wheel_torque_n_m=self.torque(state.time_s))


def _bursts(c: dict[str, Any]) -> list[tuple[float, int, float]]:
    raw = c["bursts"]
    if not isinstance(raw, list) or not raw:
        raise ValueError("bursts: expected a list of {omega_rad_s, cycles[, free_decay_s, repeat]}")
    out = []
    for i, b in enumerate(raw):
        if (not isinstance(b, dict) or not {"omega_rad_s", "cycles"} <= set(b)
                or not set(b) <= {"omega_rad_s", "cycles", "free_decay_s", "repeat"}):
            raise ValueError(f"bursts[{i}]: expected {{omega_rad_s: rad/s, cycles: int"
                             f"[, free_decay_s: s][, repeat: int]}}")
        repeat = int(b.get("repeat", 1))
        if repeat < 1:
            raise ValueError(f"bursts[{i}]: repeat must be >= 1, got {repeat}")
        burst = (float(b["omega_rad_s"]), int(b["cycles"]), float(b.get("free_decay_s", 0.0)))
        out += [burst] * repeat
    return out


@controller_factory({
    "type": Field("str", required=True),
    "torque_n_m": Field("number", "N m", default=0.06),
    "start_s": Field("number", "s", default=0.5, minimum=0.0),
    "bursts": Field("any", required=True),
})
def build_wheel_bursts(c: dict[str, Any], rig: RigConfig, dt_s: float) -> WheelBursts:
    return WheelBursts(c["torque_n_m"], c["start_s"], _bursts(c))
