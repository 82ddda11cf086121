"""Pulse-width pulse-frequency (PWPF) modulator (Hu 2006, section 3; Song et al. 1999).

A first-order pre-filter ``k_m / (tau_m s + 1)`` driven by the error ``e = r - u`` feeds a
Schmitt trigger (on at ``|f| >= U_on``, off when ``|f| < U_off``) whose output ``u`` is
``+-U_m`` or 0. The input ``r`` and output ``u`` are in the same unit (for the thruster loop:
torque demand in N m, thruster torque ``U_m`` in N m), so in its near-linear range the mean
output equals the demand.

``PWPFModulator.step(r, dt)`` returns the output held over the next ``dt`` and then advances the
pre-filter exactly (zero-order hold on ``e``). ``pwpf_static_characteristic`` measures duty cycle
and pulse frequency against a constant input by running the modulator; ``pwpf_static_analytic``
gives the closed-form limit-cycle times for comparison.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class PWPFParameters:
    """Paper defaults (section 6): k_m = 3, tau_m = 0.15 s, U_on = 0.4, U_off = 0.15, U_m = 1."""

    k_m: float = 3.0
    tau_m: float = 0.15
    u_on: float = 0.4
    u_off: float = 0.15
    u_m: float = 1.0

    def __post_init__(self) -> None:
        for name in ("k_m", "tau_m", "u_on", "u_m"):
            value = getattr(self, name)
            if not math.isfinite(value) or value <= 0:
                raise ValueError(f"{name} must be a positive finite number, got {value!r}")
        if not math.isfinite(self.u_off) or not 0 <= self.u_off < self.u_on:
            raise ValueError(
                f"u_off must satisfy 0 <= u_off < u_on ({self.u_on}), got {self.u_off!r}"
            )

    @property
    def dead_zone(self) -> float:
        """Smallest constant input that ever fires: ``U_on / k_m``."""
        return self.u_on / self.k_m

    @property
    def saturation(self) -> float:
        """Constant input above which the output stays on: ``U_m + U_off / k_m``."""
        return self.u_m + self.u_off / self.k_m


class PWPFModulator:
    """PWPF modulator with ``reset()`` and ``step(r, dt) -> u`` (u in {-U_m, 0, +U_m})."""

    def __init__(self, params: PWPFParameters | None = None) -> None:
        self.params = params or PWPFParameters()
        self._decay_dt = -1.0
        self._decay = 0.0
        self.reset()

    def reset(self) -> None:
        self.filter_output = 0.0
        self.state = 0  # -1, 0, +1

    def _trigger(self, f: float) -> int:
        p = self.params
        if self.state > 0 and f < p.u_off:
            self.state = 0
        elif self.state < 0 and f > -p.u_off:
            self.state = 0
        if self.state == 0:
            if f >= p.u_on:
                self.state = 1
            elif f <= -p.u_on:
                self.state = -1
        return self.state

    def step(self, r: float, dt: float) -> float:
        if not dt > 0:
            raise ValueError(f"dt must be positive (s), got {dt!r}")
        if not math.isfinite(r):
            raise ValueError(f"r (modulator input) must be finite, got {r!r}")
        p = self.params
        u = p.u_m * self._trigger(self.filter_output)
        if dt != self._decay_dt:
            self._decay_dt = dt
            self._decay = math.exp(-dt / p.tau_m)
        a = self._decay
        self.filter_output = a * self.filter_output + p.k_m * (1.0 - a) * (r - u)
        return u


@dataclass(frozen=True)
class StaticCharacteristic:
    """Static response to constant inputs: duty cycle (mean |u| / U_m), pulse frequency (Hz)
    and mean output (same unit as the input)."""

    inputs: np.ndarray
    duty_cycle: np.ndarray
    pulse_freq_hz: np.ndarray
    mean_output: np.ndarray


def pwpf_static_characteristic(
    inputs: np.ndarray,
    params: PWPFParameters | None = None,
    dt: float = 1e-4,
    settle_time: float = 2.0,
    measure_time: float = 10.0,
) -> StaticCharacteristic:
    """Run the modulator at each constant input; measure duty cycle and pulse frequency over
    ``measure_time`` after ``settle_time`` (s)."""
    params = params or PWPFParameters()
    inputs = np.atleast_1d(np.asarray(inputs, dtype=float))
    if dt <= 0 or settle_time < 0 or measure_time <= 0:
        raise ValueError("dt and measure_time must be positive, settle_time non-negative")
    n_settle = int(round(settle_time / dt))
    n_meas = int(round(measure_time / dt))
    duty = np.empty(inputs.size)
    freq = np.empty(inputs.size)
    mean = np.empty(inputs.size)
    mod = PWPFModulator(params)
    for k, r in enumerate(inputs):
        mod.reset()
        for _ in range(n_settle):
            mod.step(r, dt)
        on = 0
        pulses = 0
        total = 0.0
        last = mod.state
        for _ in range(n_meas):
            u = mod.step(r, dt)
            s = mod.state
            if s != 0:
                on += 1
                if last == 0:
                    pulses += 1
            last = s
            total += u
        duty[k] = on / n_meas
        freq[k] = pulses / measure_time
        mean[k] = total / n_meas
    return StaticCharacteristic(inputs, duty, freq, mean)


def pwpf_static_analytic(
    inputs: np.ndarray, params: PWPFParameters | None = None
) -> StaticCharacteristic:
    """Closed-form limit cycle of the continuous-time modulator for constant ``r >= 0``::

        T_on  = -tau ln(1 - h / (U_on + k_m (U_m - r)))
        T_off = -tau ln(1 - h / (k_m r - U_off)),   h = U_on - U_off
    """
    p = params or PWPFParameters()
    inputs = np.atleast_1d(np.asarray(inputs, dtype=float))
    if np.any(inputs < 0):
        raise ValueError("inputs must be non-negative (the characteristic is odd)")
    h = p.u_on - p.u_off
    duty = np.zeros(inputs.size)
    freq = np.zeros(inputs.size)
    for k, r in enumerate(inputs):
        if r * p.k_m <= p.u_on:
            continue  # dead zone: the filter never reaches U_on
        if r >= p.saturation:
            duty[k] = 1.0
            continue  # saturated: never switches off
        t_on = -p.tau_m * math.log(1.0 - h / (p.u_on + p.k_m * (p.u_m - r)))
        t_off = -p.tau_m * math.log(1.0 - h / (p.k_m * r - p.u_off))
        duty[k] = t_on / (t_on + t_off)
        freq[k] = 1.0 / (t_on + t_off)
    return StaticCharacteristic(inputs, duty, freq, duty * p.u_m)
