"""Controller types a run file can name, each with its schema and builder.

A builder gets the validated controller section, the rig and the loop period, and returns an
object with ``reset()`` and ``step(state) -> RigCommand``. Later issues add types here.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, Protocol

from harness.controllers.pd_wheel import PDWheelController
from harness.controllers.slew_profile import CycloidalSlew
from harness.state import RigCommand, RigState
from rig_models.rig_file import RigConfig
from rig_models.schema import Field


class Controller(Protocol):
    def reset(self) -> None: ...

    def step(self, state: RigState) -> RigCommand: ...


class HoldController:
    """Commands nothing (all actuators at rest): free decay, sensor checks."""

    def reset(self) -> None:
        pass

    def step(self, state: RigState) -> RigCommand:
        return RigCommand()


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


CONTROLLERS: dict[str, tuple[dict[str, Any], Callable[[dict[str, Any], RigConfig, float], Any]]] = {
    "pd_wheel": (PD_WHEEL_SCHEMA, build_pd_wheel),
    "hold": ({"type": Field("str", required=True)}, lambda c, rig, dt: HoldController()),
}


class WheelPulse:
    """A rectangular wheel torque pulse, then nothing: excites the beam for a free decay."""

    def __init__(self, torque_n_m: float, start_s: float, width_s: float) -> None:
        self.torque_n_m, self.start_s, self.width_s = torque_n_m, start_s, width_s

    def reset(self) -> None:
        pass

    def step(self, state: RigState) -> RigCommand:
        on = self.start_s <= state.time_s < self.start_s + self.width_s
        return RigCommand(wheel_torque_n_m=self.torque_n_m if on else 0.0)


CONTROLLERS["wheel_pulse"] = (
    {
        "type": Field("str", required=True),
        "torque_n_m": Field("number", "N m", default=0.065),
        "start_s": Field("number", "s", default=0.5, minimum=0.0),
        "width_s": Field("number", "s", default=1.0, exclusive_minimum=0.0),
    },
    lambda c, rig, dt: WheelPulse(c["torque_n_m"], c["start_s"], c["width_s"]),
)


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


CONTROLLERS["square_wave"] = (SQUARE_WAVE_SCHEMA, build_square_wave)


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


CONTROLLERS["wheel_bursts"] = (
    {
        "type": Field("str", required=True),
        "torque_n_m": Field("number", "N m", default=0.06),
        "start_s": Field("number", "s", default=0.5, minimum=0.0),
        "bursts": Field("any", required=True),
    },
    lambda c, rig, dt: WheelBursts(c["torque_n_m"], c["start_s"], _bursts(c)),
)


def _discover() -> None:
    """Modules in harness/controllers/ may add run-file controller types by defining
    ``CONTROLLER_TYPES = {name: (schema, builder)}`` (builder(section, rig, dt_s))."""
    import importlib
    import pkgutil

    import harness.controllers as pkg

    for info in pkgutil.iter_modules(pkg.__path__):
        if info.name == "registry":
            continue
        module = importlib.import_module(f"harness.controllers.{info.name}")
        extra = getattr(module, "CONTROLLER_TYPES", None)
        if extra:
            for name, entry in extra.items():
                if name in CONTROLLERS:
                    raise RuntimeError(f"controller type {name!r} defined twice")
                CONTROLLERS[name] = entry


_discover()
