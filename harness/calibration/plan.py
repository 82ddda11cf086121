"""The excitation plan: free-decay bursts placed at the rig model's predicted modes (pure).

The rig file's model (its hub-free modes and damping) only *places* the excitation; every
value used afterwards comes from the accelerometer. For each predicted mode (omega, zeta):

* a square-wave burst of the actuator at the mode's predicted damped frequency, for
  ``ceil(ln 10 / (2 pi zeta))`` cycles (the resonant response reaches 90 % of its steady
  amplitude; 2 to ``MAX_CYCLES``), then a free-decay gap of ``ln(1/DECAY_TO) / (zeta omega)``
  (the mode decays to 1 %; at least three periods). Bursts go from the fastest mode to the
  slowest; the slowest mode's gap is the final free decay of the record.
* the burst's tip response is predicted on the model (the wheel's torque lag included, the
  accelerometer's first-order bandwidth applied), and the burst is repeated until the
  Cramer-Rao bound of one decay, divided by sqrt(repeats), gives the frequency to
  ``TARGET_REL_SIGMA_OMEGA`` and the damping to ``TARGET_REL_SIGMA_DAMPING`` (at most
  ``MAX_REPEAT`` repeats).

A mode the plan cannot reach is listed with the reason, never silently dropped: above 80 %
of the accelerometer's Nyquist frequency (loop rate / its sync divider), a square wave with
fewer than two ticks per half period, a half period shorter than the valves' minimum
on-time, or a predicted tip response too weak against the accelerometer's noise (below
``MIN_SNR`` x its rms, or needing more than ``MAX_REPEAT`` repeats).

Device limits are checked (:func:`check_plan`): an explicit excitation torque above
``reaction_wheel.max_torque_n_m``, a burst spinning the wheel past
``reaction_wheel.max_speed_rad_s``, a predicted tip acceleration beyond the accelerometer's
range, a valve burst below ``thruster_valves.min_on_time_s``, a bus load above the run's
``max_bus_load_percent``: each is refused with a ``ConfigError`` naming the limit. With no
torque given, the wheel's torque is the largest of ``TORQUE_FRACTION`` x its maximum that
keeps the wheel's speed and the accelerometer's range with 10 % to spare.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from drivers.dbc import load_protocol
from harness.bus.load import compute_bus_load
from harness.identification.cramer_rao import DampedMode, cramer_rao_bound
from rig_models.rig_file import RIGS_DIR, RigConfig, rig_path
from rig_models.schema import ConfigError

ACTUATORS = {"wheel": "reaction_wheel", "valves": "thruster_valves"}
COMMAND_FRAME = {"wheel": "WHEEL_CMD", "valves": "VALVE_CMD"}
TORQUE_FRACTION = 0.9  # of the wheel's max torque, when no torque is given
SPARE = 0.9  # keep the wheel's speed and the accelerometer's range within 90 %
MAX_CYCLES = 20
MIN_CYCLES = 2
DECAY_TO = 0.01  # a gap lets the mode decay to this fraction
MIN_GAP_PERIODS = 3.0
TARGET_REL_SIGMA_OMEGA = 0.002
TARGET_REL_SIGMA_DAMPING = 0.05
MAX_REPEAT = 12
MIN_SNR = 1.5  # predicted amplitude at a window's start / accelerometer noise rms
NYQUIST_FRACTION = 0.8
MIN_HALF_PERIOD_TICKS = 2
SETTLE_S = 0.1  # a free-decay window starts this long after its burst (identify.SETTLE_S)
START_S = 0.5


@dataclass(frozen=True)
class PredictedMode:
    """A hub-free mode of the rig model (1-based ``index``)."""

    index: int
    omega_rad_s: float
    damping_ratio: float

    @property
    def omega_damped_rad_s(self) -> float:
        return self.omega_rad_s * math.sqrt(1.0 - self.damping_ratio**2)

    @property
    def freq_hz(self) -> float:
        return self.omega_rad_s / (2 * math.pi)


@dataclass(frozen=True)
class Burst:
    """One burst (repeated ``repeat`` times, each followed by ``free_decay_s``)."""

    mode: PredictedMode
    omega_rad_s: float
    cycles: int
    free_decay_s: float
    repeat: int
    predicted_amplitude_m_s2: float  # the mode's tip acceleration at its window's start
    predicted_peak_m_s2: float  # largest tip acceleration during the burst
    predicted_rel_sigma_omega: float  # of all repeats together (Cramer-Rao)
    predicted_rel_sigma_damping: float
    wheel_speed_peak_rad_s: float = 0.0

    @property
    def duration_s(self) -> float:
        return self.repeat * (self.cycles * 2 * math.pi / self.omega_rad_s + self.free_decay_s)


@dataclass(frozen=True)
class Unreachable:
    mode: PredictedMode
    reason: str

    def message(self) -> str:
        m = self.mode
        return (f"mode {m.index} (predicted {m.omega_rad_s:.4g} rad/s, {m.freq_hz:.4g} Hz, "
                f"damping {m.damping_ratio:.3g}) cannot be reached: {self.reason}")


@dataclass
class ExcitationPlan:
    rig: RigConfig
    rig_ref: str  # built-in rig name or absolute path, for run files
    actuator: str  # "wheel" | "valves"
    rate_hz: float
    torque_n_m: float  # wheel torque, or the valves' couple
    bursts: list[Burst]
    unreachable: list[Unreachable]
    predicted: list[PredictedMode]
    bus_load_percent: float
    max_bus_load_percent: float
    notes: list[str] = field(default_factory=list)

    @property
    def excitation_end_s(self) -> float:
        return START_S + sum(b.duration_s for b in self.bursts) - self.bursts[-1].free_decay_s

    @property
    def duration_s(self) -> float:
        return round(START_S + sum(b.duration_s for b in self.bursts), 3)

    def controller(self) -> dict[str, Any]:
        bursts = [{"omega_rad_s": round(b.omega_rad_s, 4), "cycles": b.cycles,
                   "free_decay_s": round(b.free_decay_s, 3), "repeat": b.repeat}
                  for b in self.bursts]
        if self.actuator == "wheel":
            return {"type": "wheel_bursts", "torque_n_m": round(self.torque_n_m, 6),
                    "start_s": START_S, "bursts": bursts}
        return {"type": "valve_bursts", "start_s": START_S, "bursts": bursts}

    def run_dict(self, bus: str = "virtual:sgsrt", clock: str = "lockstep") -> dict[str, Any]:
        modes = ", ".join(f"{b.mode.omega_rad_s:.4g}" for b in self.bursts)
        return {
            "name": "calibrate-excite",
            "description": (f"harness calibrate: {self.actuator} bursts at the rig model's "
                            f"predicted modes ({modes} rad/s), each followed by a free decay"),
            "rig": self.rig_ref, "bus": bus, "clock": clock, "rate_hz": self.rate_hz,
            "duration_s": self.duration_s, "max_bus_load_percent": self.max_bus_load_percent,
            "actuators": [ACTUATORS[self.actuator]], "controller": self.controller(),
            "residual_window_s": min(10.0, self.bursts[-1].free_decay_s),
        }

    def describe(self) -> list[str]:
        unit = "N m wheel torque" if self.actuator == "wheel" else "N m valve couple"
        lines = [f"excitation: {self.actuator}, {self.torque_n_m:.4g} {unit}, "
                 f"{self.rate_hz:g} Hz loop, {self.duration_s:.1f} s, bus load "
                 f"{self.bus_load_percent:.1f} % (max {self.max_bus_load_percent:g} %)"]
        for b in self.bursts:
            m = b.mode
            lines.append(
                f"  mode {m.index}: predicted {m.omega_rad_s:.4g} rad/s ({m.freq_hz:.4g} Hz), "
                f"damping {m.damping_ratio:.3g}: {b.repeat} x ({b.cycles} cycles at "
                f"{b.omega_rad_s:.4g} rad/s + {b.free_decay_s:.2f} s free decay); predicted "
                f"tip response {b.predicted_amplitude_m_s2:.3g} m/s^2, frequency to "
                f"{100 * b.predicted_rel_sigma_omega:.2g} %, damping to "
                f"{100 * b.predicted_rel_sigma_damping:.2g} % (1 sigma)")
        lines += [f"  {u.message()}" for u in self.unreachable]
        lines += [f"  note: {n}" for n in self.notes]
        return lines

    def to_dict(self) -> dict[str, Any]:
        return {
            "actuator": self.actuator, "rate_hz": self.rate_hz, "torque_n_m": self.torque_n_m,
            "duration_s": self.duration_s, "bus_load_percent": self.bus_load_percent,
            "bursts": [{"mode": b.mode.index, "predicted_omega_rad_s": b.mode.omega_rad_s,
                        "predicted_damping_ratio": b.mode.damping_ratio,
                        "omega_rad_s": b.omega_rad_s, "cycles": b.cycles,
                        "free_decay_s": b.free_decay_s, "repeat": b.repeat,
                        "predicted_amplitude_m_s2": b.predicted_amplitude_m_s2,
                        "predicted_peak_m_s2": b.predicted_peak_m_s2,
                        "predicted_rel_sigma_omega": b.predicted_rel_sigma_omega,
                        "predicted_rel_sigma_damping": b.predicted_rel_sigma_damping,
                        "wheel_speed_peak_rad_s": b.wheel_speed_peak_rad_s}
                       for b in self.bursts],
            "unreachable": [{"mode": u.mode.index, "omega_rad_s": u.mode.omega_rad_s,
                             "reason": u.reason, "message": u.message()}
                            for u in self.unreachable],
            "notes": list(self.notes),
        }


def rig_reference(rig_arg: str | Path) -> str:
    """How run files name the rig: a built-in name, else the file's absolute path."""
    path = rig_path(rig_arg).resolve()
    if path.parent == RIGS_DIR.resolve():
        return path.stem
    return str(path)


def predicted_modes(rig: RigConfig) -> list[PredictedMode]:
    wn, zeta = rig.plant.hub_free_modal_damping()
    return [PredictedMode(i + 1, float(w), float(z)) for i, (w, z) in enumerate(zip(wn, zeta,
                                                                                    strict=True))]


def _modal_amplitudes(rig: RigConfig, x: np.ndarray) -> np.ndarray:
    """Tip-acceleration amplitude of each oscillatory mode in state ``x`` (ascending)."""
    a = rig.plant.a
    poles, vec = np.linalg.eig(a)
    share = 2 * np.abs((rig.plant.c[2] @ vec) * np.linalg.solve(vec, x))
    osc = np.nonzero(poles.imag > 1e-9)[0]
    return share[osc[np.argsort(np.abs(poles[osc]))]]


def simulate_burst(rig: RigConfig, actuator: str, torque_n_m: float, omega_rad_s: float,
                   cycles: int, dt_s: float) -> tuple[np.ndarray, float]:
    """The model's response to one burst from rest: (each mode's tip amplitude SETTLE_S
    after the burst, peak tip acceleration during it). The wheel's first-order torque lag
    is applied; the valves' equal delays only shift the burst."""
    plant = rig.plant.discretise(dt_s)
    n = int(round(cycles * 2 * math.pi / omega_rad_s / dt_s))
    n_settle = int(round(SETTLE_S / dt_s))
    t = np.arange(n + n_settle) * dt_s
    cmd = np.where(t < n * dt_s, np.where(np.sin(omega_rad_s * t) >= 0, torque_n_m,
                                          -torque_n_m), 0.0)
    if actuator == "wheel":
        lag = rig.section("reaction_wheel")["torque_lag_s"]
        alpha = 1.0 - math.exp(-dt_s / lag) if lag > 0 else 1.0
        applied = np.empty_like(cmd)
        tq = 0.0
        for k, c in enumerate(cmd):
            applied[k] = tq
            tq += alpha * (c - tq)
        cmd = applied
    x = np.zeros(plant.ad.shape[0])
    nu = plant.bd.shape[1]
    peak = 0.0
    for c in cmd:
        u = np.zeros(nu)
        u[0] = c
        peak = max(peak, abs(float(plant.c[2] @ x + plant.d[2] @ u)))
        x = plant.ad @ x + plant.bd @ u
    return _modal_amplitudes(rig, x), peak


def _accel_gain(rig: RigConfig, omega: float) -> float:
    bw = rig.section("accelerometer")["bandwidth_hz"] * 2 * math.pi
    return 1.0 / math.sqrt(1.0 + (omega / bw) ** 2)


def bus_load_percent(rig: RigConfig, actuator: str, rate_hz: float,
                     heartbeat_hz: float = 20.0) -> float:
    return compute_bus_load(load_protocol(), rate_hz, rig.data["bus"]["sync_divider"],
                            [COMMAND_FRAME[actuator]], heartbeat_hz,
                            rig.data["bus"]["bitrate_bit_s"]).percent


def plan_excitation(rig: RigConfig, actuator: str = "wheel", *, rig_ref: str = "sgsrt",
                    rate_hz: float = 500.0, torque_n_m: float | None = None,
                    max_bus_load_percent: float = 70.0) -> ExcitationPlan:
    """The excitation for ``rig``'s predicted modes with ``actuator`` (module docstring).
    Raises ConfigError for an excitation beyond a device limit or when no mode is reachable."""
    if actuator not in ACTUATORS:
        raise ConfigError(f"actuator: expected one of {sorted(ACTUATORS)}, got {actuator!r}")
    if not (math.isfinite(rate_hz) and rate_hz > 0):
        raise ConfigError(f"rate_hz: expected a loop rate > 0 Hz, got {rate_hz!r}")
    dt = 1.0 / rate_hz
    load = bus_load_percent(rig, actuator, rate_hz)
    if load > max_bus_load_percent:
        raise ConfigError(
            f"{rig.source}: bus load {load:.1f} % at rate_hz {rate_hz:g} exceeds "
            f"max_bus_load_percent {max_bus_load_percent:g} % (bus.bitrate_bit_s "
            f"{rig.data['bus']['bitrate_bit_s']}); lower the rate")
    modes = predicted_modes(rig)
    acc = rig.section("accelerometer")
    fs = rate_hz / rig.data["bus"]["sync_divider"]["accelerometer"]
    noise = acc["noise_rms_m_s2"]
    wheel = rig.section("reaction_wheel")
    valves = rig.section("thruster_valves")
    notes: list[str] = []
    if actuator == "wheel":
        t_max = wheel["max_torque_n_m"]
        if torque_n_m is not None and not (math.isfinite(torque_n_m) and torque_n_m > 0):
            raise ConfigError(f"excitation torque: expected > 0 N m, got {torque_n_m!r}")
        if torque_n_m is not None and torque_n_m > t_max:
            raise ConfigError(
                f"excitation torque {torque_n_m:g} N m exceeds the wheel's limit "
                f"reaction_wheel.max_torque_n_m {t_max:g} N m ({rig.source})")
        torque = TORQUE_FRACTION * t_max if torque_n_m is None else torque_n_m
    else:
        if torque_n_m is not None:
            raise ConfigError("excitation torque: the valves are on/off; their level is "
                              f"thruster_valves.couple_n_m {valves['couple_n_m']:g} N m")
        torque = valves["couple_n_m"]

    reachable: list[PredictedMode] = []
    unreachable: list[Unreachable] = []
    for m in modes:
        wd = m.omega_damped_rad_s
        half = math.pi / wd
        nyq = math.pi * fs
        if wd > NYQUIST_FRACTION * nyq:
            unreachable.append(Unreachable(m, (
                f"above {100 * NYQUIST_FRACTION:g} % of the accelerometer's Nyquist frequency "
                f"{nyq / (2 * math.pi):.4g} Hz (loop {rate_hz:g} Hz / accelerometer "
                f"sync_divider {rig.data['bus']['sync_divider']['accelerometer']}): it cannot "
                "be seen")))
        elif half < MIN_HALF_PERIOD_TICKS * dt:
            unreachable.append(Unreachable(m, (
                f"its half period {half * 1e3:.3g} ms is shorter than {MIN_HALF_PERIOD_TICKS} "
                f"ticks of the {rate_hz:g} Hz loop: no square wave at it")))
        elif actuator == "valves" and half < valves["min_on_time_s"]:
            unreachable.append(Unreachable(m, (
                f"its half period {half * 1e3:.3g} ms is shorter than the valves' minimum "
                f"on-time thruster_valves.min_on_time_s {valves['min_on_time_s'] * 1e3:g} ms")))
        else:
            reachable.append(m)
    if actuator == "wheel" and reachable and torque_n_m is None:
        w_min = min(m.omega_damped_rad_s for m in reachable)
        speed_torque = SPARE * wheel["max_speed_rad_s"] * wheel["rotor_inertia_kg_m2"] * \
            w_min / math.pi
        if speed_torque < torque:
            notes.append(f"excitation torque lowered from {torque:.4g} to {speed_torque:.4g} "
                         "N m to keep the wheel within 90 % of reaction_wheel.max_speed_rad_s")
            torque = speed_torque

    bursts: list[Burst] = []
    for attempt in range(2):
        bursts = []
        dropped: list[Unreachable] = []
        for m in sorted(reachable, key=lambda m: -m.omega_rad_s):
            wd = m.omega_damped_rad_s
            z = max(m.damping_ratio, 1e-4)
            cycles = int(min(MAX_CYCLES, max(MIN_CYCLES, math.ceil(math.log(10) /
                                                                    (2 * math.pi * z)))))
            gap = max(math.log(1 / DECAY_TO) / (z * m.omega_rad_s),
                      MIN_GAP_PERIODS * 2 * math.pi / wd)
            amps, peak = simulate_burst(rig, actuator, torque, wd, cycles, dt)
            amp = float(amps[m.index - 1]) * _accel_gain(rig, m.omega_rad_s)
            speed = torque * (math.pi / wd) / wheel["rotor_inertia_kg_m2"] \
                if actuator == "wheel" else 0.0
            if noise > 0:
                if amp < MIN_SNR * noise:
                    lag = (f", torque lag {wheel['torque_lag_s']:g} s" if actuator == "wheel"
                           else "")
                    dropped.append(Unreachable(m, (
                        f"the {actuator}'s burst ({torque:.3g} N m{lag}) gives a predicted tip "
                        f"response of {amp:.2g} m/s^2, below "
                        f"{MIN_SNR:g} x the accelerometer's noise {noise:g} m/s^2 rms")))
                    continue
                n_samp = max(8, int((gap - SETTLE_S) * fs))
                crb = cramer_rao_bound([DampedMode(m.omega_rad_s, m.damping_ratio, amp)],
                                       fs_hz=fs, n_samples=n_samp, noise_rms=noise)
                b = crb.modes[0]
                rel_w = b.sigma_omega_rad_s / m.omega_rad_s
                rel_z = b.sigma_damping / max(m.damping_ratio, 1e-4)
                repeat = max(1, math.ceil(max((rel_w / TARGET_REL_SIGMA_OMEGA) ** 2,
                                              (rel_z / TARGET_REL_SIGMA_DAMPING) ** 2)))
                if repeat > MAX_REPEAT:
                    dropped.append(Unreachable(m, (
                        f"predicted tip response {amp:.2g} m/s^2 against the accelerometer's "
                        f"noise {noise:g} m/s^2 rms: {repeat} repeated decays would be "
                        f"needed for its frequency to {100 * TARGET_REL_SIGMA_OMEGA:g} % and "
                        f"damping to {100 * TARGET_REL_SIGMA_DAMPING:g} % (at most "
                        f"{MAX_REPEAT})")))
                    continue
            else:
                rel_w = rel_z = 0.0
                repeat = 1
            bursts.append(Burst(m, wd, cycles, gap, repeat, amp, peak,
                                rel_w / math.sqrt(repeat), rel_z / math.sqrt(repeat), speed))
        peak_all = max((b.predicted_peak_m_s2 for b in bursts), default=0.0)
        limit = SPARE * rig.accel_range_m_s2
        if peak_all <= limit or attempt == 1:
            break
        if torque_n_m is not None:
            raise ConfigError(
                f"excitation torque {torque:g} N m: predicted tip acceleration "
                f"{peak_all:.3g} m/s^2 exceeds 90 % of the accelerometer's range "
                f"accelerometer.range_g {rig.section('accelerometer')['range_g']:g} g")
        notes.append(f"excitation torque lowered from {torque:.4g} N m to keep the predicted tip "
                     f"acceleration within 90 % of the accelerometer's range")
        torque *= limit / peak_all
    unreachable += dropped
    unreachable.sort(key=lambda u: u.mode.index)
    if not bursts:
        raise ConfigError(f"{rig.source}: no mode of the rig can be excited and seen with the "
                          f"{actuator}: " + "; ".join(u.message() for u in unreachable))
    # the slowest mode's burst goes last: its gap is the record's final free decay
    plan = ExcitationPlan(rig, rig_ref, actuator, rate_hz, torque, bursts, unreachable, modes,
                          load, max_bus_load_percent, notes)
    check_plan(plan)
    return plan


def check_plan(plan: ExcitationPlan) -> None:
    """Refuse a plan beyond a device limit (ConfigError naming the limit)."""
    rig = plan.rig
    dt = 1.0 / plan.rate_hz
    if plan.actuator == "wheel":
        wheel = rig.section("reaction_wheel")
        if plan.torque_n_m > wheel["max_torque_n_m"] * (1 + 1e-9):
            raise ConfigError(f"excitation torque {plan.torque_n_m:g} N m exceeds "
                              f"reaction_wheel.max_torque_n_m {wheel['max_torque_n_m']:g} N m")
        for b in plan.bursts:
            speed = plan.torque_n_m * (math.pi / b.omega_rad_s) / wheel["rotor_inertia_kg_m2"]
            if speed > wheel["max_speed_rad_s"]:
                raise ConfigError(
                    f"burst at {b.omega_rad_s:.4g} rad/s with {plan.torque_n_m:g} N m spins the "
                    f"wheel to {speed:.0f} rad/s, beyond reaction_wheel.max_speed_rad_s "
                    f"{wheel['max_speed_rad_s']:g} rad/s")
    else:
        min_on = rig.section("thruster_valves")["min_on_time_s"]
        for b in plan.bursts:
            if math.pi / b.omega_rad_s < max(min_on, dt):
                raise ConfigError(
                    f"valve burst at {b.omega_rad_s:.4g} rad/s: half period "
                    f"{math.pi / b.omega_rad_s * 1e3:.3g} ms is below "
                    f"thruster_valves.min_on_time_s {min_on * 1e3:g} ms")
    for b in plan.bursts:
        if b.predicted_peak_m_s2 > rig.accel_range_m_s2:
            raise ConfigError(
                f"burst at {b.omega_rad_s:.4g} rad/s: predicted tip acceleration "
                f"{b.predicted_peak_m_s2:.3g} m/s^2 beyond accelerometer.range_g "
                f"{rig.section('accelerometer')['range_g']:g} g")
    if plan.bus_load_percent > plan.max_bus_load_percent:
        raise ConfigError(f"bus load {plan.bus_load_percent:.1f} % exceeds "
                          f"max_bus_load_percent {plan.max_bus_load_percent:g} %")
