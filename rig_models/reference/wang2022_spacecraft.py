"""Wang, Wu & Zou (2022) reference spacecraft: rigid body + rotating flexible solar wing.

Paper: "Flexible spacecraft attitude maneuver planning based on variable amplitudes input
shaping method", J. National Univ. Defense Technology 44(1), 2022 (seed 004), section 4.1.

Equations of motion (paper eq 1, body frame, SI units)::

    J(t) w' + C(t) eta'' + w x (J(t) w + C(t) eta') = tau
    C(t)^T w' + eta'' + 2 zeta Lambda eta' + Lambda^2 eta = 0

with the attitude quaternion q (scalar first, body -> inertial) following q' = q (x) [0, w] / 2.
The paper prints ``C(t) eta`` inside the gyroscopic bracket; that term has units of inertia,
not angular momentum, so we use the angular momentum J w + C eta' (a typesetting slip, we
believe). Like eq 1 we leave out the J' w and C' eta' terms of the turning wing (the drive
that turns the wing closes that balance).

Data from the paper:

* body inertia diag[2666.7, 2666.7, 1666.7] kg m^2;
* one wing's inertia about its floating frame diag[53.6, 1607.9, 1661.6] kg m^2; the wing
  turns about x_s (parallel to body x) at 3 deg/s from gamma = 0;
* coupling C(gamma), eq 30 (3 x 6, kg^0.5 m), and the six constrained modes of Table 1.

Modelling choices (not in the paper):

* J(gamma) = J_body + n_wings R_x(gamma) J_wing R_x(gamma)^T with n_wings = 2 ("a pair of
  wings", section 4.1; with one wing J - C C^T is not positive definite, so the mass matrix
  would be indefinite). No hinge-offset (parallel-axis) terms: the paper gives neither wing
  mass nor hinge position.
* Modal frequencies from Table 1's period column (3.16, 1.14, 0.56, 0.55, 0.22, 0.19 s); its Hz
  column is the same data rounded (within 1 %, except mode 1: 1/3.16 s = 0.316 Hz, printed
  0.32). The variable-amplitude shaper needs periods on a time grid (eq 24), so the periods
  are the primary data.
* Tip (out-of-plane) deflection: the paper gives no mode shapes. We take the out-of-plane
  bending modes (#1, #4, #5: bending about y_s) as modes of a uniform cantilever wing of
  length ``wing_length_m`` (assumed 8.5 m) whose mass follows from J_yy = m L^2 / 3; a
  mass-normalised cantilever mode has tip value 2/sqrt(m). The in-plane mode (#2) and the
  torsion modes (#3, #6) do not move the tip centre-line out of plane.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.integrate import solve_ivp

from rig_models.quaternion import (
    euler_321_to_quaternion,
    quaternion_angle_error,
    quaternion_multiply,
    quaternion_rotate,
)

FloatArray = NDArray[np.float64]

__all__ = [
    "STATE_SIZE",
    "SimulationResult",
    "Wang2022Spacecraft",
    "euler_321_to_quaternion",
    "quaternion_angle_error",
    "quaternion_multiply",
    "simulate",
]

N_MODES = 6
STATE_SIZE = 4 + 3 + 2 * N_MODES  # q, omega, eta, eta_dot

# eq 30, one row per mode: the row is [c_x, c_y, c_z] of C(gamma)^T.
# Rows are  const + cos(gamma) * COS + sin(gamma) * SIN.
_COUPLING_CONST = np.array(
    [[0, 0, 0], [0, 0, 0], [8.433, 0, 0], [0, 0, 0], [0, 0, 0], [-3.4535, 0, 0]], dtype=float
)
_COUPLING_COS = np.array(
    [[0, 63.5, 0], [0, 0, 67.3], [0, 0, 0], [0, 19.26, 0], [0, 8.99, 0], [0, 0, 0]], dtype=float
)
_COUPLING_SIN = np.array(
    [[0, 0, 63.5], [0, -67.3, 0], [0, 0, 0], [0, 0, 19.26], [0, 0, 8.99], [0, 0, 0]], dtype=float
)
# Table 1
MODE_NAMES = (
    "1st y_s bending",
    "1st z_s bending",
    "1st x_s torsion",
    "2nd y_s bending",
    "3rd y_s bending",
    "2nd x_s torsion",
)
TABLE1_PERIOD_S = (3.16, 1.14, 0.56, 0.55, 0.22, 0.19)
TABLE1_FREQ_HZ = (0.32, 0.88, 1.79, 1.80, 4.51, 5.19)
_OUT_OF_PLANE_MODES = (0, 3, 4)  # bending about y_s


def _rot_x(angle: float) -> FloatArray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def uniform_cantilever_tip_gain(wing_inertia_yy: float, wing_length_m: float) -> float:
    """Tip value of a mass-normalised uniform-cantilever mode, 2/sqrt(m), m = 3 J_yy / L^2."""
    if wing_length_m <= 0.0:
        raise ValueError(f"wing_length_m: expected > 0 m, got {wing_length_m}")
    mass = 3.0 * wing_inertia_yy / wing_length_m**2
    return 2.0 / math.sqrt(mass)


@dataclass(frozen=True)
class Wang2022Spacecraft:
    """Parameters of the paper's spacecraft; ``perturbed`` makes a plant that differs."""

    body_inertia: FloatArray = field(default_factory=lambda: np.diag([2666.7, 2666.7, 1666.7]))
    wing_inertia: FloatArray = field(default_factory=lambda: np.diag([53.6, 1607.9, 1661.6]))
    n_wings: int = 2
    wing_rate_rad_s: float = math.radians(3.0)
    wing_angle0_rad: float = 0.0
    modal_omega: FloatArray = field(
        default_factory=lambda: 2.0 * math.pi / np.array(TABLE1_PERIOD_S)
    )
    modal_damping: FloatArray = field(default_factory=lambda: np.zeros(N_MODES))
    wing_length_m: float = 8.5

    def __post_init__(self) -> None:
        for name in ("body_inertia", "wing_inertia"):
            value = np.asarray(getattr(self, name), dtype=float)
            if value.shape != (3, 3):
                raise ValueError(f"{name}: expected a 3x3 matrix (kg m^2), got {value.shape}")
            object.__setattr__(self, name, value)
        omega = np.asarray(self.modal_omega, dtype=float).reshape(-1)
        zeta = np.broadcast_to(np.asarray(self.modal_damping, dtype=float), (N_MODES,)).copy()
        if omega.shape != (N_MODES,) or np.any(omega <= 0.0):
            raise ValueError(f"modal_omega: expected {N_MODES} frequencies > 0 rad/s")
        if np.any(zeta < 0.0) or np.any(zeta >= 1.0):
            raise ValueError("modal_damping: expected damping ratios in [0, 1)")
        if self.n_wings < 1:
            raise ValueError(f"n_wings: expected >= 1, got {self.n_wings}")
        object.__setattr__(self, "modal_omega", omega)
        object.__setattr__(self, "modal_damping", zeta)
        # the mass matrix [[J, C], [C^T, I]] must be positive definite at every wing angle
        for gamma in np.linspace(0.0, math.pi, 37):
            schur = self.inertia(gamma) - self.coupling(gamma) @ self.coupling(gamma).T
            if np.min(np.linalg.eigvalsh(schur)) <= 0.0:
                raise ValueError(
                    "n_wings/inertia: J - C C^T is not positive definite "
                    f"at gamma = {math.degrees(gamma):.0f} deg (mass matrix indefinite)"
                )

    # -- geometry -------------------------------------------------------------------------
    def wing_angle(self, t: ArrayLike) -> FloatArray:
        """gamma(t), rad."""
        return self.wing_angle0_rad + self.wing_rate_rad_s * np.asarray(t, dtype=float)

    @staticmethod
    def coupling(gamma: float) -> FloatArray:
        """C(gamma), 3 x 6 (kg^0.5 m), paper eq 30."""
        rows = _COUPLING_CONST + math.cos(gamma) * _COUPLING_COS + math.sin(gamma) * _COUPLING_SIN
        return rows.T

    @staticmethod
    def coupling_rows(gamma: ArrayLike) -> FloatArray:
        """C(gamma)^T for an array of angles: shape (..., 6, 3)."""
        g = np.asarray(gamma, dtype=float)[..., None, None]
        return _COUPLING_CONST + np.cos(g) * _COUPLING_COS + np.sin(g) * _COUPLING_SIN

    def inertia(self, gamma: float) -> FloatArray:
        """J(gamma) = J_body + n_wings R_x J_wing R_x^T (kg m^2)."""
        r = _rot_x(gamma)
        return self.body_inertia + self.n_wings * (r @ self.wing_inertia @ r.T)

    @property
    def tip_gain(self) -> FloatArray:
        """Out-of-plane tip deflection per unit modal coordinate (m per kg^0.5 m)."""
        gain = np.zeros(N_MODES)
        gain[list(_OUT_OF_PLANE_MODES)] = uniform_cantilever_tip_gain(
            float(self.wing_inertia[1, 1]), self.wing_length_m
        )
        return gain

    def perturbed(
        self, frequency_scale: float = 1.0, damping_ratio: float | None = None
    ) -> Wang2022Spacecraft:
        """A plant whose modal frequencies are scaled and/or whose modal damping differs."""
        if not (math.isfinite(frequency_scale) and frequency_scale > 0.0):
            raise ValueError(f"frequency_scale: expected > 0, got {frequency_scale}")
        damping = self.modal_damping if damping_ratio is None else np.full(N_MODES, damping_ratio)
        return replace(self, modal_omega=self.modal_omega * frequency_scale, modal_damping=damping)

    # -- dynamics -------------------------------------------------------------------------
    def _inertia_terms(self) -> tuple[FloatArray, FloatArray, FloatArray]:
        """J(gamma) = A0 + cos(2 gamma) A1 + sin(2 gamma) A2 (R_x J_w R_x^T is quadratic)."""
        cached = self.__dict__.get("_j_terms")
        if cached is None:
            j0, j45, j90 = (self.inertia(g) for g in (0.0, math.pi / 4, math.pi / 2))
            a0 = 0.5 * (j0 + j90)
            cached = (a0, 0.5 * (j0 - j90), j45 - a0)
            object.__setattr__(self, "_j_terms", cached)
        return cached

    def inertia_and_coupling(self, t: float) -> tuple[FloatArray, FloatArray]:
        """J(gamma(t)) (3 x 3) and C(gamma(t)) (3 x 6), fast path for simulation."""
        j, ct = self._inertia_and_coupling_rows(t)
        return j, ct.T

    def _inertia_and_coupling_rows(self, t: float) -> tuple[FloatArray, FloatArray]:
        gamma = self.wing_angle0_rad + self.wing_rate_rad_s * t
        cg, sg = math.cos(gamma), math.sin(gamma)
        a0, a1, a2 = self._inertia_terms()
        j = a0 + (cg * cg - sg * sg) * a1 + (2.0 * sg * cg) * a2
        ct = _COUPLING_CONST + cg * _COUPLING_COS + sg * _COUPLING_SIN  # C^T, 6 x 3
        return j, ct

    def rhs(self, t: float, x: FloatArray, tau: FloatArray) -> FloatArray:
        """State derivative; x = [q (4, scalar first), omega (3), eta (6), eta_dot (6)]."""
        j, ct = self._inertia_and_coupling_rows(t)
        lam = self.modal_omega
        w = x[4:7]
        eta, deta = x[7:13], x[13:19]
        modal_rhs = -2.0 * self.modal_damping * lam * deta - lam * lam * eta
        h = j @ w + deta @ ct
        w0, w1, w2 = w
        gyro = np.array([w1 * h[2] - w2 * h[1], w2 * h[0] - w0 * h[2], w0 * h[1] - w1 * h[0]])
        dw = _solve3(j - ct.T @ ct, tau - gyro - modal_rhs @ ct)
        ddeta = modal_rhs - ct @ dw
        q0, q1, q2, q3 = x[0:4]
        dq = 0.5 * np.array(
            [
                -q1 * w0 - q2 * w1 - q3 * w2,
                q0 * w0 + q2 * w2 - q3 * w1,
                q0 * w1 - q1 * w2 + q3 * w0,
                q0 * w2 + q1 * w1 - q2 * w0,
            ]
        )
        return np.concatenate([dq, dw, deta, ddeta])

    def energy(self, t: float, x: FloatArray) -> float:
        """Kinetic + modal strain energy (J)."""
        w, eta, deta = x[4:7], x[7:13], x[13:19]
        gamma = float(self.wing_angle(t))
        j, c = self.inertia(gamma), self.coupling(gamma)
        kinetic = 0.5 * w @ j @ w + w @ c @ deta + 0.5 * deta @ deta
        return float(kinetic + 0.5 * np.sum((self.modal_omega * eta) ** 2))

    def inertial_angular_momentum(self, t: float, x: FloatArray) -> FloatArray:
        """Angular momentum J w + C eta' expressed in the inertial frame (N m s)."""
        gamma = float(self.wing_angle(t))
        h_body = self.inertia(gamma) @ x[4:7] + self.coupling(gamma) @ x[13:19]
        return quaternion_rotate(x[0:4], h_body)


def _solve3(m: FloatArray, b: FloatArray) -> FloatArray:
    """Solve a 3 x 3 symmetric positive definite system (Cramer's rule, no LAPACK overhead)."""
    (a, bb, c), (d, e, f), (g, h, i) = m.tolist()
    co0, co1, co2 = e * i - f * h, f * g - d * i, d * h - e * g
    det = a * co0 + bb * co1 + c * co2
    inv = np.array(
        [
            [co0, c * h - bb * i, bb * f - c * e],
            [co1, a * i - c * g, c * d - a * f],
            [co2, bb * g - a * h, a * e - bb * d],
        ]
    )
    return inv @ b / det


# ------------------------------------------------------------------------------ quaternions
# generic: rig_models.quaternion (imported above; re-exported for the paper's code and tests)

# ------------------------------------------------------------------------------ simulation


@dataclass(frozen=True)
class SimulationResult:
    """Sampled histories of a simulation (SI units, body frame)."""

    t: FloatArray
    q: FloatArray  # (N, 4), normalised
    omega: FloatArray  # (N, 3) rad/s
    eta: FloatArray  # (N, 6)
    eta_dot: FloatArray  # (N, 6)
    torque: FloatArray  # (N, 3) N m

    @property
    def state(self) -> FloatArray:
        return np.hstack([self.q, self.omega, self.eta, self.eta_dot])


def simulate(
    model: Wang2022Spacecraft,
    torque: Callable[[float, FloatArray], FloatArray],
    t_end: float,
    *,
    x0: ArrayLike | None = None,
    breakpoints: ArrayLike = (),
    t_eval: ArrayLike | None = None,
    rtol: float = 1e-9,
    atol: float = 1e-11,
    method: str = "DOP853",
) -> SimulationResult:
    """Integrate the nonlinear attitude + modal dynamics under the body torque ``torque(t, x)``.

    ``torque`` gets the time and the state (for a plain torque history, ignore the state).

    ``breakpoints`` are times where the torque may jump (e.g. a zero-order-hold grid); the
    integration restarts there so no step straddles a discontinuity. ``x0`` defaults to rest
    at the identity attitude. Results are sampled at ``t_eval`` (default: 1001 points). At a
    breakpoint the torque is evaluated from inside the segment being integrated (time nudged
    by 1e-9 of the segment length), so ``torque`` may switch value exactly at breakpoints.
    """
    t_end = float(t_end)
    if not (math.isfinite(t_end) and t_end > 0.0):
        raise ValueError(f"t_end: expected > 0 s, got {t_end}")
    if x0 is None:
        state = np.zeros(STATE_SIZE)
        state[0] = 1.0
    else:
        state = np.asarray(x0, dtype=float).copy()
        if state.shape != (STATE_SIZE,):
            raise ValueError(f"x0: expected {STATE_SIZE} states, got {state.shape}")
    samples = np.linspace(0.0, t_end, 1001) if t_eval is None else np.asarray(t_eval, float)
    if samples.ndim != 1 or np.any(np.diff(samples) < 0) or samples[0] < 0 or samples[-1] > t_end:
        raise ValueError("t_eval: expected sorted times within [0, t_end]")
    bps = np.asarray(breakpoints, dtype=float).reshape(-1)
    edges = np.unique(np.concatenate([[0.0, t_end], bps[(bps > 0.0) & (bps < t_end)]]))

    segment = [0.0, t_end]

    def fun(t: float, x: FloatArray) -> FloatArray:
        # evaluate the torque from inside the current segment: at a breakpoint a piecewise
        # torque must take the value of the side being integrated
        lo, hi = segment
        eps = 1e-9 * (hi - lo)
        tau = torque(min(max(t, lo + eps), hi - eps), x)
        return model.rhs(t, x, np.asarray(tau, dtype=float))

    out = np.empty((samples.size, STATE_SIZE))
    filled = np.zeros(samples.size, dtype=bool)
    for t0, t1 in zip(edges[:-1], edges[1:], strict=True):
        segment[:] = [t0, t1]
        mask = (samples >= t0) & (samples <= t1) & ~filled
        n_in = int(np.count_nonzero(mask))
        t_seg = samples[mask]
        if n_in == 0 or t_seg[-1] < t1:
            t_seg = np.append(t_seg, t1)  # always return the segment's end state
        sol = solve_ivp(
            fun, (t0, t1), state, method=method, rtol=rtol, atol=atol,
            t_eval=t_seg, first_step=min(t1 - t0, 0.05),
        )
        if not sol.success:
            raise RuntimeError(f"simulate: integration failed on [{t0}, {t1}]: {sol.message}")
        if n_in:
            out[mask] = sol.y[:, :n_in].T
            filled |= mask
        state = sol.y[:, -1].copy()
        state[0:4] /= np.linalg.norm(state[0:4])
    q = out[:, 0:4] / np.linalg.norm(out[:, 0:4], axis=1, keepdims=True)
    # torque at the samples, from the right side of a breakpoint (left side at t_end)
    tau = np.array(
        [
            np.asarray(torque(min(float(t), t_end - 1e-9 * t_end), x), dtype=float)
            for t, x in zip(samples, out, strict=True)
        ]
    )
    return SimulationResult(samples, q, out[:, 4:7], out[:, 7:13], out[:, 13:19], tau)
