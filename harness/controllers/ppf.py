"""Positive position feedback (PPF) compensators, one per structural mode (Hu 2006, eqs 5-6).

Each compensator is ``xi'' + 2 zeta_c w_c xi' + w_c^2 xi = w_c^2 k_in y`` driven by the sensor
signal ``y`` (here the sensor patch voltage); its contribution to the actuator command is
``k_out xi``. The bank sums the contributions and clips to the actuator limit. The filters are
advanced with an exact zero-order-hold discretisation, so any fixed step works.

``harness.controllers.oppf`` chooses ``w_c``, ``zeta_c`` and the gains and builds the bank.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.linalg import expm


@dataclass(frozen=True)
class PPFCompensatorParameters:
    """Filter frequency (rad/s), damping ratio, input gain (per sensor unit) and output gain
    (actuator unit per unit of filter coordinate)."""

    freq_rad_s: float
    zeta: float
    input_gain: float = 1.0
    output_gain: float = 1.0

    def __post_init__(self) -> None:
        if not math.isfinite(self.freq_rad_s) or self.freq_rad_s <= 0:
            raise ValueError(f"freq_rad_s must be positive, got {self.freq_rad_s!r}")
        if not math.isfinite(self.zeta) or self.zeta <= 0:
            raise ValueError(f"zeta must be a positive damping ratio, got {self.zeta!r}")
        for name in ("input_gain", "output_gain"):
            if not math.isfinite(getattr(self, name)):
                raise ValueError(f"{name} must be finite")


class PPFCompensator:
    """One second-order PPF filter; ``step(y, dt)`` returns ``k_out xi`` held over ``dt``."""

    def __init__(self, params: PPFCompensatorParameters) -> None:
        self.params = params
        self._dt = -1.0
        self._ad = np.eye(2)
        self._bd = np.zeros(2)
        self.reset()

    def reset(self) -> None:
        self.state = np.zeros(2)  # xi, xi'

    def _discretize(self, dt: float) -> None:
        p = self.params
        w, z = p.freq_rad_s, p.zeta
        m = np.zeros((3, 3))
        m[0, 1] = 1.0
        m[1, 0] = -(w**2)
        m[1, 1] = -2 * z * w
        m[1, 2] = w**2 * p.input_gain
        e = expm(m * dt)
        self._ad = e[:2, :2]
        self._bd = e[:2, 2]
        self._dt = dt

    def step(self, y: float, dt: float) -> float:
        if not dt > 0:
            raise ValueError(f"dt must be positive (s), got {dt!r}")
        if dt != self._dt:
            self._discretize(dt)
        out = self.params.output_gain * float(self.state[0])
        self.state = self._ad @ self.state + self._bd * float(y)
        return out


class PPFController:
    """Bank of PPF compensators on one sensor / one actuator; output clipped to
    ``+-output_limit`` (``None`` for no limit)."""

    def __init__(
        self, compensators: Sequence[PPFCompensatorParameters], output_limit: float | None = None
    ) -> None:
        if len(compensators) == 0:
            raise ValueError("compensators must list at least one PPFCompensatorParameters")
        if output_limit is not None and not output_limit > 0:
            raise ValueError(f"output_limit must be positive or None, got {output_limit!r}")
        self.compensators = [PPFCompensator(p) for p in compensators]
        self.output_limit = output_limit
        self.reset()

    def reset(self) -> None:
        for c in self.compensators:
            c.reset()
        self.saturated_steps = 0

    def step(self, sensor: float, dt: float) -> float:
        u = sum(c.step(sensor, dt) for c in self.compensators)
        if self.output_limit is not None and abs(u) > self.output_limit:
            self.saturated_steps += 1
            u = math.copysign(self.output_limit, u)
        return u
