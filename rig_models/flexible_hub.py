"""Linear hub + flexible-beam plant (SGSRT paper 003, eq. 4) and its exact ZOH discretisation.

Generalised coordinates q = [theta, eta_1..eta_n]; state x = [q, q'].

    M q'' + C q' + K q = B u,   M = [[J, delta], [delta^T, I]],
    K = diag(0, omega_i^2),     C = diag(0, 2 zeta_i omega_i),

with u = [hub torque] (every external torque on the hub: wheel reaction, thrusters,
disturbance rotor) plus, optionally, modal forces (piezo patches). J is the whole system's
inertia about the axis with the beam undeformed (the paper's J), so J >= the beam's own
rigid inertia.

Outputs: hub angle, hub rate, and the tip's absolute transverse acceleration
a_tip = (R + L) theta'' + phi(L)^T eta'' (which depends on the input through q'').
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from functools import cached_property

import numpy as np
import scipy.linalg as sla

from rig_models.beam import BeamModes


@dataclass(frozen=True)
class HubBeamModel:
    """Continuous-time matrices of the hub-beam plant."""

    inertia_kg_m2: float
    modes: BeamModes
    damping_ratio: np.ndarray
    tip_radius_m: float
    mass: np.ndarray
    stiffness: np.ndarray
    damping: np.ndarray
    a: np.ndarray
    b: np.ndarray
    c: np.ndarray  # rows: angle, rate, tip acceleration
    d: np.ndarray

    @property
    def n_modes(self) -> int:
        return len(self.modes.omega_rad_s)

    @property
    def n_states(self) -> int:
        return self.a.shape[0]

    def hub_free_modes(self) -> tuple[np.ndarray, np.ndarray]:
        """Natural frequencies (rad/s) and mode shapes of the unconstrained (hub-free) system,
        without the rigid-body mode."""
        w2, vec = sla.eigh(self.stiffness, self.mass)
        order = np.argsort(w2)
        w2, vec = w2[order][1:], vec[:, order][:, 1:]
        return np.sqrt(np.clip(w2, 0.0, None)), vec

    def hub_free_modal_damping(self) -> tuple[np.ndarray, np.ndarray]:
        """Natural frequency (rad/s) and damping ratio of each oscillatory pole of the damped
        hub-free system (from the eigenvalues of A), in ascending frequency."""
        poles = np.linalg.eigvals(self.a)
        osc = poles[poles.imag > 1e-9]
        wn = np.abs(osc)
        order = np.argsort(wn)
        return wn[order], (-osc.real / np.abs(osc))[order]

    def discretise(self, dt_s: float) -> DiscreteHubBeam:
        return DiscreteHubBeam.from_continuous(self, dt_s)


def build_hub_beam(
    inertia_kg_m2: float,
    modes: BeamModes,
    damping_ratio: float | np.ndarray,
    tip_radius_m: float,
    frequency_factors: Sequence[float] | np.ndarray | None = None,
) -> HubBeamModel:
    """Assemble the hub-beam model from the beam's constrained modes. ``frequency_factors``:
    each constrained mode's frequency times its factor, mode by mode (its modal stiffness
    times factor^2; shapes and coupling kept; missing entries 1): a beam measured off its
    model. The model's ``modes`` then carry the scaled frequencies."""
    n = len(modes.omega_rad_s)
    if frequency_factors is not None and len(frequency_factors):
        factors = np.ones(n)
        given = np.asarray(frequency_factors, dtype=float)[:n]
        if np.any(~np.isfinite(given)) or np.any(given <= 0):
            raise ValueError(f"beam frequency factors must be > 0, got {given}")
        factors[:len(given)] = given
        modes = replace(modes, omega_rad_s=modes.omega_rad_s * factors)
    if inertia_kg_m2 <= modes.rigid_inertia_kg_m2:
        raise ValueError(
            f"hub.inertia_kg_m2 = {inertia_kg_m2} must exceed the beam's own rigid inertia "
            f"{modes.rigid_inertia_kg_m2:.3f} kg m^2 (it is the whole system's inertia)"
        )
    zeta = np.broadcast_to(np.asarray(damping_ratio, dtype=float), (n,)).copy()
    if np.any(zeta < 0) or np.any(zeta >= 1):
        raise ValueError(f"beam damping ratio must be in [0, 1), got {zeta}")
    delta = modes.coupling_kg_m
    mass = np.eye(n + 1)
    mass[0, 0] = inertia_kg_m2
    mass[0, 1:] = delta
    mass[1:, 0] = delta
    stiffness = np.diag(np.r_[0.0, modes.omega_rad_s**2])
    damping = np.diag(np.r_[0.0, 2.0 * zeta * modes.omega_rad_s])
    m_inv = np.linalg.inv(mass)
    nq = n + 1
    # inputs: hub torque, then one generalised force per mode (piezo moments etc.)
    b_q = np.eye(nq)
    a = np.zeros((2 * nq, 2 * nq))
    a[:nq, nq:] = np.eye(nq)
    a[nq:, :nq] = -m_inv @ stiffness
    a[nq:, nq:] = -m_inv @ damping
    b = np.zeros((2 * nq, nq))
    b[nq:, :] = m_inv @ b_q
    accel_row = np.r_[tip_radius_m, modes.tip_deflection]  # a_tip = accel_row . q''
    c = np.zeros((3, 2 * nq))
    c[0, 0] = 1.0
    c[1, nq] = 1.0
    c[2, :] = accel_row @ a[nq:, :]
    d = np.zeros((3, nq))
    d[2, :] = accel_row @ b[nq:, :]
    return HubBeamModel(
        inertia_kg_m2=inertia_kg_m2,
        modes=modes,
        damping_ratio=zeta,
        tip_radius_m=tip_radius_m,
        mass=mass,
        stiffness=stiffness,
        damping=damping,
        a=a,
        b=b,
        c=c,
        d=d,
    )


@dataclass(frozen=True)
class DiscreteHubBeam:
    """x[k+1] = Ad x[k] + Bd u[k] (exact for u held constant over the step); y = C x + D u."""

    dt_s: float
    ad: np.ndarray
    bd: np.ndarray
    c: np.ndarray
    d: np.ndarray

    @classmethod
    def from_continuous(cls, model: HubBeamModel, dt_s: float) -> DiscreteHubBeam:
        if not dt_s > 0:
            raise ValueError(f"dt_s must be > 0, got {dt_s}")
        n, m = model.b.shape
        block = np.zeros((n + m, n + m))
        block[:n, :n] = model.a
        block[:n, n:] = model.b
        phi = sla.expm(block * dt_s)
        return cls(dt_s=dt_s, ad=phi[:n, :n], bd=phi[:n, n:], c=model.c, d=model.d)

    def step(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        return self.ad @ x + self.bd @ u

    @cached_property
    def fused(self) -> np.ndarray:
        """[[Ad, Bd], [C Ad, C Bd + D]]: times [x[k]; u[k]] it gives [x[k+1]; y], y the
        outputs at k+1 with u[k] still held (what the rig samples right after its step)."""
        top = np.hstack([self.ad, self.bd])
        return np.vstack([top, self.c @ top + np.hstack([np.zeros_like(self.c), self.d])])

    def advance(self, xu: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """One step and its outputs in one matrix product: ``xu`` = [x[k]; u[k]] ->
        (x[k+1], C x[k+1] + D u[k])."""
        out = self.fused @ xu
        n = self.ad.shape[0]
        return out[:n], out[n:]

    def output(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        return self.c @ x + self.d @ u

    def simulate(self, x0: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """States (len(u)+1) and outputs (len(u)) for an input sequence u of shape (N, m)."""
        xs = np.empty((len(u) + 1, len(x0)))
        xs[0] = x0
        for k in range(len(u)):
            xs[k + 1] = self.ad @ xs[k] + self.bd @ u[k]
        ys = xs[:-1] @ self.c.T + u @ self.d.T
        return xs, ys
