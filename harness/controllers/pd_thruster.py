"""PD attitude law for the on-off thruster loop of Hu (2006): torque demand
``tau = k_p (theta_ref - theta) + k_d (rate_ref - rate)`` (N m), fed to a PWPF modulator.

``ThrusterAttitudeController`` chains an optional CSVS shaper (on the reference or on the torque
demand), the PD law and the PWPF modulator: ``step((theta_ref, theta, rate), dt)`` returns the
thruster command in ``{-1, 0, +1}`` (multiples of the modulator's ``U_m``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Literal

from harness.controllers.pwpf import PWPFModulator, PWPFParameters
from harness.shaping.csvs import ComponentSequence, CSVSShaper

CSVSPlacement = Literal["reference", "torque"]


class PDThrusterController:
    """``step((theta_ref, theta, rate[, rate_ref]), dt) -> torque demand`` in N m (SI in)."""

    def __init__(self, kp: float = 15.0, kd: float = 50.0) -> None:
        if not math.isfinite(kp) or kp <= 0:
            raise ValueError(f"kp must be a positive gain (N m/rad), got {kp!r}")
        if not math.isfinite(kd) or kd < 0:
            raise ValueError(f"kd must be a non-negative gain (N m s/rad), got {kd!r}")
        self.kp = float(kp)
        self.kd = float(kd)

    def reset(self) -> None:
        """Stateless; present for the common controller interface."""

    def step(self, measurement: Sequence[float], dt: float) -> float:
        if len(measurement) not in (3, 4):
            raise ValueError(
                "measurement must be (theta_ref, theta, rate[, rate_ref]) in rad, rad/s"
            )
        theta_ref, theta, rate = (float(v) for v in measurement[:3])
        rate_ref = float(measurement[3]) if len(measurement) == 4 else 0.0
        return self.kp * (theta_ref - theta) + self.kd * (rate_ref - rate)


class ThrusterAttitudeController:
    """CSVS (optional) -> PD -> PWPF. Output: thruster command in {-1, 0, +1}."""

    def __init__(
        self,
        pd: PDThrusterController | None = None,
        pwpf: PWPFParameters | None = None,
        csvs: ComponentSequence | None = None,
        csvs_placement: CSVSPlacement = "reference",
        initial_reference: float = 0.0,
    ) -> None:
        if csvs_placement not in ("reference", "torque"):
            raise ValueError(
                f"csvs_placement must be 'reference' or 'torque', got {csvs_placement!r}"
            )
        self.pd = pd or PDThrusterController()
        self.modulator = PWPFModulator(pwpf)
        self.placement = csvs_placement
        initial = initial_reference if csvs_placement == "reference" else 0.0
        self.shaper = CSVSShaper(csvs, initial_value=initial) if csvs is not None else None
        self.reset()

    def reset(self) -> None:
        self.pd.reset()
        self.modulator.reset()
        if self.shaper is not None:
            self.shaper.reset()
        self.last_reference = math.nan
        self.last_demand = 0.0

    def step(self, measurement: Sequence[float], dt: float) -> float:
        theta_ref, theta, rate = (float(v) for v in measurement[:3])
        if self.shaper is not None and self.placement == "reference":
            theta_ref = self.shaper.step(theta_ref, dt)
        demand = self.pd.step((theta_ref, theta, rate), dt)
        if self.shaper is not None and self.placement == "torque":
            demand = self.shaper.step(demand, dt)
        self.last_reference = theta_ref
        self.last_demand = demand
        u = self.modulator.step(demand, dt)
        return u / self.modulator.params.u_m
