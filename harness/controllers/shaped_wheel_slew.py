"""Open-loop reaction-wheel slews, unshaped (bang-bang) or input-shaped (ZV, ZVD, EI).

The unshaped command is a rest-to-rest bang-bang at the wheel torque T: +T for tau, -T for
tau, with tau a whole number of ticks and T lowered (never raised) so that the rigid body
turns exactly ``angle_deg``: T = theta J / tau^2. It switches hard, so it excites the beam.

A shaped slew convolves the *same* command with a multi-mode shaper (one ZV, ZVD or EI per
mode, convolved; ``harness.shaping.impulse_shapers``) designed for the modes the run file
gives (identified from a free decay: undamped natural frequency and damping ratio), each
frequency multiplied by ``mode_scale`` (1.1: the design believes the modes 10 % stiffer than
they are). The shaper's amplitudes are positive and sum to one, so the shaped torque never
exceeds T and the rigid body still turns exactly ``angle_deg``; impulse times are put on the
tick grid by splitting each impulse between its two neighbouring ticks (amplitude and time
centroid kept).

The whole torque history is computed when the controller is built and indexed by tick
(deterministic, no state). The manoeuvre ends at ``end_s``: the end of the last tick with a
non-zero command. ``reference(t)`` is the rigid-body motion the command produces (the loop
records it as the attitude reference).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from harness.shaping.impulse_shapers import ImpulseSequence, ShapedCommand, ei, multi_mode, zv, zvd
from harness.shaping.robust import mode_band, si_for_band
from harness.state import RigCommand, RigState
from rig_models.rig_file import RigConfig
from rig_models.schema import Field

SHAPERS = ("none", "zv", "zvd", "ei", "si")


@dataclass(frozen=True)
class Mode:
    """A vibration mode: undamped natural frequency (rad/s) and damping ratio, and
    optionally their 1-sigma uncertainties (from the identification; used by the ``si``
    shaper's band)."""

    omega_rad_s: float
    damping_ratio: float = 0.0
    sigma_omega_rad_s: float = 0.0
    sigma_damping: float = 0.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.omega_rad_s) and self.omega_rad_s > 0):
            raise ValueError(f"omega_rad_s: expected a frequency > 0 rad/s, got "
                             f"{self.omega_rad_s!r}")
        if not (math.isfinite(self.damping_ratio) and 0 <= self.damping_ratio < 1):
            raise ValueError(f"damping_ratio: expected a value in [0, 1), got "
                             f"{self.damping_ratio!r}")

        for name in ("sigma_omega_rad_s", "sigma_damping"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"{name}: expected a value >= 0, got {v!r}")

    def scaled(self, factor: float) -> Mode:
        return Mode(self.omega_rad_s * factor, self.damping_ratio,
                    self.sigma_omega_rad_s * factor, self.sigma_damping)


def parse_modes(raw: Any, name: str = "modes") -> tuple[Mode, ...]:
    """Modes from a run file: a list of {omega_rad_s: rad/s, damping_ratio: -} (optionally
    with ``sigma_omega_rad_s`` and ``sigma_damping``, the identification's 1-sigma)."""
    if not isinstance(raw, list) or not raw:
        raise ValueError(f"{name}: expected a non-empty list of {{omega_rad_s, damping_ratio}}")
    out = []
    keys = {"omega_rad_s", "damping_ratio", "sigma_omega_rad_s", "sigma_damping"}
    for i, m in enumerate(raw):
        if not isinstance(m, dict) or not set(m) <= keys or "omega_rad_s" not in m:
            raise ValueError(f"{name}[{i}]: expected {{omega_rad_s: rad/s, damping_ratio: -"
                             f"[, sigma_omega_rad_s: rad/s, sigma_damping: -]}}, got {m!r}")
        try:
            out.append(Mode(float(m["omega_rad_s"]), float(m.get("damping_ratio", 0.0)),
                            float(m.get("sigma_omega_rad_s", 0.0)),
                            float(m.get("sigma_damping", 0.0))))
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{name}[{i}]: {exc}") from exc
    return tuple(out)


def design_shaper(kind: str, modes: Sequence[Mode], mode_scale: float = 1.0,
                  ei_tolerance: float = 0.05, si_tolerance: float = 0.05,
                  band_sigmas: float = 3.0, band_min_rel: float = 0.05) -> ImpulseSequence:
    """Multi-mode shaper: one ``kind`` shaper per mode (frequencies x ``mode_scale``),
    convolved. ``kind`` 'none' gives the identity (one unit impulse at 0). ``si``: a
    specified-insensitivity shaper per mode keeping the residual below ``si_tolerance`` over
    the mode's band, +-max(``band_sigmas`` sigma, ``band_min_rel``) in frequency and
    +-``band_sigmas`` sigma in damping (``harness.shaping.robust``)."""
    if kind not in SHAPERS:
        raise ValueError(f"shaper: expected one of {SHAPERS}, got {kind!r}")
    if not (math.isfinite(mode_scale) and mode_scale > 0):
        raise ValueError(f"mode_scale: expected a factor > 0, got {mode_scale!r}")
    if kind == "none":
        return ImpulseSequence(np.array([0.0]), np.array([1.0]))
    if not modes:
        raise ValueError(f"modes: shaper {kind} needs at least one mode")
    if kind == "si":
        return multi_mode([si_for_band(mode_band(
            m.omega_rad_s * mode_scale, m.damping_ratio, m.sigma_omega_rad_s * mode_scale,
            m.sigma_damping, band_sigmas, band_min_rel), si_tolerance) for m in modes])
    single = {"zv": zv, "zvd": zvd,
              "ei": lambda w, z: ei(w, z, ei_tolerance)}[kind]
    return multi_mode([single(m.omega_rad_s * mode_scale, m.damping_ratio) for m in modes])


def bang_bang_ticks(angle_rad: float, inertia_kg_m2: float, max_torque_n_m: float,
                    dt_s: float) -> tuple[int, float]:
    """(ticks per half, signed torque) of the shortest tick-aligned bang-bang turning the
    rigid body by ``angle_rad`` with |torque| <= ``max_torque_n_m``."""
    if not (math.isfinite(angle_rad) and angle_rad != 0):
        raise ValueError(f"angle_deg: expected a non-zero angle, got {math.degrees(angle_rad)}")
    if not max_torque_n_m > 0:
        raise ValueError(f"torque_n_m: expected a torque > 0 N m, got {max_torque_n_m}")
    tau = math.sqrt(abs(angle_rad) * inertia_kg_m2 / max_torque_n_m)
    n = max(1, math.ceil(tau / dt_s - 1e-9))
    torque = abs(angle_rad) * inertia_kg_m2 / (n * dt_s) ** 2
    return n, math.copysign(torque, angle_rad)


def rigid_reference(torque_by_tick: np.ndarray, inertia_kg_m2: float,
                    dt_s: float) -> np.ndarray:
    """Rigid-body (angle, rate, acceleration) at every tick, shape (n + 1, 3), for the torque
    commanded at tick k acting over (t_k, t_k+1] (exact for a held torque)."""
    acc = np.asarray(torque_by_tick, dtype=float) / inertia_kg_m2
    rate = np.concatenate([[0.0], np.cumsum(acc) * dt_s])
    angle = np.concatenate([[0.0], np.cumsum(rate[:-1] * dt_s + acc * dt_s**2 / 2)])
    return np.column_stack([angle, rate, np.concatenate([acc, [0.0]])])


class TickSchedule:
    """A precomputed command history indexed by tick, with its rigid-body reference."""

    def __init__(self, values: np.ndarray, start_tick: int, dt_s: float,
                 inertia_kg_m2: float, torque_scale_n_m: float) -> None:
        self.values = np.asarray(values)
        self.start_tick = int(start_tick)
        self.dt_s = dt_s
        nz = np.nonzero(self.values)[0]
        # the command of the last non-zero tick acts until the next tick
        self.end_tick = self.start_tick + (int(nz[-1]) + 1 if len(nz) else 0)
        self._ref = rigid_reference(self.values * torque_scale_n_m, inertia_kg_m2, dt_s)
        # the same rows as Python floats: ``reference`` is called every tick
        self._ref_rows: list[tuple[float, float, float]] = [
            (a, r, acc) for a, r, acc in self._ref.tolist()]

    @property
    def start_s(self) -> float:
        return self.start_tick * self.dt_s

    @property
    def end_s(self) -> float:
        """End of the manoeuvre: every actuator command is zero from then on."""
        return self.end_tick * self.dt_s

    def at_tick(self, tick: int) -> Any:
        k = tick - self.start_tick
        return self.values[k] if 0 <= k < len(self.values) else 0

    def reference(self, t_s: float) -> tuple[float, float, float]:
        k = int(round(t_s / self.dt_s)) - self.start_tick
        k = min(max(k, 0), len(self._ref_rows) - 1)
        return self._ref_rows[k]


class ScheduledSlew:
    """What an open-loop slew driven by a ``TickSchedule`` (``self.schedule``) exposes to the
    harness: its end, duration and rigid-body reference."""

    schedule: TickSchedule

    @property
    def end_s(self) -> float:
        return self.schedule.end_s

    @property
    def duration_s(self) -> float:
        return self.schedule.end_s - self.schedule.start_s

    def reset(self) -> None:
        pass

    def reference(self, t_s: float) -> tuple[float, float, float]:
        return self.schedule.reference(t_s)


class ShapedWheelSlew(ScheduledSlew):
    """Open-loop wheel slew: the (shaped) bang-bang torque of every tick, precomputed."""

    def __init__(self, angle_rad: float, inertia_kg_m2: float, torque_n_m: float,
                 start_s: float, dt_s: float, shaper: ImpulseSequence,
                 shaper_name: str = "none") -> None:
        if not start_s >= 0:
            raise ValueError(f"start_s: expected a time >= 0 s, got {start_s}")
        self.n_half, self.torque_n_m = bang_bang_ticks(angle_rad, inertia_kg_m2, torque_n_m,
                                                       dt_s)
        self.angle_rad = angle_rad
        self.shaper = shaper
        self.shaper_name = shaper_name
        raw = np.r_[np.ones(self.n_half), -np.ones(self.n_half)]
        shaping = ShapedCommand(shaper, dt_s, rounding="split")
        tail = np.zeros(int(shaping.delay_ticks[-1]) + 1)
        shaped = shaping.process(np.r_[raw, tail])
        shaped[np.abs(shaped) < 1e-12] = 0.0
        self.applied_shaper = shaping.quantized_sequence
        self.schedule = TickSchedule(shaped * self.torque_n_m, round(start_s / dt_s), dt_s,
                                     inertia_kg_m2, 1.0)

    def step(self, state: RigState) -> RigCommand:
        return RigCommand(wheel_torque_n_m=float(self.schedule.at_tick(state.tick)))


SHAPED_WHEEL_SLEW_SCHEMA = {
    "type": Field("str", required=True),
    "angle_deg": Field("number", "deg", required=True),
    "start_s": Field("number", "s", default=1.0, minimum=0.0),
    "torque_n_m": Field("number", "N m", default=0.06, exclusive_minimum=0.0),
    "shaper": Field("str", default="none", choices=SHAPERS),
    "modes": Field("any", default=None),
    "mode_scale": Field("number", default=1.0, exclusive_minimum=0.0),
    "ei_tolerance_percent": Field("number", "%", default=5.0, exclusive_minimum=0.0,
                                  maximum=50.0),
    # shaper si: residual below si_tolerance_percent over each mode's band, +-max(band_sigmas
    # x its sigma_omega_rad_s, band_min_percent) in frequency, +-band_sigmas x sigma_damping
    "si_tolerance_percent": Field("number", "%", default=5.0, exclusive_minimum=0.0,
                                  maximum=50.0),
    "band_sigmas": Field("number", default=3.0, minimum=0.0),
    "band_min_percent": Field("number", "%", default=5.0, minimum=0.0, maximum=50.0),
}


def build_shaped_wheel_slew(c: dict[str, Any], rig: RigConfig, dt_s: float) -> ShapedWheelSlew:
    t_max = rig.section("reaction_wheel")["max_torque_n_m"]
    if c["torque_n_m"] > t_max:
        raise ValueError(f"torque_n_m {c['torque_n_m']} exceeds the wheel's limit "
                         f"reaction_wheel.max_torque_n_m {t_max} N m")
    modes: tuple[Mode, ...] = ()
    if c["shaper"] != "none" or c["modes"] is not None:
        modes = parse_modes(c["modes"])
    shaper = design_shaper(c["shaper"], modes, c["mode_scale"],
                           c["ei_tolerance_percent"] / 100.0, c["si_tolerance_percent"] / 100.0,
                           c["band_sigmas"], c["band_min_percent"] / 100.0)
    return ShapedWheelSlew(math.radians(c["angle_deg"]), rig.plant.inertia_kg_m2,
                           c["torque_n_m"], c["start_s"], dt_s, shaper, c["shaper"])


CONTROLLER_TYPES = {"shaped_wheel_slew": (SHAPED_WHEEL_SLEW_SCHEMA, build_shaped_wheel_slew)}
