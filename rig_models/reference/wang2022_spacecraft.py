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
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.integrate import BDF, DOP853, LSODA, RK23, RK45, OdeSolver, Radau

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
_SOLVERS: dict[str, type[OdeSolver]] = {
    "RK23": RK23, "RK45": RK45, "DOP853": DOP853, "Radau": Radau, "BDF": BDF, "LSODA": LSODA
}
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


class _Geometry:
    """J(gamma(t)) = A0 + cos(2 gamma) A1 + sin(2 gamma) A2 and C(gamma(t))^T = const
    + cos(gamma) COS + sin(gamma) SIN (eq 30) evaluated on plain floats, entry by entry as
    the array form does, and the last evaluation kept: within a step the torque law and the
    right-hand side ask for the same time (``perturbed`` plants share it with their model:
    the modes change, not the geometry)."""

    __slots__ = ("_coupling", "_gamma0", "_inertia", "_last", "_rate")

    def __init__(
        self, gamma0: float, rate: float, inertia_terms: tuple[FloatArray, FloatArray, FloatArray]
    ) -> None:
        a0, a1, a2 = (np.asarray(a, dtype=float).ravel().tolist() for a in inertia_terms)
        self._gamma0 = float(gamma0)
        self._rate = float(rate)
        self._inertia = tuple(zip(a0, a1, a2, strict=True))  # row-major (A0, A1, A2)
        self._coupling = tuple(  # per mode (const, cos, sin) of x, y, z
            tuple(
                float(v)
                for a in range(3)
                for v in (_COUPLING_CONST[p, a], _COUPLING_COS[p, a], _COUPLING_SIN[p, a])
            )
            for p in range(N_MODES)
        )
        self._last: tuple[float, tuple[tuple[float, ...], tuple[tuple[float, ...], ...]]] = (
            math.nan,
            ((), ()),
        )

    def at(self, t: float) -> tuple[tuple[float, ...], tuple[tuple[float, float, float], ...]]:
        last = self._last  # one tuple, replaced whole: never a stale half
        if last[0] == t:
            return last[1]
        gamma = self._gamma0 + self._rate * t
        cg, sg = math.cos(gamma), math.sin(gamma)
        c2, s2 = cg * cg - sg * sg, 2.0 * sg * cg
        j = tuple([a + c2 * b + s2 * c for a, b, c in self._inertia])
        ct = tuple(
            [
                (x0 + cg * xc + sg * xs, y0 + cg * yc + sg * ys, z0 + cg * zc + sg * zs)
                for x0, xc, xs, y0, yc, ys, z0, zc, zs in self._coupling
            ]
        )
        self._last = (t, (j, ct))
        return j, ct


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
        plant = replace(
            self, modal_omega=self.modal_omega * frequency_scale, modal_damping=damping
        )
        object.__setattr__(plant, "_geometry_cache", self._geometry())  # same J and C
        return plant

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

    def _geometry(self) -> _Geometry:
        """J(gamma(t)) and C(gamma(t))^T on floats (built once; shared by ``perturbed``)."""
        cached = self.__dict__.get("_geometry_cache")
        if cached is None:
            cached = _Geometry(self.wing_angle0_rad, self.wing_rate_rad_s, self._inertia_terms())
            object.__setattr__(self, "_geometry_cache", cached)
        return cached

    def _modal_terms(self) -> tuple[tuple[float, ...], tuple[float, ...]]:
        """Per mode -2 zeta lam (1/s) and lam^2 (1/s^2), grouped as the array form groups
        -2 zeta lam eta' - lam^2 eta (built once per model)."""
        cached = self.__dict__.get("_modal_cache")
        if cached is None:
            lam = self.modal_omega
            cached = (
                tuple((-2.0 * self.modal_damping * lam).tolist()),
                tuple((lam * lam).tolist()),
            )
            object.__setattr__(self, "_modal_cache", cached)
        return cached

    def inertia_and_coupling_floats(
        self, t: float
    ) -> tuple[tuple[float, ...], tuple[tuple[float, float, float], ...]]:
        """:meth:`inertia_and_coupling` as plain floats: J(gamma(t)) row-major (9 floats) and
        the six rows of C(gamma(t))^T (one (x, y, z) per mode). Same arithmetic, entry by
        entry, without numpy's per-call cost on 3-vectors (the simulator's hot path)."""
        return self._geometry().at(t)

    def rhs(self, t: float, x: FloatArray, tau: ArrayLike) -> FloatArray:
        """State derivative; x = [q (4, scalar first), omega (3), eta (6), eta_dot (6)]."""
        tau_list = np.asarray(tau, dtype=float).tolist()
        return np.array(self.rhs_floats(float(t), np.asarray(x, dtype=float).tolist(), tau_list))

    def rhs_floats(self, t: float, x: list[float], tau: Sequence[float]) -> list[float]:
        """:meth:`rhs` on plain floats (x a list of the 19 states, tau three floats).

        Paper eq 1 solved for w' and eta'' (the mass matrix eliminated by its Schur
        complement J - C C^T, a 3 x 3 system by Cramer's rule), q' = q (x) [0, w] / 2.
        """
        j, ct = self._geometry().at(t)
        damping, stiffness = self._modal_terms()
        j00, j01, j02, j10, j11, j12, j20, j21, j22 = j
        q0, q1, q2, q3, w0, w1, w2 = x[0:7]
        deta = x[13:19]
        # per mode: modal rhs r = -2 zeta lam eta' - lam^2 eta; sums over the modes of
        # C eta' (momentum), C r (for the torque balance) and C C^T (for J - C C^T)
        ce0 = ce1 = ce2 = cr0 = cr1 = cr2 = 0.0
        s00 = s01 = s02 = s11 = s12 = s22 = 0.0
        modal = []
        for (cx, cy, cz), e, de, kd, ks in zip(
            ct, x[7:13], deta, damping, stiffness, strict=True
        ):
            r = kd * de - ks * e
            modal.append(r)
            ce0 += cx * de
            ce1 += cy * de
            ce2 += cz * de
            cr0 += cx * r
            cr1 += cy * r
            cr2 += cz * r
            s00 += cx * cx
            s01 += cx * cy
            s02 += cx * cz
            s11 += cy * cy
            s12 += cy * cz
            s22 += cz * cz
        h0 = j00 * w0 + j01 * w1 + j02 * w2 + ce0
        h1 = j10 * w0 + j11 * w1 + j12 * w2 + ce1
        h2 = j20 * w0 + j21 * w1 + j22 * w2 + ce2
        tau0, tau1, tau2 = tau
        b0 = tau0 - (w1 * h2 - w2 * h1) - cr0
        b1 = tau1 - (w2 * h0 - w0 * h2) - cr1
        b2 = tau2 - (w0 * h1 - w1 * h0) - cr2
        # (J - C C^T) w' = b by Cramer's rule (no LAPACK call for a 3 x 3)
        a, bb, c = j00 - s00, j01 - s01, j02 - s02
        d, e, f = j10 - s01, j11 - s11, j12 - s12
        g, hh, i = j20 - s02, j21 - s12, j22 - s22
        co0, co1, co2 = e * i - f * hh, f * g - d * i, d * hh - e * g
        det = a * co0 + bb * co1 + c * co2
        dw0 = (co0 * b0 + (c * hh - bb * i) * b1 + (bb * f - c * e) * b2) / det
        dw1 = (co1 * b0 + (a * i - c * g) * b1 + (c * d - a * f) * b2) / det
        dw2 = (co2 * b0 + (bb * g - a * hh) * b1 + (a * e - bb * d) * b2) / det
        out = [
            0.5 * (-q1 * w0 - q2 * w1 - q3 * w2),
            0.5 * (q0 * w0 + q2 * w2 - q3 * w1),
            0.5 * (q0 * w1 - q1 * w2 + q3 * w0),
            0.5 * (q0 * w2 + q1 * w1 - q2 * w0),
            dw0,
            dw1,
            dw2,
        ]
        out += deta
        out += [
            r - (cx * dw0 + cy * dw1 + cz * dw2) for r, (cx, cy, cz) in zip(modal, ct, strict=True)
        ]
        return out

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
    torque: Callable[[float, FloatArray], ArrayLike],
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
    If it also has a method ``floats(t, x)`` taking the state as a list of floats and
    returning the three torque components as floats (the same values), the integration
    calls that instead (no arrays per call: the variable-amplitude torque laws have it).

    ``breakpoints`` are times where the torque may jump (e.g. a zero-order-hold grid); the
    integration restarts there so no step straddles a discontinuity. ``x0`` defaults to rest
    at the identity attitude. Results are sampled at ``t_eval`` (default: 1001 points). At a
    breakpoint the torque is evaluated from inside the segment being integrated (time nudged
    by 1e-9 of the segment length), so ``torque`` may switch value exactly at breakpoints.

    Each segment is integrated by scipy's ``method`` solver (``scipy.integrate.DOP853`` by
    default) stepped directly, as ``solve_ivp`` steps it: the same steps and tolerances, a
    sample inside a step from the step's dense output, a sample at a step's end (every
    breakpoint) the step's own end state, without ``solve_ivp``'s per-call set-up.
    """
    t_end = float(t_end)
    if not (math.isfinite(t_end) and t_end > 0.0):
        raise ValueError(f"t_end: expected > 0 s, got {t_end}")
    if method not in _SOLVERS:
        raise ValueError(f"method: expected one of {sorted(_SOLVERS)}, got {method!r}")
    solver_class = _SOLVERS[method]
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

    # the torque is evaluated from inside the current segment: at a breakpoint a piecewise
    # torque must take the value of the side being integrated
    inside = [0.0, t_end]  # [lo + eps, hi - eps], eps = 1e-9 of the segment
    rhs_floats = model.rhs_floats
    torque_floats = getattr(torque, "floats", None)

    if torque_floats is not None:

        def fun(t: float, x: FloatArray) -> list[float]:
            lo, hi = inside
            xs = x.tolist()
            return rhs_floats(t, xs, torque_floats(min(max(t, lo), hi), xs))

    else:

        def fun(t: float, x: FloatArray) -> list[float]:
            lo, hi = inside
            tau = np.asarray(torque(min(max(t, lo), hi), x), dtype=float).tolist()
            return rhs_floats(t, x.tolist(), tau)

    out = np.empty((samples.size, STATE_SIZE))
    k = 0  # the next sample to fill
    n_samples = samples.size
    times = samples.tolist()
    for t0, t1 in zip(edges[:-1].tolist(), edges[1:].tolist(), strict=True):
        eps = 1e-9 * (t1 - t0)
        inside[:] = [t0 + eps, t1 - eps]
        while k < n_samples and times[k] <= t0:  # only t = 0: the first segment's start
            out[k] = state
            k += 1
        solver = solver_class(
            fun, t0, state, t1, rtol=rtol, atol=atol, first_step=min(t1 - t0, 0.05)
        )
        while solver.status == "running":
            message = solver.step()
            if solver.status == "failed":
                raise RuntimeError(f"simulate: integration failed on [{t0}, {t1}]: {message}")
            t_step = solver.t
            k_end = k
            while k_end < n_samples and times[k_end] <= t_step:
                k_end += 1
            if k_end > k:
                k_in = k_end - 1 if times[k_end - 1] == t_step else k_end
                if k_in > k:  # inside the step: its dense output, as solve_ivp's t_eval
                    out[k:k_in] = solver.dense_output()(samples[k:k_in]).T
                if k_in < k_end:  # at the step's end: its end state
                    out[k_in] = solver.y
                k = k_end
        state = solver.y.copy()
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
