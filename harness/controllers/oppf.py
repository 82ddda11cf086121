"""Optimal positive position feedback (OPPF) design (Hu 2006, eqs 5-14).

Structure and compensators (eqs 5-6)::

    eta'' + D eta' + Omega eta = a1 C^T G xi
    xi''  + D_f xi' + Omega_f xi = a2 Omega_f C eta

with one sensor/actuator pair (sensor ``e_s = b^T eta / gamma``, modal force ``-b e_a``). We
normalise each compensator on its own mode: ``a1 = a2 = 1`` and ``C_ij = w_i b_j / b_i``; then
compensator i reads ``w_i gamma / b_i`` times the sensor voltage, the actuator voltage is
``e_a = -sum_i w_i g_i xi_i / b_i``, and the stability condition (eq 7)
``Omega - a1 a2 C^T G C > 0`` reduces, for one isolated mode, to the classical ``g_i < 1``.

Design (eqs 10-14): minimise ``J = 1/2 trace[(P_s + P_u) X(0)]`` over the gains ``g_i``, the
filter frequencies ``w_ci`` and damping ratios ``zeta_ci`` with ``P_s``, ``P_u`` the solutions of
``P A + A^T P + Q = 0`` for the closed-loop matrix ``A`` of eq (8), ``Q_s = diag(Omega, I, 0, 0)``
(so ``x^T Q_s x`` is the vibration energy ``E``), ``Q_u = r K_v^T K_v`` with ``e_a = K_v x``, and
``X(0)`` unit energy in every design mode (half potential, half kinetic), compensators at rest;
subject to eq (7) with a margin, solved by SLSQP from several starting points.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.linalg import solve_continuous_lyapunov
from scipy.optimize import minimize

from harness.controllers.ppf import PPFCompensatorParameters, PPFController


@dataclass(frozen=True)
class PPFDesignModel:
    """Modes to control: frequencies (rad/s), structural damping ratios, actuator participation
    ``b_i`` (modal force per actuator volt) and sensor constant ``gamma`` (eq 3)."""

    freqs_rad_s: np.ndarray
    damping_ratios: np.ndarray
    participation: np.ndarray
    gamma: float

    def __post_init__(self) -> None:
        w = np.atleast_1d(np.asarray(self.freqs_rad_s, dtype=float))
        z = np.broadcast_to(np.asarray(self.damping_ratios, dtype=float), w.shape).copy()
        b = np.atleast_1d(np.asarray(self.participation, dtype=float))
        if w.ndim != 1 or b.shape != w.shape:
            raise ValueError("freqs_rad_s and participation must be 1-D of the same length")
        if np.any(w <= 0) or not np.all(np.isfinite(w)):
            raise ValueError("freqs_rad_s must be positive")
        if np.any(z < 0) or np.any(z >= 1):
            raise ValueError("damping_ratios must be in [0, 1)")
        if np.any(b == 0) or not np.all(np.isfinite(b)):
            raise ValueError("participation must be non-zero for every design mode")
        if not math.isfinite(self.gamma) or self.gamma <= 0:
            raise ValueError(f"gamma must be positive, got {self.gamma!r}")
        object.__setattr__(self, "freqs_rad_s", w)
        object.__setattr__(self, "damping_ratios", z)
        object.__setattr__(self, "participation", b)

    @property
    def n(self) -> int:
        return int(self.freqs_rad_s.size)

    @property
    def omega(self) -> np.ndarray:
        return np.diag(self.freqs_rad_s**2)

    def participation_matrix(self) -> np.ndarray:
        """``C`` of eqs (5)-(7) with ``a1 = a2 = 1``: ``C_ij = w_i b_j / b_i``."""
        b = self.participation
        return (self.freqs_rad_s / b)[:, None] * b[None, :]

    def input_gains(self) -> np.ndarray:
        """Compensator input gains on the sensor voltage: ``w_i gamma / b_i``."""
        return self.freqs_rad_s * self.gamma / self.participation

    def output_gains(self, gains: np.ndarray) -> np.ndarray:
        """Actuator volts per unit compensator coordinate: ``-w_i g_i / b_i``."""
        return -self.freqs_rad_s * np.asarray(gains, dtype=float) / self.participation


def stability_matrix(model: PPFDesignModel, gains: np.ndarray) -> np.ndarray:
    """``Omega - a1 a2 C^T G C`` (eq 7, ``a1 = a2 = 1``); positive definite means stable."""
    c = model.participation_matrix()
    return model.omega - c.T @ np.diag(np.asarray(gains, dtype=float)) @ c


def stability_margin(model: PPFDesignModel, gains: np.ndarray) -> float:
    """Smallest eigenvalue of ``Omega^-1/2 (Omega - C^T G C) Omega^-1/2``: 1 with no feedback,
    0 at the stability boundary, negative beyond it."""
    s = np.diag(1.0 / model.freqs_rad_s)
    return float(np.min(np.linalg.eigvalsh(s @ stability_matrix(model, gains) @ s)))


def closed_loop_matrix(
    model: PPFDesignModel, gains: np.ndarray, comp_freqs: np.ndarray, comp_zetas: np.ndarray
) -> np.ndarray:
    """``A-bar`` of eq (8), state ``[eta, eta', xi, xi']``."""
    n = model.n
    w = model.freqs_rad_s
    wc = np.asarray(comp_freqs, dtype=float)
    zc = np.asarray(comp_zetas, dtype=float)
    c = model.participation_matrix()
    g = np.diag(np.asarray(gains, dtype=float))
    a = np.zeros((4 * n, 4 * n))
    i = np.eye(n)
    a[0:n, n:2 * n] = i
    a[n:2 * n, 0:n] = -model.omega
    a[n:2 * n, n:2 * n] = -np.diag(2 * model.damping_ratios * w)
    a[n:2 * n, 2 * n:3 * n] = c.T @ g
    a[2 * n:3 * n, 3 * n:4 * n] = i
    a[3 * n:4 * n, 0:n] = np.diag(wc**2) @ c
    a[3 * n:4 * n, 2 * n:3 * n] = -np.diag(wc**2)
    a[3 * n:4 * n, 3 * n:4 * n] = -np.diag(2 * zc * wc)
    return a


@dataclass(frozen=True)
class OPPFWeights:
    """``voltage_weight`` is ``r`` in ``Q_u = r K_v^T K_v`` (J s per V^2 s, i.e. the cost
    counts ``E + r e_a^2``); ``min_margin`` is the required ``stability_margin``."""

    voltage_weight: float = 0.0
    min_margin: float = 0.05

    def __post_init__(self) -> None:
        if not self.voltage_weight >= 0:
            raise ValueError(f"voltage_weight must be >= 0, got {self.voltage_weight!r}")
        if not 0 <= self.min_margin < 1:
            raise ValueError(f"min_margin must be in [0, 1), got {self.min_margin!r}")


def initial_covariance(model: PPFDesignModel) -> np.ndarray:
    """``X(0)``: unit vibration energy in each design mode, half potential and half kinetic,
    compensators at rest."""
    n = model.n
    x0 = np.zeros((4 * n, 4 * n))
    x0[:n, :n] = np.diag(0.5 / model.freqs_rad_s**2)
    x0[n:2 * n, n:2 * n] = 0.5 * np.eye(n)
    return x0


def oppf_cost(
    model: PPFDesignModel,
    gains: np.ndarray,
    comp_freqs: np.ndarray,
    comp_zetas: np.ndarray,
    weights: OPPFWeights | None = None,
    x0_cov: np.ndarray | None = None,
) -> float:
    """``J = 1/2 trace[(P_s + P_u) X(0)]`` (eqs 11-14); ``inf`` if ``A-bar`` is not Hurwitz."""
    weights = weights or OPPFWeights()
    a = closed_loop_matrix(model, gains, comp_freqs, comp_zetas)
    if np.max(np.linalg.eigvals(a).real) >= 0:
        return math.inf
    n = model.n
    q = np.zeros_like(a)
    q[:n, :n] = model.omega
    q[n:2 * n, n:2 * n] = np.eye(n)
    if weights.voltage_weight > 0:
        kv = np.zeros(4 * n)
        kv[2 * n:3 * n] = model.output_gains(gains)
        q = q + weights.voltage_weight * np.outer(kv, kv)
    p = solve_continuous_lyapunov(a.T, -q)
    x0 = initial_covariance(model) if x0_cov is None else x0_cov
    return 0.5 * float(np.trace(p @ x0))


@dataclass(frozen=True)
class OPPFDesign:
    """Result of ``design_oppf``."""

    model: PPFDesignModel
    gains: np.ndarray
    comp_freqs_rad_s: np.ndarray
    comp_zetas: np.ndarray
    cost: float
    open_loop_cost: float
    margin: float
    max_real_eig: float
    success: bool
    message: str
    weights: OPPFWeights = field(default_factory=OPPFWeights)

    def stability_condition_holds(self) -> bool:
        return bool(np.all(np.linalg.eigvalsh(stability_matrix(self.model, self.gains)) > 0))

    def compensator_parameters(self) -> list[PPFCompensatorParameters]:
        kin = self.model.input_gains()
        kout = self.model.output_gains(self.gains)
        return [
            PPFCompensatorParameters(float(w), float(z), float(ki), float(ko))
            for w, z, ki, ko in zip(self.comp_freqs_rad_s, self.comp_zetas, kin, kout,
                                    strict=True)
        ]

    def controller(self, voltage_limit: float | None = None) -> PPFController:
        """PPF bank reading the sensor voltage and returning the actuator voltage."""
        return PPFController(self.compensator_parameters(), output_limit=voltage_limit)


def design_oppf(
    model: PPFDesignModel,
    weights: OPPFWeights | None = None,
    freq_ratio_bounds: tuple[float, float] = (0.3, 2.0),
    zeta_bounds: tuple[float, float] = (0.02, 1.0),
    starts: int = 4,
) -> OPPFDesign:
    """Minimise ``J`` over ``(g_i, w_ci / w_i, zeta_ci)`` subject to eq (7) with
    ``stability_margin >= weights.min_margin``; SLSQP from ``starts`` starting points."""
    weights = weights or OPPFWeights()
    if starts < 1:
        raise ValueError(f"starts must be >= 1, got {starts}")
    lo_r, hi_r = freq_ratio_bounds
    lo_z, hi_z = zeta_bounds
    if not 0 < lo_r < 1 < hi_r:
        raise ValueError(f"freq_ratio_bounds must bracket 1, got {freq_ratio_bounds}")
    if not 0 < lo_z < hi_z:
        raise ValueError(f"zeta_bounds must be increasing and positive, got {zeta_bounds}")
    n = model.n
    w = model.freqs_rad_s

    def unpack(p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return p[:n], p[n:2 * n] * w, p[2 * n:]

    def cost(p: np.ndarray) -> float:
        g, wc, zc = unpack(p)
        if stability_margin(model, g) <= 0:
            return 1e12
        j = oppf_cost(model, g, wc, zc, weights)
        return j if math.isfinite(j) else 1e12

    constraints = [{"type": "ineq",
                    "fun": lambda p: stability_margin(model, p[:n]) - weights.min_margin}]
    bounds = [(0.0, 1.0)] * n + [(lo_r, hi_r)] * n + [(lo_z, hi_z)] * n
    rng = np.random.default_rng(0)
    best = None
    for k in range(starts):
        if k == 0:
            p0 = np.r_[np.full(n, 0.2), np.ones(n), np.full(n, 0.3)]
        else:
            p0 = np.r_[rng.uniform(0.05, 0.4, n), rng.uniform(0.7, 1.3, n),
                       rng.uniform(0.1, 0.8, n)]
        # pull the starting gains inside the stability region
        while stability_margin(model, p0[:n]) < weights.min_margin:
            p0[:n] *= 0.5
        res = minimize(cost, p0, method="SLSQP", bounds=bounds, constraints=constraints,
                       options={"maxiter": 500, "ftol": 1e-12})
        if best is None or (res.fun < best.fun and
                            stability_margin(model, res.x[:n]) >= weights.min_margin - 1e-9):
            best = res
    assert best is not None
    g, wc, zc = unpack(best.x)
    a = closed_loop_matrix(model, g, wc, zc)
    open_loop = oppf_cost(model, np.zeros(n), w, np.full(n, 0.5), weights)
    return OPPFDesign(
        model=model, gains=g, comp_freqs_rad_s=wc, comp_zetas=zc,
        cost=float(best.fun), open_loop_cost=open_loop,
        margin=stability_margin(model, g),
        max_real_eig=float(np.max(np.linalg.eigvals(a).real)),
        success=bool(best.success), message=str(best.message), weights=weights,
    )
