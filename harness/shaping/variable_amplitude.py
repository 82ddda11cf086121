"""Variable-amplitude ZV / ZVD shaping of a rest-to-rest slew (Wang, Wu & Zou 2022, seed 004).

The slew is planned as a body angular-acceleration profile a(t) = a0 * chi(t) (eq 13),
piecewise constant on n intervals of dt (t_f = n dt). ``a0`` is the bang-bang reference of
the decoupled rigid model, a0 = 4 theta_target / t_f^2 per axis, so chi = +-1 is bang-bang.

Constraints:

* Vibration (eqs 24-27). With the body acceleration prescribed, each constrained mode obeys
  eta'' + 2 zeta w eta' + w^2 eta = F(t) = -C(t)^T a(t) (eq 23). On interval i the coupling is
  frozen at its mid-interval value (the paper's piecewise linearisation), so F_p is piecewise
  constant and is a sum of steps f_{p,k} = F_{p,k} - F_{p,k-1} at t_k = k dt, k = 0..n (the
  last one, -F_{p,n-1}, ends the slew). With the period T_p = m_p dt (m_p even), the steps are
  grouped by half periods (eq 6): class j holds f_{p,j}, f_{p,j+m_p/2}, f_{p,j+m_p}, ... Each
  class must be a combination of shifted ZV ([1, K]) or ZVD ([1, 2K, K^2]) sequences (eqs 8-12),
  i.e. its polynomial sum_l c_l z^l has a simple (ZV) or double (ZVD) root at z = -1/K. That
  is m_p/2 (ZV) or m_p (ZVD) linear equations per mode, as the paper counts.
* Rest to rest: sum_i chi_i = 0 on each axis (zero final rate; implied by "rest-to-rest").
* Attitude (eqs 16-22): the quaternion propagated through the n intervals must reach the
  target. We propagate with the exact exponential of the mid-interval rate (second order; the
  paper's eq 19 is the first-order I + Omega dt / 2, which does not keep |q| = 1) and impose
  the vector part of q_target^-1 (x) q_end = 0 (three independent equations instead of the
  four, norm-redundant, of eq 22).

Objective: the smoothness v(chi) of eq 28, summed over the three axes; we minimise v^2 / n
(same minimiser, smooth). Solved by scipy's SQP ``trust-constr`` (equality-constrained SQP)
after eliminating the linear constraints by orthogonal projection (see
:func:`solve_variable_amplitude`; SLSQP's dense subproblems are too big for 3n ~ 10^4
unknowns). The design must converge and meet every constraint, else RuntimeError.

Torque laws for the simulator: :class:`FeedforwardTorque` (open-loop inverse dynamics of eq 1
on the design model) and :class:`PathTrackingTorque` (imposes the planned acceleration on a
plant, i.e. an ideal attitude loop). :func:`prescribed_motion_residual` is the cheap modal
residual of a plant under the imposed plan (eq 23), for sensitivity sweeps.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike, NDArray
from scipy.linalg import cho_factor, cho_solve
from scipy.optimize import NonlinearConstraint, minimize
from scipy.sparse.linalg import LinearOperator

from rig_models.quaternion import (
    euler_321_to_quaternion,
    quaternion_angle_error,
    quaternion_multiply,
)

FloatArray = NDArray[np.float64]


class FlexibleSpacecraft(Protocol):
    """What the variable-amplitude design needs of a spacecraft model (paper 004's
    ``rig_models.reference.wang2022_spacecraft.Wang2022Spacecraft`` is one, passed in by the
    study): its modes, and its rigid-flexible coupling as the appendages turn."""

    modal_omega: FloatArray  # rad/s, one per mode
    modal_damping: FloatArray  # damping ratio, one per mode

    def wing_angle(self, t: ArrayLike) -> FloatArray: ...

    def coupling_rows(self, gamma: ArrayLike) -> FloatArray: ...

    def inertia_and_coupling(self, t: float) -> tuple[FloatArray, FloatArray]: ...

    def inertia_and_coupling_floats(
        self, t: float
    ) -> tuple[Sequence[float], Sequence[tuple[float, float, float]]]:
        """J(t) row-major (9 floats) and the rows of C(t)^T (one (x, y, z) per mode)."""
        ...


__all__ = [
    "FeedforwardTorque",
    "PathTrackingTorque",
    "ManeuverSpec",
    "VariableAmplitudeProfile",
    "design_modal_states",
    "end_quaternion",
    "grid_multiples",
    "prescribed_motion_residual",
    "solve_variable_amplitude",
    "summarize",
    "vibration_constraint_matrix",
]

SHAPERS = ("none", "zv", "zvd")  # "none": attitude and rest constraints only (reference)


@dataclass(frozen=True)
class ManeuverSpec:
    """What to plan: target Euler angles (3-2-1, rad), duration, grid, shaper, shaped modes."""

    target_euler_rad: tuple[float, float, float] = tuple(
        math.radians(a) for a in (60.0, 45.0, 30.0)
    )
    duration_s: float = 20.0
    dt_s: float = 0.005
    shaper: str = "zvd"
    modes: tuple[int, ...] = (0, 1, 2, 3, 4, 5)
    design_damping: float = 0.0

    def __post_init__(self) -> None:
        if self.shaper not in SHAPERS:
            raise ValueError(f"shaper: expected one of {SHAPERS}, got {self.shaper!r}")
        if len(self.target_euler_rad) != 3:
            raise ValueError("target_euler_rad: expected three angles (roll, pitch, yaw)")
        if not (self.duration_s > 0.0 and self.dt_s > 0.0):
            raise ValueError("duration_s/dt_s: expected > 0 s")
        n = self.duration_s / self.dt_s
        if abs(n - round(n)) > 1e-6 * n:
            raise ValueError(
                f"dt_s: expected a divisor of duration_s={self.duration_s}, got {self.dt_s}"
            )
        if not (0.0 <= self.design_damping < 1.0):
            raise ValueError(f"design_damping: expected [0, 1), got {self.design_damping}")
        if len(self.modes) == 0 or len(set(self.modes)) != len(self.modes):
            raise ValueError("modes: expected distinct mode indices")

    @property
    def n_intervals(self) -> int:
        return int(round(self.duration_s / self.dt_s))

    @property
    def a0(self) -> FloatArray:
        """Bang-bang reference acceleration per axis, 4 theta / t_f^2 (rad/s^2)."""
        theta = np.asarray(self.target_euler_rad, dtype=float)
        return 4.0 * theta / self.duration_s**2

    @property
    def target_quaternion(self) -> FloatArray:
        return euler_321_to_quaternion(self.target_euler_rad)


def grid_multiples(model: FlexibleSpacecraft, spec: ManeuverSpec) -> list[int]:
    """m_p = T_p / dt for the shaped modes (eq 24); each must be an even integer."""
    if spec.shaper == "none":
        return []
    out = []
    for p in spec.modes:
        if not 0 <= p < model.modal_omega.size:
            raise ValueError(f"modes: index {p} out of range 0..{model.modal_omega.size - 1}")
        zeta = spec.design_damping
        period = 2.0 * math.pi / (model.modal_omega[p] * math.sqrt(1.0 - zeta * zeta))
        m = period / spec.dt_s
        m_int = int(round(m))
        if abs(m - m_int) > 1e-6 * m or m_int % 2 or m_int < 2:
            raise ValueError(
                f"dt_s: mode {p + 1} period {period:.6g} s is not an even multiple of "
                f"dt_s={spec.dt_s} (eq 24 needs T_p = m_p dt, m_p even)"
            )
        out.append(m_int)
    return out


def _mid_couplings(model: FlexibleSpacecraft, spec: ManeuverSpec) -> FloatArray:
    """C^T at mid-interval wing angles, shape (n, 6, 3)."""
    n = spec.n_intervals
    t_mid = (np.arange(n) + 0.5) * spec.dt_s
    return model.coupling_rows(model.wing_angle(t_mid))


def _class_rows(length: int, k_factor: float, shaper: str) -> FloatArray:
    """Rows r with r . c = 0 iff sum_l c_l z^l has a simple/double root at z = -1/K."""
    l_idx = np.arange(length, dtype=float)
    base = (-1.0) ** l_idx * k_factor ** (length - 1 - l_idx)
    rows = [base] if shaper == "zv" else [base, l_idx * base]
    out = []
    for r in rows:
        norm = np.linalg.norm(r)
        if norm > 0.0:
            out.append(r / norm)
    return np.array(out)


def vibration_constraint_matrix(model: FlexibleSpacecraft, spec: ManeuverSpec) -> sp.csr_matrix:
    """Sparse rows (eqs 24-27) acting on chi flattened axis-major (x[axis * n + i])."""
    n = spec.n_intervals
    if spec.shaper == "none":
        return sp.csr_matrix((0, 3 * n))
    a0 = spec.a0
    ct_mid = _mid_couplings(model, spec)  # (n, 6, 3)
    zeta = spec.design_damping
    k_factor = math.exp(-zeta * math.pi / math.sqrt(1.0 - zeta * zeta))
    # increments f = D F, D (n+1) x n
    diff = sp.diags([np.ones(n), -np.ones(n)], [0, -1], shape=(n + 1, n), format="csr")
    blocks = []
    for p, m in zip(spec.modes, grid_multiples(model, spec), strict=True):
        # F_p = G x, G[i, axis*n + i] = -C^T_{p,axis}(gamma_i) a0_axis
        g_cols = [sp.diags(-ct_mid[:, p, axis] * a0[axis], 0, shape=(n, n)) for axis in range(3)]
        g_mat = sp.hstack(g_cols, format="csr")
        half = m // 2
        rows, cols, vals = [], [], []
        r = 0
        for j in range(half):
            idx = np.arange(j, n + 1, half)
            for row in _class_rows(idx.size, k_factor, spec.shaper):
                rows.extend([r] * idx.size)
                cols.extend(idx.tolist())
                vals.extend(row.tolist())
                r += 1
        sel = sp.csr_matrix((vals, (rows, cols)), shape=(r, n + 1))
        block = (sel @ diff @ g_mat).tocsr()
        norms = np.sqrt(np.asarray(block.multiply(block).sum(axis=1)).ravel())
        keep = norms > 1e-12 * max(norms.max(), 1.0)
        block = sp.diags(1.0 / norms[keep]) @ block[keep]
        blocks.append(block)
    return sp.vstack(blocks, format="csr")


def _rest_matrix(n: int) -> sp.csr_matrix:
    rows = np.repeat(np.arange(3), n)
    return sp.csr_matrix(
        (np.full(3 * n, 1.0 / math.sqrt(n)), (rows, np.arange(3 * n))), shape=(3, 3 * n)
    )


# ------------------------------------------------------------------------- attitude constraint


def _rates(chi: FloatArray, a0: FloatArray, dt: float) -> tuple[FloatArray, FloatArray]:
    """Body rates at the grid (n+1, 3) and at mid-interval (n, 3) for chi of shape (3, n)."""
    acc = (a0[:, None] * chi).T  # (n, 3)
    grid = np.vstack([np.zeros(3), np.cumsum(acc, axis=0) * dt])
    return grid, grid[:-1] + 0.5 * dt * acc


def _half_rotation(w: FloatArray, dt: float) -> tuple[FloatArray, FloatArray]:
    """exp(w dt / 2) as quaternions (n, 4) and d/dw (n, 3, 4)."""
    v = 0.5 * dt * w
    theta = np.linalg.norm(v, axis=1)
    small = theta < 1e-4
    th = np.where(small, 1.0, theta)
    sinc = np.where(small, 1.0 - theta**2 / 6.0, np.sin(th) / th)
    # (theta cos theta - sin theta) / theta^3
    dsinc = np.where(small, -1.0 / 3.0 + theta**2 / 30.0, (th * np.cos(th) - np.sin(th)) / th**3)
    quat = np.column_stack([np.cos(theta), sinc[:, None] * v])
    deriv = np.empty((w.shape[0], 3, 4))
    deriv[:, :, 0] = -sinc[:, None] * v
    deriv[:, :, 1:] = sinc[:, None, None] * np.eye(3) + dsinc[:, None, None] * (
        v[:, :, None] * v[:, None, :]
    )
    return quat, deriv * (0.5 * dt)


def end_quaternion(chi: FloatArray, a0: FloatArray, dt: float) -> FloatArray:
    """Attitude after the profile chi (3, n) from the identity (eqs 16-22, exact exponential)."""
    _, w_mid = _rates(np.asarray(chi, dtype=float), a0, dt)
    quat, _ = _half_rotation(w_mid, dt)
    q = np.array([1.0, 0.0, 0.0, 0.0])
    for e in quat:
        q = quaternion_multiply(q, e)
    return q


class _AttitudeConstraint:
    """vec(q_target^-1 (x) q_end(chi)) = 0 with its Jacobian; caches the last evaluation."""

    def __init__(self, spec: ManeuverSpec) -> None:
        self.n = spec.n_intervals
        self.dt = spec.dt_s
        self.a0 = spec.a0
        q_t = spec.target_quaternion
        self.q_t_conj = q_t * np.array([1.0, -1.0, -1.0, -1.0])
        self._key: bytes | None = None

    def _evaluate(self, x: FloatArray) -> None:
        key = x.tobytes()
        if key == self._key:
            return
        chi = x.reshape(3, self.n)
        _, w_mid = _rates(chi, self.a0, self.dt)
        quat, dquat = _half_rotation(w_mid, self.dt)
        n = self.n
        prefix = np.empty((n + 1, 4))
        suffix = np.empty((n + 1, 4))
        prefix[0] = suffix[n] = (1.0, 0.0, 0.0, 0.0)
        for i in range(n):
            prefix[i + 1] = _qmul(prefix[i], quat[i])
        for i in range(n - 1, -1, -1):
            suffix[i] = _qmul(quat[i], suffix[i + 1])
        q_end = prefix[n]
        self.value = _qmul(self.q_t_conj, q_end)[1:]
        # d g / d w_i[c] = vec(q_t^-1 (x) P_i (x) dE_i/dw_c (x) S_{i+1})
        left = quaternion_multiply(self.q_t_conj, prefix[:n])[:, None, :]
        dq_dw = quaternion_multiply(
            quaternion_multiply(left, dquat), suffix[1:][:, None, :]
        )[..., 1:]  # (n, 3 [w comp], 3 [g comp])
        # w_i = dt * sum_{k<i} a_k + dt/2 * a_i  ->  d/da_k = dt * sum_{i>k} + dt/2 * (i = k)
        rev = np.cumsum(dq_dw[::-1], axis=0)[::-1]
        d_da = self.dt * (rev - 0.5 * dq_dw)  # (n, 3, 3)
        d_dchi = d_da * self.a0[None, :, None]
        self.jacobian = np.ascontiguousarray(d_dchi.transpose(2, 1, 0).reshape(3, 3 * n))
        self._key = key

    def fun(self, x: FloatArray) -> FloatArray:
        self._evaluate(x)
        return self.value.copy()

    def jac(self, x: FloatArray) -> FloatArray:
        self._evaluate(x)
        return self.jacobian.copy()


def _qmul(p: FloatArray, q: FloatArray) -> FloatArray:
    p0, p1, p2, p3 = p
    q0, q1, q2, q3 = q
    return np.array(
        [
            p0 * q0 - p1 * q1 - p2 * q2 - p3 * q3,
            p0 * q1 + p1 * q0 + p2 * q3 - p3 * q2,
            p0 * q2 - p1 * q3 + p2 * q0 + p3 * q1,
            p0 * q3 + p1 * q2 - p2 * q1 + p3 * q0,
        ]
    )


# ------------------------------------------------------------------------------ the solver


@dataclass(frozen=True)
class VariableAmplitudeProfile:
    """A solved variable-amplitude slew: chi (3, n), a = a0 chi, and how the solve went."""

    spec: ManeuverSpec
    chi: FloatArray
    converged: bool
    status: int
    message: str
    iterations: int
    smoothness: float  # v(chi), eq 28 (summed over axes)
    linear_residual: float  # max |A chi| (rows normalised)
    attitude_error_rad: float  # angle between q_end (grid propagation) and the target
    end_rate_rad_s: float  # |omega(t_f)|
    n_linear_constraints: int
    grid_multiples: tuple[int, ...]
    info: dict[str, float] = field(default_factory=dict)

    @property
    def acceleration(self) -> FloatArray:
        """Body angular acceleration per interval, shape (n, 3) (rad/s^2)."""
        return (self.spec.a0[:, None] * self.chi).T

    @property
    def interval_times_s(self) -> FloatArray:
        """Grid t_k = k dt, k = 0..n."""
        return np.arange(self.spec.n_intervals + 1) * self.spec.dt_s

    def rate_at(self, t: float) -> FloatArray:
        """Planned body rate omega(t), rad/s (zero outside the slew)."""
        grid, _ = _rates(self.chi, self.spec.a0, self.spec.dt_s)
        if t <= 0.0 or t >= self.spec.duration_s:
            return np.zeros(3)
        i = min(int(t / self.spec.dt_s), self.spec.n_intervals - 1)
        return grid[i] + self.acceleration[i] * (t - i * self.spec.dt_s)


class _NullSpaceProjector:
    """Orthogonal projector onto {x : A x = 0}: P x = x - A^T (A A^T)^-1 A x.

    (A A^T) is small (rows ~ number of constraints) and is factored once, densely; one step
    of iterative refinement keeps A P x at rounding level despite its conditioning.
    """

    def __init__(self, a: sp.csr_matrix) -> None:
        self.a = a
        self.at = a.T.tocsr()
        gram = (a @ self.at).toarray()
        try:
            self._factor = ("cho", cho_factor(gram))
        except np.linalg.LinAlgError:  # rank-deficient constraints: pseudo-inverse
            vals, vecs = np.linalg.eigh(gram)
            keep = vals > 1e-12 * vals.max()
            self._factor = ("eig", (vecs[:, keep], vals[keep]))

    def _solve(self, r: FloatArray) -> FloatArray:
        kind, data = self._factor
        if kind == "cho":
            return cho_solve(data, r)
        vecs, vals = data
        return vecs @ ((vecs.T @ r) / vals)

    def __call__(self, x: FloatArray) -> FloatArray:
        y = x - self.at @ self._solve(self.a @ x)
        return y - self.at @ self._solve(self.a @ y)


def solve_variable_amplitude(
    model: FlexibleSpacecraft,
    spec: ManeuverSpec,
    *,
    maxiter: int = 100,
    tol: float = 1e-10,
) -> VariableAmplitudeProfile:
    """Solve problem (29) by SQP; raise RuntimeError if it fails or a constraint is not met.

    The linear constraints (vibration, rest) are eliminated by orthogonal projection: with P
    the projector onto their null space, chi = P u and we solve min |u|^2 / n s.t.
    attitude(P u) = 0 with scipy's ``trust-constr`` (equality-constrained SQP, exact gradients,
    Hessian-vector products of the attitude constraint by differences of its Jacobian). Any
    component of u outside the null space only adds to |u|^2 and leaves chi unchanged, so the
    optimum has u = chi: this is problem (29) itself, with the objective v^2 / n (the rest
    constraint makes the mean of chi zero). The sparse linear rows would otherwise have to
    be factored inside every SQP iteration, which is far slower at 3n ~ 10^4 unknowns.
    """
    n = spec.n_intervals
    mults = grid_multiples(model, spec)
    a_vib = vibration_constraint_matrix(model, spec)
    a_lin = sp.vstack([a_vib, _rest_matrix(n)], format="csr")
    project = _NullSpaceProjector(a_lin)
    attitude = _AttitudeConstraint(spec)

    def att_fun(u: FloatArray) -> FloatArray:
        return attitude.fun(project(u))

    def att_jac(u: FloatArray) -> FloatArray:
        jac = attitude.jac(project(u))
        return np.array([project(row) for row in jac])

    def att_hess(u: FloatArray, v: FloatArray) -> LinearOperator:
        u = np.array(u, dtype=float)
        base = att_jac(u).T @ v

        def matvec(p: FloatArray) -> FloatArray:
            p = np.asarray(p, dtype=float).reshape(-1)
            norm = np.linalg.norm(p)
            if norm == 0.0:
                return np.zeros_like(u)
            h = 1e-6 * max(1.0, np.linalg.norm(u)) / norm
            return (att_jac(u + h * p).T @ v - base) / h

        return LinearOperator((u.size, u.size), matvec=matvec, dtype=float)

    def objective(u: FloatArray) -> float:
        return float(u @ u / n)

    def gradient(u: FloatArray) -> FloatArray:
        return 2.0 * u / n

    def hessian(u: FloatArray) -> LinearOperator:
        return LinearOperator((3 * n, 3 * n), matvec=lambda p: 2.0 * np.ravel(p) / n, dtype=float)

    # start from the bang-bang reference (eq 15), projected onto the linear constraints
    u0 = project(np.tile(np.where(np.arange(n) < n // 2, 1.0, -1.0), 3))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # "delta_grad == 0.0" notes
        res = minimize(
            objective,
            u0,
            jac=gradient,
            hess=hessian,
            method="trust-constr",
            constraints=[NonlinearConstraint(att_fun, 0.0, 0.0, jac=att_jac, hess=att_hess)],
            options={
                "maxiter": maxiter,
                "gtol": tol,
                "xtol": 1e-14,
                "initial_tr_radius": math.sqrt(3 * n),
                "verbose": 0,
            },
        )
    x = project(res.x)
    chi = x.reshape(3, n)
    lin_res = float(np.max(np.abs(a_lin @ x)))
    q_end = end_quaternion(chi, spec.a0, spec.dt_s)
    att_err = float(quaternion_angle_error(q_end, spec.target_quaternion))
    grid, _ = _rates(chi, spec.a0, spec.dt_s)
    dev = chi - chi.mean(axis=1, keepdims=True)
    profile = VariableAmplitudeProfile(
        spec=spec,
        chi=chi,
        converged=bool(res.success),
        status=int(res.status),
        message=str(res.message),
        iterations=int(res.nit),
        smoothness=float(np.sqrt(np.sum(dev * dev))),
        linear_residual=lin_res,
        attitude_error_rad=att_err,
        end_rate_rad_s=float(np.linalg.norm(grid[-1])),
        n_linear_constraints=int(a_vib.shape[0]),
        grid_multiples=tuple(mults),
        info={
            "constr_violation": float(res.constr_violation),
            "optimality": float(res.optimality),
        },
    )
    feasible = lin_res < 1e-8 and att_err < 1e-8
    if not (res.success and feasible):
        raise RuntimeError(
            f"variable-amplitude {spec.shaper.upper()} SQP did not converge: status "
            f"{res.status} ({res.message}); max linear residual {lin_res:.2e}, "
            f"attitude error {math.degrees(att_err):.2e} deg after {res.nit} iterations"
        )
    return profile


# ---------------------------------------------------------------- design model and torque


def _modal_response(
    eta0: FloatArray,
    deta0: FloatArray,
    force: FloatArray,
    omega: FloatArray,
    zeta: FloatArray,
    s: float | FloatArray,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """eta, eta', eta'' after time s under constant modal force (closed form, per mode)."""
    sigma = zeta * omega
    wd = omega * np.sqrt(1.0 - zeta * zeta)
    y0 = eta0 - force / omega**2
    decay = np.exp(-sigma * s)
    c, sn = np.cos(wd * s), np.sin(wd * s)
    y = decay * (y0 * c + (deta0 + sigma * y0) / wd * sn)
    dy = decay * (deta0 * c - (omega**2 * y0 + sigma * deta0) / wd * sn)
    eta = y + force / omega**2
    return eta, dy, force - 2.0 * sigma * dy - omega**2 * eta


def _modal_states(
    model: FlexibleSpacecraft, profile: VariableAmplitudeProfile, damping: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    spec = profile.spec
    n = spec.n_intervals
    ct_mid = _mid_couplings(model, spec)
    force = -np.einsum("npa,na->np", ct_mid, profile.acceleration)
    eta = np.zeros((n + 1, model.modal_omega.size))
    deta = np.zeros_like(eta)
    for i in range(n):
        eta[i + 1], deta[i + 1], _ = _modal_response(
            eta[i], deta[i], force[i], model.modal_omega, damping, spec.dt_s
        )
    return eta, deta, force


def design_modal_states(
    model: FlexibleSpacecraft, profile: VariableAmplitudeProfile
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Design-model modal states at the grid (n+1, 6) each, and the modal forces (n, 6).

    Design model: the spacecraft ``model`` as the designer knows it (its frequencies, damping
    ``spec.design_damping``), body acceleration prescribed, coupling frozen per interval.
    """
    damping = np.full(model.modal_omega.size, profile.spec.design_damping)
    return _modal_states(model, profile, damping)


def prescribed_motion_residual(
    plant: FlexibleSpacecraft, profile: VariableAmplitudeProfile
) -> FloatArray:
    """Vibration amplitude of each plant mode left at t_f when the body follows the plan.

    Eq 23 with the plant's frequencies and damping (closed form per interval, coupling frozen
    per interval as in the design): the envelope sqrt(eta^2 + ((eta' + zeta w eta)/w_d)^2)
    of the free vibration after the slew. Cheap (no attitude simulation): use it for
    sensitivity sweeps.
    """
    eta, deta, _ = _modal_states(plant, profile, plant.modal_damping)
    w, z = plant.modal_omega, plant.modal_damping
    wd = w * np.sqrt(1.0 - z * z)
    return np.hypot(eta[-1], (deta[-1] + z * w * eta[-1]) / wd)


class _Grid:
    """The slew's interval grid on floats: (i, s) of a time, or None outside the slew."""

    __slots__ = ("_dt", "_last", "_t_f")

    def __init__(self, spec: ManeuverSpec) -> None:
        self._t_f = float(spec.duration_s)
        self._dt = float(spec.dt_s)
        self._last = spec.n_intervals - 1

    def interval(self, t: float) -> tuple[int, float] | None:
        if t < 0.0 or t >= self._t_f:
            return None
        i = min(int(t / self._dt), self._last)
        return i, t - i * self._dt


def _rows(a: FloatArray) -> list[tuple[float, ...]]:
    return [tuple(row) for row in np.asarray(a, dtype=float).tolist()]


class FeedforwardTorque:
    """Open-loop body torque tau(t) that makes the design model follow the profile (eq 1).

    tau = J a + C eta_d'' + w x (J w + C eta_d'), with w, a the planned rate and acceleration
    and eta_d the design-model modal response; zero after the slew. It ignores the state it is
    given (``__call__(t, x)`` matches the simulator's torque law). ``breakpoints`` are the grid
    times where tau jumps (pass them to the simulator).

    Evaluated on plain floats (the simulator calls it ~10^5 times a run): the per-interval
    terms of :func:`_modal_response` that do not depend on the time into the interval are
    computed once, here, with the same numpy arithmetic; the design model's parameters are
    read once.
    """

    def __init__(self, design_model: FlexibleSpacecraft, profile: VariableAmplitudeProfile):
        self.model = design_model
        self.profile = profile
        self._eta, self._deta, self._force = design_modal_states(design_model, profile)
        self._rates, _ = _rates(profile.chi, profile.spec.a0, profile.spec.dt_s)
        self._acc = profile.acceleration
        self._zeta = np.full(design_model.modal_omega.size, profile.spec.design_damping)
        # _modal_response's arithmetic, split into what is fixed per mode / per interval
        omega, zeta = design_model.modal_omega, self._zeta
        sigma = zeta * omega
        wd = omega * np.sqrt(1.0 - zeta * zeta)
        n = profile.spec.n_intervals
        eta0, deta0, force = self._eta[:n], self._deta[:n], self._force
        y0 = eta0 - force / omega**2
        per_interval = np.stack(
            [
                y0,
                (deta0 + sigma * y0) / wd,
                deta0,
                (omega**2 * y0 + sigma * deta0) / wd,
                force / omega**2,
                force,
            ],
            axis=-1,
        )  # (n, modes, 6)
        self._mode_terms = [[tuple(m) for m in row] for row in per_interval.tolist()]
        self._mode_consts = list(
            zip(
                (-sigma).tolist(), wd.tolist(), (2.0 * sigma).tolist(), (omega**2).tolist(),
                strict=True,
            )
        )
        self._acc_rows = _rows(self._acc)
        self._grid = _Grid(profile.spec)
        self._rate_rows = _rows(self._rates)

    @property
    def breakpoints(self) -> FloatArray:
        return self.profile.interval_times_s

    @property
    def design_residual(self) -> FloatArray:
        """Design-model free-vibration amplitude of each mode after the slew."""
        w = self.model.modal_omega
        return np.hypot(self._eta[-1], self._deta[-1] / w)

    def __call__(self, t: float, x: FloatArray | None = None) -> FloatArray:
        return np.array(self.floats(float(t)))

    def floats(self, t: float, x: Sequence[float] | None = None) -> tuple[float, float, float]:
        """The torque at t as three floats (N m); x is ignored."""
        where = self._grid.interval(t)
        if where is None:
            return (0.0, 0.0, 0.0)
        i, s = where
        a0, a1, a2 = self._acc_rows[i]
        r0, r1, r2 = self._rate_rows[i]
        w0, w1, w2 = r0 + a0 * s, r1 + a1 * s, r2 + a2 * s
        j, ct = self.model.inertia_and_coupling_floats(t)
        # C eta_d'' and C eta_d', eta_d from _modal_response (closed form, per mode)
        cd0 = cd1 = cd2 = ce0 = ce1 = ce2 = 0.0
        for (cx, cy, cz), (y0, b, deta0, e, fo, force), (msig, wd, two_sigma, w2m) in zip(
            ct, self._mode_terms[i], self._mode_consts, strict=True
        ):
            decay = math.exp(msig * s)
            c, sn = math.cos(wd * s), math.sin(wd * s)
            eta = decay * (y0 * c + b * sn) + fo
            dy = decay * (deta0 * c - e * sn)
            ddeta = force - two_sigma * dy - w2m * eta
            cd0 += cx * ddeta
            cd1 += cy * ddeta
            cd2 += cz * ddeta
            ce0 += cx * dy
            ce1 += cy * dy
            ce2 += cz * dy
        return _inverse_dynamics(j, (a0, a1, a2), (w0, w1, w2), (cd0, cd1, cd2), (ce0, ce1, ce2))


def _inverse_dynamics(
    j: Sequence[float],
    acc: tuple[float, float, float],
    w: tuple[float, float, float],
    c_ddeta: tuple[float, float, float],
    c_deta: tuple[float, float, float],
) -> tuple[float, float, float]:
    """Eq 1's torque J a + C eta'' + w x (J w + C eta'), J row-major, on floats."""
    j00, j01, j02, j10, j11, j12, j20, j21, j22 = j
    a0, a1, a2 = acc
    w0, w1, w2 = w
    h0 = j00 * w0 + j01 * w1 + j02 * w2 + c_deta[0]
    h1 = j10 * w0 + j11 * w1 + j12 * w2 + c_deta[1]
    h2 = j20 * w0 + j21 * w1 + j22 * w2 + c_deta[2]
    return (
        j00 * a0 + j01 * a1 + j02 * a2 + c_ddeta[0] + (w1 * h2 - w2 * h1),
        j10 * a0 + j11 * a1 + j12 * a2 + c_ddeta[1] + (w2 * h0 - w0 * h2),
        j20 * a0 + j21 * a1 + j22 * a2 + c_ddeta[2] + (w0 * h1 - w1 * h0),
    )


class PathTrackingTorque:
    """Torque law that imposes the planned body acceleration on ``plant`` (an ideal loop).

    tau = J a + C eta'' + w x (J w + C eta') with the plant's own state and parameters and
    eta'' from its modal equation under w' = a: the body follows the planned path exactly,
    the wing responds as in eq 23 with the plant's true frequencies and damping. Zero after
    the slew, so the residual vibration then moves the free body.

    Evaluated on plain floats; the plant's modal parameters are read once, here.
    """

    def __init__(self, plant: FlexibleSpacecraft, profile: VariableAmplitudeProfile):
        self.plant = plant
        self.profile = profile
        self._acc = profile.acceleration
        lam = plant.modal_omega
        # -2 zeta lam eta' - lam^2 eta, grouped as the array form groups it
        self._modal = list(
            zip((-2.0 * plant.modal_damping * lam).tolist(), (lam * lam).tolist(), strict=True)
        )
        self._acc_rows = _rows(self._acc)
        self._grid = _Grid(profile.spec)

    @property
    def breakpoints(self) -> FloatArray:
        return self.profile.interval_times_s

    def __call__(self, t: float, x: FloatArray) -> FloatArray:
        return np.array(self.floats(float(t), np.asarray(x, dtype=float).tolist()))

    def floats(self, t: float, x: Sequence[float]) -> tuple[float, float, float]:
        """The torque at t on the state x (19 floats) as three floats (N m)."""
        where = self._grid.interval(t)
        if where is None:
            return (0.0, 0.0, 0.0)
        i, _ = where
        a0, a1, a2 = self._acc_rows[i]
        j, ct = self.plant.inertia_and_coupling_floats(t)
        cd0 = cd1 = cd2 = ce0 = ce1 = ce2 = 0.0
        for (cx, cy, cz), eta, deta, (kd, ks) in zip(
            ct, x[7:13], x[13:19], self._modal, strict=True
        ):
            # eta'' from the modal equation under w' = a: -2 zeta lam eta' - lam^2 eta - C^T a
            ddeta = kd * deta - ks * eta - (a0 * cx + a1 * cy + a2 * cz)
            cd0 += cx * ddeta
            cd1 += cy * ddeta
            cd2 += cz * ddeta
            ce0 += cx * deta
            ce1 += cy * deta
            ce2 += cz * deta
        return _inverse_dynamics(
            j, (a0, a1, a2), (x[4], x[5], x[6]), (cd0, cd1, cd2), (ce0, ce1, ce2)
        )


def summarize(profile: VariableAmplitudeProfile) -> dict[str, float | int | str | bool]:
    """Convergence report of a solve, JSON-friendly."""
    return {
        "shaper": profile.spec.shaper,
        "converged": profile.converged,
        "status": profile.status,
        "message": profile.message,
        "iterations": profile.iterations,
        "smoothness_v": profile.smoothness,
        "max_linear_residual": profile.linear_residual,
        "end_attitude_error_deg": math.degrees(profile.attitude_error_rad),
        "end_rate_rad_s": profile.end_rate_rad_s,
        "n_vibration_constraints": profile.n_linear_constraints,
        "n_intervals": profile.spec.n_intervals,
    }
