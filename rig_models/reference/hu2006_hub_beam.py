"""Reference plant of Hu (2006): rigid hub + cantilever beam with a tip mass, a PZT-5A
sensor/actuator patch pair at the beam root, and on-off thrusters on the hub.

Equations of motion (paper eqs 1-3; the paper's eq (1) prints ``D_i qdot_i``, read here as the
usual ``D_i qddot_i`` of a hub-beam model)::

    J thetaddot + D^T qddot                 = T              (1)
    qddot + D thetaddot + Z qdot + Lambda q = -B e_a         (2)
    gamma e_s = B^T q                                        (3)

``q`` are the mass-normalised *constrained* (clamped-at-hub) modal coordinates of the beam with
its tip mass, ``Lambda = diag(omega_i^2)``, ``Z = diag(2 zeta omega_i)``, ``D_i`` the rigid-elastic
coupling, ``T`` the thruster torque, ``e_a`` the actuator patch voltage and ``e_s`` the sensor
patch voltage. Five modes are kept.

Physical parameters (the paper takes its plant from Hu and Ma 2005, which we do not have; only
its first two coupled, i.e. hub-free, frequencies 3.161 and 16.954 rad/s are quoted). We chose a
rig-like aluminium beam and solved the hub inertia and beam thickness so that the five-mode
model's first two hub-free frequencies hit those values (``solve_hub_inertia_and_thickness``):

=====================================  ==========================  ==========================
hub radius b                           0.20 m                      chosen
hub inertia J_h                        3.9846 kg m^2               solved
beam length l, width                   2.0 m, 0.10 m               chosen
beam thickness                         2.6305 mm                   solved
beam material (aluminium)              E = 69 GPa, rho = 2700      chosen
tip mass m_t (point mass)              0.5 kg                      chosen
modal damping ratio (all modes)        0.01                        chosen (paper gives none)
PZT-5A patch (each face)               300 x 80 x 0.5 mm           chosen (4 patches of 75
                                                                   mm wired in parallel)
patch position from root               10 mm .. 310 mm             chosen
PZT-5A: Y11, d31, eps33^T              61 GPa, -171 pm/V, 1700e0   datasheet values
patch voltage limit                    +-200 V (0.4 MV/m)          chosen
thruster torque                        1 N m per unit command      paper's U_m = 1 read in N m
=====================================  ==========================  ==========================

Resulting model: J = 8.92 kg m^2, constrained frequencies 2.16, 16.65, 50.2, 102.4, 173.5 rad/s,
hub-free frequencies 3.161, 16.954, 50.3, 102.5, 173.6 rad/s (recomputed, never stored).

Piezo model (Crawley and de Luis, perfect bonding; patch mass and stiffness neglected as in the
paper's model, although on a 2.6 mm beam the patches would roughly double the root's bending
stiffness, so the real beam would be stiffer near the root than this model): the
actuator patch applies a bending moment ``M = Y11 |d31| w_p z_p e_a`` (``z_p = (h + t_p)/2``) whose
generalised force on mode i is ``M (phi_i'(x2) - phi_i'(x1))``; the collocated sensor patch on the
other face gives ``e_s = |e31| w_p z_p (w'(x2) - w'(x1)) / C_p`` with ``C_p = eps33 w_p L_p / t_p``,
wired so that eq (3) holds with ``gamma > 0``. Geometric stiffening, rotary inertia of the tip mass
and gravity are neglected (the paper's assumptions). SI units throughout.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cached_property

import numpy as np
from numpy.polynomial.legendre import leggauss
from scipy.integrate import solve_ivp
from scipy.linalg import expm
from scipy.optimize import brentq, least_squares

EPSILON_0 = 8.8541878128e-12  # F/m
HU2006_TARGET_COUPLED_FREQS_RAD_S = (3.161, 16.954)  # design targets (paper section 6)


@dataclass(frozen=True)
class HubBeamParameters:
    """Physical parameters of the hub-beam-tip-mass plant (SI)."""

    hub_radius: float = 0.20
    hub_inertia: float = 3.9846
    beam_length: float = 2.0
    beam_width: float = 0.10
    beam_thickness: float = 2.6305e-3
    beam_youngs_modulus: float = 69e9
    beam_density: float = 2700.0
    tip_mass: float = 0.5
    modal_damping_ratio: float = 0.01
    n_modes: int = 5
    patch_start: float = 0.010
    patch_length: float = 0.30
    patch_width: float = 0.08
    patch_thickness: float = 0.5e-3
    pzt_youngs_modulus: float = 61e9
    pzt_d31: float = -171e-12
    pzt_permittivity: float = 1700 * EPSILON_0
    voltage_limit: float = 200.0
    thruster_torque: float = 1.0

    def __post_init__(self) -> None:
        positive = (
            "hub_inertia", "beam_length", "beam_width", "beam_thickness", "beam_youngs_modulus",
            "beam_density", "patch_length", "patch_width", "patch_thickness",
            "pzt_youngs_modulus", "pzt_permittivity", "voltage_limit", "thruster_torque",
        )
        for name in positive:
            value = getattr(self, name)
            if not np.isfinite(value) or value <= 0:
                raise ValueError(f"{name} must be a positive finite number, got {value!r}")
        for name in ("hub_radius", "tip_mass", "modal_damping_ratio", "patch_start"):
            value = getattr(self, name)
            if not np.isfinite(value) or value < 0:
                raise ValueError(f"{name} must be a non-negative finite number, got {value!r}")
        if not 0 <= self.modal_damping_ratio < 1:
            raise ValueError(
                f"modal_damping_ratio must be in [0, 1), got {self.modal_damping_ratio}"
            )
        if int(self.n_modes) != self.n_modes or self.n_modes < 1:
            raise ValueError(f"n_modes must be a positive integer, got {self.n_modes!r}")
        if self.patch_start + self.patch_length > self.beam_length:
            raise ValueError("patch_start + patch_length must not exceed beam_length")


def cantilever_tip_mass_roots(mass_ratio: float, n_modes: int) -> np.ndarray:
    """First ``n_modes`` roots ``beta_i l`` of a clamped beam with a tip point mass.

    ``mass_ratio`` is tip mass / beam mass. Characteristic equation (divided by cosh)::

        1/cosh z + cos z + mu z (cos z tanh z - sin z) = 0
    """
    if mass_ratio < 0:
        raise ValueError(f"mass_ratio must be >= 0, got {mass_ratio}")
    if n_modes < 1:
        raise ValueError(f"n_modes must be >= 1, got {n_modes}")

    def char(z: float) -> float:
        return 1.0 / np.cosh(z) + np.cos(z) + mass_ratio * z * (np.cos(z) * np.tanh(z) - np.sin(z))

    grid = np.linspace(1e-6, (n_modes + 1.5) * np.pi, 400 * (n_modes + 2))
    values = np.array([char(z) for z in grid])
    roots: list[float] = []
    for i in range(len(grid) - 1):
        if values[i] * values[i + 1] < 0:
            roots.append(brentq(char, grid[i], grid[i + 1], xtol=1e-14))
            if len(roots) == n_modes:
                break
    if len(roots) < n_modes:
        raise RuntimeError("could not bracket all cantilever roots")
    return np.array(roots)


def cantilever_mode_shape(beta_l: float, xi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unnormalised clamped-free mode shape and its derivative d/dxi at ``xi = x / l``.

    ``phi = cosh a - cos a - s (sinh a - sin a)`` with ``a = beta_l xi`` and
    ``s = (cosh z + cos z) / (sinh z + sin z)`` (zero tip moment); evaluated without the
    cancellation of large hyperbolic terms.
    """
    z = float(beta_l)
    xi = np.asarray(xi, dtype=float)
    den = np.sinh(z) + np.sin(z)
    s = (np.cosh(z) + np.cos(z)) / den
    one_minus_s = (-np.exp(-z) + np.sin(z) - np.cos(z)) / den
    a = z * xi
    ch_minus_s_sh = 0.5 * (one_minus_s * np.exp(a) + (1 + s) * np.exp(-a))
    sh_minus_s_ch = 0.5 * (one_minus_s * np.exp(a) - (1 + s) * np.exp(-a))
    phi = ch_minus_s_sh - np.cos(a) + s * np.sin(a)
    dphi = z * (sh_minus_s_ch + np.sin(a) + s * np.cos(a))
    return phi, dphi


class Hu2006HubBeam:
    """Linear model of eqs (1)-(3); state ``x = [theta, q, thetadot, qdot]``, inputs
    ``u = [T, e_a]`` (thruster torque N m, actuator voltage V)."""

    def __init__(self, params: HubBeamParameters | None = None, n_quad: int = 400) -> None:
        self.params = params or HubBeamParameters()
        p = self.params
        n = int(p.n_modes)
        area = p.beam_width * p.beam_thickness
        second_moment = p.beam_width * p.beam_thickness**3 / 12
        rho_a = p.beam_density * area
        beam_mass = rho_a * p.beam_length
        self.beam_mass = beam_mass
        self.beta_l = cantilever_tip_mass_roots(p.tip_mass / beam_mass, n)
        self.constrained_freqs = (self.beta_l / p.beam_length) ** 2 * np.sqrt(
            p.beam_youngs_modulus * second_moment / rho_a
        )
        nodes, weights = leggauss(n_quad)
        xi = 0.5 * (nodes + 1)
        w = 0.5 * weights
        radius = p.hub_radius + p.beam_length * xi
        x1 = p.patch_start / p.beam_length
        x2 = (p.patch_start + p.patch_length) / p.beam_length
        coupling = np.empty(n)
        slope_diff = np.empty(n)
        tip = np.empty(n)
        self._shape_scale = np.empty(n)
        for i, z in enumerate(self.beta_l):
            phi, _ = cantilever_mode_shape(z, xi)
            phi_tip, _ = cantilever_mode_shape(z, np.array(1.0))
            modal_mass = beam_mass * np.sum(w * phi**2) + p.tip_mass * float(phi_tip) ** 2
            c = 1.0 / np.sqrt(modal_mass)
            self._shape_scale[i] = c
            coupling[i] = c * (
                rho_a * p.beam_length * np.sum(w * radius * phi)
                + p.tip_mass * (p.hub_radius + p.beam_length) * float(phi_tip)
            )
            _, d1 = cantilever_mode_shape(z, np.array(x1))
            _, d2 = cantilever_mode_shape(z, np.array(x2))
            slope_diff[i] = c * (float(d2) - float(d1)) / p.beam_length
            tip[i] = c * float(phi_tip)
        self.coupling = coupling
        self.tip_shape = tip
        self.patch_slope_difference = slope_diff
        self.inertia = (
            p.hub_inertia
            + rho_a * p.beam_length * np.sum(w * radius**2)
            + p.tip_mass * (p.hub_radius + p.beam_length) ** 2
        )
        self.modal_stiffness = self.constrained_freqs**2
        self.modal_damping = 2 * p.modal_damping_ratio * self.constrained_freqs
        z_p = 0.5 * (p.beam_thickness + p.patch_thickness)
        self.actuator_moment_per_volt = p.pzt_youngs_modulus * abs(p.pzt_d31) * p.patch_width * z_p
        capacitance = p.pzt_permittivity * p.patch_width * p.patch_length / p.patch_thickness
        e31 = abs(p.pzt_d31) * p.pzt_youngs_modulus
        self.sensor_volt_per_slope = e31 * p.patch_width * z_p / capacitance
        self.piezo_b = self.actuator_moment_per_volt * slope_diff  # B of eq (2)
        self.gamma = self.actuator_moment_per_volt / self.sensor_volt_per_slope  # eq (3)

    # ----- matrices -------------------------------------------------------------------------
    @property
    def n_modes(self) -> int:
        return int(self.params.n_modes)

    @property
    def n_states(self) -> int:
        return 2 * (self.n_modes + 1)

    def mass_matrix(self) -> np.ndarray:
        n = self.n_modes
        m = np.eye(n + 1)
        m[0, 0] = self.inertia
        m[0, 1:] = self.coupling
        m[1:, 0] = self.coupling
        return m

    def stiffness_matrix(self) -> np.ndarray:
        return np.diag(np.r_[0.0, self.modal_stiffness])

    def damping_matrix(self) -> np.ndarray:
        return np.diag(np.r_[0.0, self.modal_damping])

    def force_matrix(self) -> np.ndarray:
        """Generalised forces of ``[T, e_a]`` on ``[theta, q]`` (eqs 1-2)."""
        f = np.zeros((self.n_modes + 1, 2))
        f[0, 0] = 1.0
        f[1:, 1] = -self.piezo_b
        return f

    @cached_property
    def _state_space(self) -> tuple[np.ndarray, np.ndarray]:
        n1 = self.n_modes + 1
        m_inv = np.linalg.inv(self.mass_matrix())
        a = np.zeros((2 * n1, 2 * n1))
        a[:n1, n1:] = np.eye(n1)
        a[n1:, :n1] = -m_inv @ self.stiffness_matrix()
        a[n1:, n1:] = -m_inv @ self.damping_matrix()
        b = np.zeros((2 * n1, 2))
        b[n1:, :] = m_inv @ self.force_matrix()
        return a, b

    def state_space(self) -> tuple[np.ndarray, np.ndarray]:
        """Continuous ``(A, B)`` with ``xdot = A x + B [T, e_a]``."""
        a, b = self._state_space
        return a.copy(), b.copy()

    def discretize(self, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """Exact zero-order-hold ``(Ad, Bd)`` for a step ``dt`` (s)."""
        if not np.isfinite(dt) or dt <= 0:
            raise ValueError(f"dt must be a positive finite step in seconds, got {dt!r}")
        a, b = self._state_space
        ns, ni = b.shape
        aug = np.zeros((ns + ni, ns + ni))
        aug[:ns, :ns] = a
        aug[:ns, ns:] = b
        e = expm(aug * dt)
        return e[:ns, :ns], e[:ns, ns:]

    def derivatives(self, t: float, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        a, b = self._state_space
        return a @ x + b @ np.asarray(u, dtype=float)

    def simulate(self, times: np.ndarray, inputs, x0: np.ndarray | None = None) -> np.ndarray:
        """Integrate with ``scipy.integrate.solve_ivp``; ``inputs(t) -> [T, e_a]``.
        Returns states at ``times`` (shape ``len(times) x n_states``)."""
        times = np.asarray(times, dtype=float)
        x0 = np.zeros(self.n_states) if x0 is None else np.asarray(x0, dtype=float)
        sol = solve_ivp(
            lambda t, x: self.derivatives(t, x, inputs(t)),
            (times[0], times[-1]), x0, t_eval=times, rtol=1e-9, atol=1e-12, max_step=0.01,
        )
        if not sol.success:
            raise RuntimeError(sol.message)
        return sol.y.T

    # ----- outputs --------------------------------------------------------------------------
    def split(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``theta, q, thetadot, qdot`` from state(s) (last axis is the state)."""
        x = np.asarray(x)
        n1 = self.n_modes + 1
        return x[..., 0], x[..., 1:n1], x[..., n1], x[..., n1 + 1:]

    def sensor_voltage(self, x: np.ndarray) -> np.ndarray:
        """Sensor patch voltage ``e_s = B^T q / gamma`` (eq 3), V."""
        _, q, _, _ = self.split(x)
        return q @ self.piezo_b / self.gamma

    def vibration_energy(self, x: np.ndarray) -> np.ndarray:
        """Paper's vibration energy ``E = qdot^T qdot + q^T Lambda q`` (N m)."""
        _, q, _, qd = self.split(x)
        return np.sum(qd**2, axis=-1) + np.sum(self.modal_stiffness * q**2, axis=-1)

    def tip_deflection(self, x: np.ndarray) -> np.ndarray:
        """Elastic tip deflection relative to the hub frame, m."""
        _, q, _, _ = self.split(x)
        return q @ self.tip_shape

    def clip_voltage(self, volts: float) -> float:
        lim = self.params.voltage_limit
        return float(min(max(volts, -lim), lim))

    # ----- modal analysis -------------------------------------------------------------------
    def coupled_modes(self) -> tuple[np.ndarray, np.ndarray]:
        """Hub-free (coupled) elastic modes: frequencies (rad/s) and mass-normalised mode
        vectors over ``[theta, q]`` (columns), rigid-body mode removed."""
        m = self.mass_matrix()
        k = self.stiffness_matrix()
        chol = np.linalg.cholesky(m)
        ci = np.linalg.inv(chol)
        evals, evecs = np.linalg.eigh(ci @ k @ ci.T)
        order = np.argsort(evals)
        evals = evals[order][1:]
        vecs = (ci.T @ evecs)[:, order][:, 1:]
        return np.sqrt(np.clip(evals, 0.0, None)), vecs

    def coupled_freqs(self) -> np.ndarray:
        return self.coupled_modes()[0]


class OnOffThrusters:
    """A pair of opposed on-off thrusters: command in {-1, 0, +1} -> torque (N m). Counts
    firings (off -> on transitions, either direction) and accumulated on-time."""

    def __init__(self, torque: float) -> None:
        if not np.isfinite(torque) or torque <= 0:
            raise ValueError(f"torque must be positive (N m), got {torque!r}")
        self.torque = float(torque)
        self.reset()

    def reset(self) -> None:
        self.firings = 0
        self.on_time = 0.0
        self._last = 0

    def step(self, command: float, dt: float) -> float:
        state = int(np.sign(round(float(command))))
        if state != 0 and state != self._last:
            self.firings += 1
        if state != 0:
            self.on_time += dt
        self._last = state
        return state * self.torque


def solve_hub_inertia_and_thickness(
    targets_rad_s: tuple[float, float] = HU2006_TARGET_COUPLED_FREQS_RAD_S,
    base: HubBeamParameters | None = None,
) -> HubBeamParameters:
    """Solve hub inertia and beam thickness so that the first two hub-free frequencies of the
    model equal ``targets_rad_s``; every other parameter is taken from ``base``."""
    base = base or HubBeamParameters()
    target = np.asarray(targets_rad_s, dtype=float)
    if target.shape != (2,) or np.any(target <= 0) or target[1] <= target[0]:
        raise ValueError(
            f"targets_rad_s must be two increasing positive values, got {targets_rad_s}"
        )

    def residual(p: np.ndarray) -> np.ndarray:
        trial = replace(base, hub_inertia=float(np.exp(p[0])), beam_thickness=float(np.exp(p[1])))
        return np.log(Hu2006HubBeam(trial, n_quad=200).coupled_freqs()[:2] / target)

    sol = least_squares(residual, np.log([base.hub_inertia, base.beam_thickness]), xtol=1e-12)
    if np.max(np.abs(sol.fun)) > 1e-6:
        raise RuntimeError("no hub inertia / thickness reproduces the target frequencies")
    hub_inertia, thickness = (float(v) for v in np.exp(sol.x))
    return replace(base, hub_inertia=hub_inertia, beam_thickness=thickness)
