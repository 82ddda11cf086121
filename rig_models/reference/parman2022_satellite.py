"""Flexible satellite of Parman 2022 (seed 002): rigid main body + two clamped plate panels.

The main body is six lumped masses (Table 1). Each solar panel (Table 2: 12 x 2.4 x 0.03 m,
E = 0.6e8 N/m^2, nu = 0.3, rho = 120 kg/m^3) is meshed with 8 x 2 rectangular Kirchhoff plate
elements of 1.5 x 1.2 m: the 12-DOF ACM (Adini-Clough-Melosh, also called MZC) element with
nodal DOFs (w, theta_x = dw/dy, theta_y = -dw/dx) in the element's local frame and the
consistent mass matrix of the same 12-term polynomial. Roots (the 3 nodes at 1.8 m from O_b)
are clamped, so each panel keeps 24 x 3 = 72 DOFs: 144 elastic DOFs in all.

Geometry (body frame O_b X_b Y_b Z_b): the panels lie along +-Y_b; the panel's width
coordinate s in [-1.2, 1.2] m points along u = (cos d, 0, -sin d) and its out-of-plane
normal is n = (sin d, 0, cos d), d = offset angle (30 deg), i.e. the panels are turned by d
about their rotating axis Y_b. A panel point sits at p0 = s u +- (r0 + eta) e_y.

Coupled equations (the paper's eq. 1, generalised coordinates q = [r (3), theta (3), d (144)]):

    [[m U3, Q, W], [Q^T, I, A], [W^T, A^T, M]] q'' + G q' + K q = [F_b, T_b, F_a]

    W = int rho t n N dA,  A = int rho t (p0 x n) N dA,  Q = -int (p0~) dm (zero: O_b is the
    centre of mass),  I = whole-satellite inertia (hub + undeformed panels),
    M, K = assembled plate matrices,  G = [[0, Q w~, 0], [0, I w~, 0], [0, A^T w~, D]],
    w = orbit rate vector (0, -w_o, 0), D = 0 (no structural damping).

The orbit-rate term is written as eq. (1) shows it. As written, G q' = M[:, theta] (w~ theta'),
so it acts on the attitude only: at w_o = 7.29e-5 rad/s it shifts the angles by about
0.01 deg over a one-minute manoeuvre and leaves the panel deflection unchanged.

Nodes of the +Y panel are numbered 1..27 as node = 3 i + j + 1 (i = 0..8 along the span from
the root, j = 0..2 across the width from s = -1.2 m), so node 27 is the tip corner at
s = +1.2 m; the -Y panel holds nodes 28..54 the same way.

This module is physics only: no imports from `harness`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg as sla

# --------------------------------------------------------------------------- plate element

_N_GAUSS = 5  # exact for the degree-8 products in the consistent mass matrix


def _poly(x: float, y: float) -> np.ndarray:
    """The ACM element's 12-term polynomial basis."""
    return np.array(
        [1, x, y, x * x, x * y, y * y, x**3, x * x * y, x * y * y, y**3, x**3 * y, x * y**3],
        dtype=float,
    )


def _poly_dx(x: float, y: float) -> np.ndarray:
    return np.array(
        [0, 1, 0, 2 * x, y, 0, 3 * x * x, 2 * x * y, y * y, 0, 3 * x * x * y, y**3], dtype=float
    )


def _poly_dy(x: float, y: float) -> np.ndarray:
    return np.array(
        [0, 0, 1, 0, x, 2 * y, 0, x * x, 2 * x * y, 3 * y * y, x**3, 3 * x * y * y], dtype=float
    )


def _poly_curvatures(x: float, y: float) -> np.ndarray:
    """Rows: d2/dx2, d2/dy2, 2 d2/dxdy of the basis."""
    wxx = [0, 0, 0, 2, 0, 0, 6 * x, 2 * y, 0, 0, 6 * x * y, 0]
    wyy = [0, 0, 0, 0, 0, 2, 0, 0, 2 * x, 6 * y, 0, 6 * x * y]
    wxy = [0, 0, 0, 0, 1, 0, 0, 2 * x, 2 * y, 0, 3 * x * x, 3 * y * y]
    return np.array([wxx, wyy, [2 * v for v in wxy]], dtype=float)


def _check_positive(name: str, value: float) -> None:
    if not np.isfinite(value) or value <= 0.0:
        raise ValueError(f"{name} must be a positive finite number, got {value!r}")


@dataclass(frozen=True)
class AcmPlateElement:
    """12-DOF rectangular Kirchhoff plate element (ACM/MZC), local frame at node 1.

    Nodes (0,0), (a,0), (a,b), (0,b); DOFs per node (w, theta_x = dw/dy, theta_y = -dw/dx).
    """

    length_x_m: float
    length_y_m: float
    youngs_modulus_pa: float
    poisson_ratio: float
    thickness_m: float
    density_kg_m3: float
    stiffness: np.ndarray = field(init=False, repr=False)
    mass: np.ndarray = field(init=False, repr=False)
    _coeffs: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        _check_positive("length_x_m", self.length_x_m)
        _check_positive("length_y_m", self.length_y_m)
        _check_positive("youngs_modulus_pa", self.youngs_modulus_pa)
        _check_positive("thickness_m", self.thickness_m)
        _check_positive("density_kg_m3", self.density_kg_m3)
        if not 0.0 <= self.poisson_ratio < 0.5:
            raise ValueError(f"poisson_ratio must be in [0, 0.5), got {self.poisson_ratio!r}")
        a, b = self.length_x_m, self.length_y_m
        rows = []
        for x, y in ((0.0, 0.0), (a, 0.0), (a, b), (0.0, b)):
            rows += [_poly(x, y), _poly_dy(x, y), -_poly_dx(x, y)]
        coeffs = np.linalg.inv(np.array(rows))
        nu, t = self.poisson_ratio, self.thickness_m
        rigidity = self.youngs_modulus_pa * t**3 / (12.0 * (1.0 - nu**2))
        d_mat = rigidity * np.array([[1.0, nu, 0.0], [nu, 1.0, 0.0], [0.0, 0.0, (1.0 - nu) / 2]])
        k = np.zeros((12, 12))
        m = np.zeros((12, 12))
        for x, y, w in self.quadrature():
            curv = _poly_curvatures(x, y) @ coeffs
            k += w * curv.T @ d_mat @ curv
            n = self.shape(x, y, coeffs)
            m += w * self.density_kg_m3 * t * np.outer(n, n)
        object.__setattr__(self, "_coeffs", coeffs)
        object.__setattr__(self, "stiffness", 0.5 * (k + k.T))
        object.__setattr__(self, "mass", 0.5 * (m + m.T))

    def quadrature(self) -> list[tuple[float, float, float]]:
        """Gauss points (x, y, weight) over the element."""
        g, wg = np.polynomial.legendre.leggauss(_N_GAUSS)
        a, b = self.length_x_m, self.length_y_m
        return [
            ((gi + 1) * a / 2, (gj + 1) * b / 2, wi * wj * a * b / 4)
            for gi, wi in zip(g, wg, strict=True)
            for gj, wj in zip(g, wg, strict=True)
        ]

    def shape(self, x: float, y: float, coeffs: np.ndarray | None = None) -> np.ndarray:
        """Row of 12 shape functions giving w(x, y) from the element DOFs."""
        return _poly(x, y) @ (self._coeffs if coeffs is None else coeffs)


@dataclass(frozen=True)
class PlateMesh:
    """A rectangular plate of nx x ny ACM elements; node (i, j) has id j * (nx + 1) + i."""

    nx: int
    ny: int
    stiffness: np.ndarray
    mass: np.ndarray

    def node(self, i: int, j: int) -> int:
        return j * (self.nx + 1) + i

    def dofs(self, i: int, j: int) -> tuple[int, int, int]:
        """(w, theta_x, theta_y) DOF indices of node (i, j)."""
        n = 3 * self.node(i, j)
        return n, n + 1, n + 2


def rectangular_plate(
    nx: int,
    ny: int,
    length_x_m: float,
    length_y_m: float,
    *,
    youngs_modulus_pa: float,
    poisson_ratio: float,
    thickness_m: float,
    density_kg_m3: float,
) -> PlateMesh:
    """Assemble a free rectangular plate (apply boundary conditions by deleting DOFs)."""
    if nx < 1 or ny < 1:
        raise ValueError(f"nx and ny must be >= 1, got nx={nx}, ny={ny}")
    elem = AcmPlateElement(
        length_x_m / nx,
        length_y_m / ny,
        youngs_modulus_pa,
        poisson_ratio,
        thickness_m,
        density_kg_m3,
    )
    n_dof = 3 * (nx + 1) * (ny + 1)
    k = np.zeros((n_dof, n_dof))
    m = np.zeros((n_dof, n_dof))
    mesh = PlateMesh(nx, ny, k, m)
    for i in range(nx):
        for j in range(ny):
            idx = np.array(
                [
                    d
                    for ij in ((i, j), (i + 1, j), (i + 1, j + 1), (i, j + 1))
                    for d in mesh.dofs(*ij)
                ]
            )
            k[np.ix_(idx, idx)] += elem.stiffness
            m[np.ix_(idx, idx)] += elem.mass
    return mesh


# --------------------------------------------------------------------------- satellite


@dataclass(frozen=True)
class LumpedMass:
    mass_kg: float
    position_m: tuple[float, float, float]


TABLE1_LUMPED_MASSES: tuple[LumpedMass, ...] = (
    LumpedMass(400.0, (0.4, 0.0, 0.0)),
    LumpedMass(400.0, (-0.4, 0.0, 0.0)),
    LumpedMass(500.0, (0.0, 0.5, 0.0)),
    LumpedMass(500.0, (0.0, -0.5, 0.0)),
    LumpedMass(550.0, (0.0, 0.0, 1.4)),
    LumpedMass(550.0, (0.0, 0.0, -1.4)),
)


@dataclass(frozen=True)
class SatelliteParameters:
    """Inputs of the paper's satellite (Tables 1 and 2); SI units, angles in degrees at the edge."""

    lumped_masses: tuple[LumpedMass, ...] = TABLE1_LUMPED_MASSES
    panel_length_m: float = 12.0
    panel_width_m: float = 2.4
    panel_thickness_m: float = 0.03
    elements_along_span: int = 8
    elements_across_width: int = 2
    poisson_ratio: float = 0.3
    density_kg_m3: float = 120.0
    youngs_modulus_pa: float = 0.6e8
    root_distance_m: float = 1.8
    offset_angle_deg: float = 30.0
    orbit_rate_rad_s: float = 7.29e-5

    def __post_init__(self) -> None:
        for name in (
            "panel_length_m",
            "panel_width_m",
            "panel_thickness_m",
            "density_kg_m3",
            "youngs_modulus_pa",
        ):
            _check_positive(name, getattr(self, name))
        if self.root_distance_m < 0:
            raise ValueError(f"root_distance_m must be >= 0, got {self.root_distance_m!r}")
        if self.elements_along_span < 1 or self.elements_across_width < 1:
            raise ValueError("elements_along_span and elements_across_width must be >= 1")
        if not self.lumped_masses:
            raise ValueError("lumped_masses must hold at least one mass")


@dataclass(frozen=True)
class SatelliteModel:
    """Matrices of eq. (1); q = [r (3), theta (3), elastic d (n_elastic)]."""

    parameters: SatelliteParameters
    mass: np.ndarray
    damping: np.ndarray  # G of eq. (1): orbit-rate terms (D = 0)
    stiffness: np.ndarray
    inertia_kg_m2: np.ndarray  # whole satellite, undeformed
    total_mass_kg: float
    node_positions_m: np.ndarray  # (54, 3) undeformed positions, node k at row k - 1
    node_w_dof: np.ndarray  # (54,) index into q of w at each node, -1 at clamped roots
    normal: np.ndarray  # panel out-of-plane unit normal

    @property
    def n_dof(self) -> int:
        return self.mass.shape[0]

    @property
    def n_elastic(self) -> int:
        return self.n_dof - 6

    def w_dof_of_node(self, node: int) -> int:
        """q index of the local out-of-plane displacement of node 1..54."""
        if not 1 <= node <= len(self.node_w_dof):
            raise ValueError(f"node must be in 1..{len(self.node_w_dof)}, got {node!r}")
        dof = int(self.node_w_dof[node - 1])
        if dof < 0:
            raise ValueError(f"node {node} is a clamped root node (no DOF)")
        return dof

    def natural_frequencies(self) -> tuple[np.ndarray, np.ndarray]:
        """Undamped elastic frequencies (rad/s, ascending) and mass-normalised mode shapes.

        The six rigid-body modes are removed (the orbit-rate term is ignored here).
        """
        w2, vecs = sla.eigh(self.stiffness, self.mass)
        order = np.argsort(w2)[6:]
        return np.sqrt(np.clip(w2[order], 0.0, None)), vecs[:, order]

    def roll_yaw_frequencies(self, threshold: float = 1e-3) -> np.ndarray:
        """Elastic frequencies whose modes a roll or yaw torque excites (rad/s, ascending).

        A mode counts when the roll or yaw component of its mass-normalised shape exceeds
        `threshold` times the largest such component over all modes.
        """
        omega, vecs = self.natural_frequencies()
        rot = np.hypot(vecs[3, :], vecs[5, :])
        return omega[rot > threshold * rot.max()]


def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def build_satellite(params: SatelliteParameters | None = None) -> SatelliteModel:
    """Assemble eq. (1) for the satellite described by `params` (defaults: the paper's)."""
    p = params or SatelliteParameters()
    nx, ny = p.elements_along_span, p.elements_across_width
    ex, ey = p.panel_length_m / nx, p.panel_width_m / ny
    elem = AcmPlateElement(
        ex, ey, p.youngs_modulus_pa, p.poisson_ratio, p.panel_thickness_m, p.density_kg_m3
    )
    delta = np.radians(p.offset_angle_deg)
    u = np.array([np.cos(delta), 0.0, -np.sin(delta)])
    normal = np.array([np.sin(delta), 0.0, np.cos(delta)])
    e_y = np.array([0.0, 1.0, 0.0])
    nodes_per_panel = (nx + 1) * (ny + 1)
    free_per_panel = 3 * nx * (ny + 1)
    n_el = 2 * free_per_panel
    n = 6 + n_el
    m_ee = np.zeros((n_el, n_el))
    k_ee = np.zeros((n_el, n_el))
    w_mat = np.zeros((3, n_el))
    a_mat = np.zeros((3, n_el))
    i_panels = np.zeros((3, 3))
    first_moment = np.zeros(3)
    m_panels = 0.0
    positions = np.zeros((2 * nodes_per_panel, 3))
    w_dof = -np.ones(2 * nodes_per_panel, dtype=int)
    rho_t = p.density_kg_m3 * p.panel_thickness_m
    half_w = p.panel_width_m / 2

    for side, sign in enumerate((1.0, -1.0)):

        def point(eta: float, s: float, sign: float = sign) -> np.ndarray:
            return s * u + sign * (p.root_distance_m + eta) * e_y

        def node_base(i: int, j: int, side: int = side) -> int | None:
            """First q index (w) of span station i, width station j; None at the root."""
            if i == 0:
                return None
            return 6 + side * free_per_panel + 3 * ((i - 1) * (ny + 1) + j)

        for i in range(nx + 1):
            for j in range(ny + 1):
                k_node = side * nodes_per_panel + i * (ny + 1) + j
                positions[k_node] = point(i * ex, -half_w + j * ey)
                base = node_base(i, j)
                w_dof[k_node] = -1 if base is None else base
        for i in range(nx):
            for j in range(ny):
                corners = ((i, j), (i + 1, j), (i + 1, j + 1), (i, j + 1))
                q_idx: list[int] = []
                e_idx: list[int] = []
                for c, (ci, cj) in enumerate(corners):
                    base = node_base(ci, cj)
                    if base is not None:
                        q_idx += [base - 6, base - 5, base - 4]
                        e_idx += [3 * c, 3 * c + 1, 3 * c + 2]
                qi, ei = np.array(q_idx), np.array(e_idx)
                k_ee[np.ix_(qi, qi)] += elem.stiffness[np.ix_(ei, ei)]
                m_ee[np.ix_(qi, qi)] += elem.mass[np.ix_(ei, ei)]
                for x, y, wq in elem.quadrature():
                    dm = rho_t * wq
                    p0 = point(i * ex + x, -half_w + j * ey + y)
                    shp = elem.shape(x, y)[ei]
                    w_mat[:, qi] += dm * np.outer(normal, shp)
                    a_mat[:, qi] += dm * np.outer(np.cross(p0, normal), shp)
                    i_panels += dm * (p0 @ p0 * np.eye(3) - np.outer(p0, p0))
                    first_moment += dm * p0
                    m_panels += dm

    i_hub = np.zeros((3, 3))
    m_hub = 0.0
    for lm in p.lumped_masses:
        r = np.asarray(lm.position_m, dtype=float)
        i_hub += lm.mass_kg * (r @ r * np.eye(3) - np.outer(r, r))
        first_moment += lm.mass_kg * r
        m_hub += lm.mass_kg
    inertia = i_hub + i_panels
    total = m_hub + m_panels
    q_mat = -_skew(first_moment)  # -int p0~ dm; zero when O_b is the centre of mass

    mass = np.zeros((n, n))
    mass[:3, :3] = total * np.eye(3)
    mass[:3, 3:6] = q_mat
    mass[3:6, :3] = q_mat.T
    mass[3:6, 3:6] = inertia
    mass[:3, 6:] = w_mat
    mass[6:, :3] = w_mat.T
    mass[3:6, 6:] = a_mat
    mass[6:, 3:6] = a_mat.T
    mass[6:, 6:] = m_ee
    mass = 0.5 * (mass + mass.T)
    stiffness = np.zeros((n, n))
    stiffness[6:, 6:] = 0.5 * (k_ee + k_ee.T)
    w_orbit = _skew(np.array([0.0, -p.orbit_rate_rad_s, 0.0]))
    damping = np.zeros((n, n))
    damping[:3, 3:6] = q_mat @ w_orbit
    damping[3:6, 3:6] = inertia @ w_orbit
    damping[6:, 3:6] = a_mat.T @ w_orbit
    return SatelliteModel(
        parameters=p,
        mass=mass,
        damping=damping,
        stiffness=stiffness,
        inertia_kg_m2=inertia,
        total_mass_kg=total,
        node_positions_m=positions,
        node_w_dof=w_dof,
        normal=normal,
    )


# --------------------------------------------------------------------------- simulation


@dataclass(frozen=True)
class TorqueSchedule:
    """Piecewise-constant body torque: `torques_n_m[k]` acts from `times_s[k]` to the next
    time (the last one until the end of the run)."""

    times_s: np.ndarray
    torques_n_m: np.ndarray  # (k, 3) roll, pitch, yaw

    def __post_init__(self) -> None:
        t = np.asarray(self.times_s, dtype=float)
        tq = np.asarray(self.torques_n_m, dtype=float)
        if t.ndim != 1 or tq.shape != (len(t), 3):
            raise ValueError("torques_n_m must have shape (len(times_s), 3)")
        if len(t) and np.any(np.diff(t) <= 0):
            raise ValueError("times_s must be strictly increasing")
        object.__setattr__(self, "times_s", t)
        object.__setattr__(self, "torques_n_m", tq)

    @classmethod
    def from_impulses(
        cls, axes: Sequence[tuple[Sequence[float], Sequence[float]]], torque_n_m: float
    ) -> TorqueSchedule:
        """Torque on each of the three axes = torque_n_m * sum_i A_i step(t - t_i).

        `axes` holds (times_s, amplitudes) for roll, pitch and yaw.
        """
        if len(axes) != 3:
            raise ValueError("axes must hold (times_s, amplitudes) for roll, pitch and yaw")
        events = np.unique(np.concatenate([np.asarray(t, dtype=float) for t, _ in axes] + [[0.0]]))
        levels = np.zeros((len(events), 3))
        for k, (times, amps) in enumerate(axes):
            times = np.asarray(times, dtype=float)
            amps = np.asarray(amps, dtype=float)
            if times.shape != amps.shape:
                raise ValueError(f"axis {k}: times and amplitudes differ in length")
            for t_i, a_i in zip(times, amps, strict=True):
                levels[events >= t_i - 1e-12, k] += a_i
        return cls(events, torque_n_m * levels)

    def at(self, t: float) -> np.ndarray:
        k = int(self.level_index(t))
        return np.zeros(3) if k < 0 else self.torques_n_m[k]

    def level_index(self, t: np.ndarray) -> np.ndarray:
        """Row of `torques_n_m` acting at each of the times t (-1: before the first time)."""
        return np.searchsorted(self.times_s, np.asarray(t, dtype=float), side="right") - 1

    def at_times(self, t: np.ndarray) -> np.ndarray:
        """`at` for each of the times t: shape (len(t), 3)."""
        k = self.level_index(t)
        out = np.zeros((k.size, 3))
        out[k >= 0] = self.torques_n_m[k[k >= 0]]
        return out


@dataclass(frozen=True)
class SimulationResult:
    time_s: np.ndarray
    q: np.ndarray  # (n_t, n_dof)
    qdot: np.ndarray

    def attitude_rad(self) -> np.ndarray:
        """(n_t, 3) roll, pitch, yaw (small-angle Bryant angles)."""
        return self.q[:, 3:6]


class Discretisation:
    """Exact zero-order-hold transition of one model's eq. (1): (Phi, Gamma) over dt with
    x(t + dt) = Phi x(t) + Gamma T for a torque T held over dt (matrix exponential).

    Each distinct dt is computed once and kept (up to `max_kept`, least recently used
    dropped): runs of the same model that share switch times (a study's cases) reuse the
    same matrices instead of recomputing them, so their results are the same bit for bit.
    """

    def __init__(self, model: SatelliteModel, max_kept: int = 64) -> None:
        n = model.n_dof
        m_inv = np.linalg.inv(model.mass)
        a = np.zeros((2 * n, 2 * n))
        a[:n, n:] = np.eye(n)
        a[n:, :n] = -m_inv @ model.stiffness
        a[n:, n:] = -m_inv @ model.damping
        b = np.zeros((2 * n, 3))
        b[n:, :] = m_inv[:, 3:6]
        self.model = model
        self._a, self._b = a, b
        self._max_kept = max_kept
        self._kept: dict[float, tuple[np.ndarray, np.ndarray]] = {}

    def __call__(self, dt: float) -> tuple[np.ndarray, np.ndarray]:
        dt = float(dt)
        hit = self._kept.pop(dt, None)
        if hit is None:
            n2 = self._a.shape[0]
            aug = np.zeros((n2 + 3, n2 + 3))
            aug[:n2, :n2] = self._a * dt
            aug[:n2, n2:] = self._b * dt
            e = sla.expm(aug)
            hit = (e[:n2, :n2], e[:n2, n2:])
            for m in hit:
                m.setflags(write=False)
            if len(self._kept) >= self._max_kept:
                del self._kept[next(iter(self._kept))]
        self._kept[dt] = hit  # most recently used last
        return hit


def simulate(
    model: SatelliteModel,
    schedule: TorqueSchedule,
    *,
    duration_s: float,
    step_s: float,
    initial_attitude_rad: Sequence[float] = (0.0, 0.0, 0.0),
    discretisation: Discretisation | None = None,
) -> SimulationResult:
    """Exact response of eq. (1) to a piecewise-constant torque, sampled every `step_s`.

    Starts at rest, undeformed, at `initial_attitude_rad`. Torque switches that fall between
    samples are integrated exactly (matrix exponential over each sub-interval).
    `discretisation` (of this model) lets several runs share the matrix exponentials.
    """
    _check_positive("duration_s", duration_s)
    _check_positive("step_s", step_s)
    if discretisation is None:
        discretisation = Discretisation(model)
    elif discretisation.model is not model:
        raise ValueError("discretisation belongs to another model")
    n = model.n_dof

    n_steps = int(round(duration_s / step_s))
    times = np.arange(n_steps + 1) * step_s
    phi, gam = discretisation(step_s)
    x = np.zeros(2 * n)
    x[3:6] = np.asarray(initial_attitude_rad, dtype=float)
    out = np.empty((n_steps + 1, 2 * n))
    out[0] = x
    switches = schedule.times_s
    # per step: the switches strictly inside it (t0 + 1e-12 < ts < t1 - 1e-12; the times are
    # increasing) and the torque at its start, looked up for all steps at once
    first = np.searchsorted(switches, times[:-1] + 1e-12, side="right")
    last = np.searchsorted(switches, times[1:] - 1e-12, side="left")
    level = schedule.level_index(times[:-1])
    zero = np.zeros(3)
    for k in range(n_steps):
        if first[k] >= last[k]:
            x = phi @ x + gam @ (schedule.torques_n_m[level[k]] if level[k] >= 0 else zero)
        else:
            t = times[k]
            for ts in [*switches[first[k] : last[k]], times[k + 1]]:
                ph, gm = discretisation(ts - t)
                x = ph @ x + gm @ schedule.at(t)
                t = ts
        out[k + 1] = x
    return SimulationResult(times, out[:, :n], out[:, n:])
