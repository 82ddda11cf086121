"""Euler-Bernoulli cantilever beam clamped to a rotating hub, by Hermite finite elements.

The beam lies along x from the hub edge (x = 0, clamped, at radius ``hub_radius_m`` from the
rotation axis) to the tip (x = L). Each node carries the transverse deflection w and the slope
w'. The constrained (clamped-root) modes are mass-normalised, so that with the modal
coordinates eta the hub-beam equations are those of the SGSRT paper (003, eq. 4):

    J theta'' + delta eta''                 = T
    delta^T theta'' + eta'' + C eta' + K eta = 0

where ``delta_i = phi_i^T M r`` couples the rigid rotation (r = distance to the axis for the
deflection dofs, 1 for the slope dofs) to mode i. Nothing here knows about CAN or the harness.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla


@dataclass(frozen=True)
class BeamSpec:
    """Geometry and material of a uniform beam (SI units)."""

    length_m: float
    width_m: float
    thickness_m: float
    youngs_modulus_pa: float
    density_kg_m3: float
    hub_radius_m: float
    tip_mass_kg: float = 0.0
    n_elements: int = 40

    def __post_init__(self) -> None:
        for name in ("length_m", "width_m", "thickness_m", "youngs_modulus_pa", "density_kg_m3"):
            if not getattr(self, name) > 0:
                raise ValueError(f"beam.{name} must be > 0, got {getattr(self, name)!r}")
        if self.hub_radius_m < 0:
            raise ValueError(f"beam.hub_radius_m must be >= 0, got {self.hub_radius_m!r}")
        if self.tip_mass_kg < 0:
            raise ValueError(f"beam.tip_mass_kg must be >= 0, got {self.tip_mass_kg!r}")
        if self.n_elements < 2:
            raise ValueError(f"beam.n_elements must be >= 2, got {self.n_elements!r}")

    @property
    def area_m2(self) -> float:
        return self.width_m * self.thickness_m

    @property
    def second_moment_m4(self) -> float:
        return self.width_m * self.thickness_m**3 / 12.0

    @property
    def mass_kg(self) -> float:
        return self.density_kg_m3 * self.area_m2 * self.length_m


@dataclass(frozen=True)
class BeamModes:
    """Clamped-root modes of the beam and their coupling to the hub rotation."""

    omega_rad_s: np.ndarray  # constrained natural frequencies, shape (n,)
    coupling_kg_m: np.ndarray  # delta_i = phi_i^T M r, shape (n,)
    tip_deflection: np.ndarray  # phi_i(L): tip deflection per unit modal coordinate, (n,)
    rigid_inertia_kg_m2: float  # r^T M r: inertia of the undeformed beam about the axis
    node_x_m: np.ndarray  # node positions from the root, (n_elements + 1,)
    shapes: np.ndarray  # mode shapes on the free dofs [w1, w1', w2, ...], (2 n_el, n)
    stiffness: np.ndarray  # free-dof stiffness matrix (for curvature/strain recovery)
    mass: np.ndarray  # free-dof mass matrix

    def curvature_at(self, x_m: float) -> np.ndarray:
        """w''(x) of each mode at position x from the root (1/m per unit modal coordinate)."""
        n_el = len(self.node_x_m) - 1
        le = self.node_x_m[1] - self.node_x_m[0]
        e = min(int(x_m / le), n_el - 1)
        xi = (x_m - e * le) / le
        # second derivatives of the Hermite shape functions with respect to x
        d2 = np.array([(-6 + 12 * xi), le * (-4 + 6 * xi), (6 - 12 * xi), le * (-2 + 6 * xi)])
        d2 /= le**2
        dofs = _element_dofs(e)
        values = np.zeros((4, self.shapes.shape[1]))
        for k, d in enumerate(dofs):
            if d >= 0:
                values[k] = self.shapes[d]
        return d2 @ values


def _element_dofs(e: int) -> list[int]:
    """Free-dof indices of element e (the root node's dofs are clamped: -1)."""
    first = 2 * (e - 1)
    return [first, first + 1, first + 2, first + 3] if e > 0 else [-1, -1, 0, 1]


def assemble(spec: BeamSpec) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Mass and stiffness over ALL dofs (root node first: w0, w0', w1, w1', ...), the
    rigid-rotation vector r (distance to the axis for w, 1 for slopes) and node positions."""
    n_el = spec.n_elements
    le = spec.length_m / n_el
    ei = spec.youngs_modulus_pa * spec.second_moment_m4
    rho_a = spec.density_kg_m3 * spec.area_m2
    ke = (ei / le**3) * np.array(
        [
            [12, 6 * le, -12, 6 * le],
            [6 * le, 4 * le**2, -6 * le, 2 * le**2],
            [-12, -6 * le, 12, -6 * le],
            [6 * le, 2 * le**2, -6 * le, 4 * le**2],
        ]
    )
    me = (rho_a * le / 420.0) * np.array(
        [
            [156, 22 * le, 54, -13 * le],
            [22 * le, 4 * le**2, 13 * le, -3 * le**2],
            [54, 13 * le, 156, -22 * le],
            [-13 * le, -3 * le**2, -22 * le, 4 * le**2],
        ]
    )
    n_all = 2 * (n_el + 1)
    k = np.zeros((n_all, n_all))
    m = np.zeros((n_all, n_all))
    for e in range(n_el):
        sl = slice(2 * e, 2 * e + 4)
        k[sl, sl] += ke
        m[sl, sl] += me
    m[n_all - 2, n_all - 2] += spec.tip_mass_kg
    x = np.linspace(0.0, spec.length_m, n_el + 1)
    r = np.zeros(n_all)
    r[0::2] = spec.hub_radius_m + x
    r[1::2] = 1.0
    return m, k, r, x


def beam_modes(spec: BeamSpec, n_modes: int) -> BeamModes:
    """The first ``n_modes`` clamped-root modes, mass-normalised, and the hub coupling."""
    if not 1 <= n_modes <= spec.n_elements:
        raise ValueError(f"n_modes must be in 1..{spec.n_elements}, got {n_modes}")
    m_all, k_all, r, x = assemble(spec)
    free = slice(2, None)  # the root node is clamped to the hub
    m, k = m_all[free, free], k_all[free, free]
    omega2, phi = sla.eigh(k, m, subset_by_index=[0, n_modes - 1])
    phi = phi / np.sqrt(np.einsum("ij,ik,kj->j", phi, m, phi))
    signs = np.sign(phi[-2])  # convention: positive tip deflection
    signs[signs == 0] = 1.0
    phi = phi * signs
    return BeamModes(
        omega_rad_s=np.sqrt(omega2),
        coupling_kg_m=phi.T @ (m_all[free, :] @ r),
        tip_deflection=phi[-2].copy(),
        rigid_inertia_kg_m2=float(r @ m_all @ r),
        node_x_m=x,
        shapes=phi,
        stiffness=k,
        mass=m,
    )


def cantilever_omega_exact(spec: BeamSpec, n_modes: int) -> np.ndarray:
    """Closed-form clamped-free frequencies (no tip mass), for checking the elements."""
    roots = []
    for guess in (1.875, 4.694, 7.855, 10.996, 14.137, 17.279):
        from scipy.optimize import brentq

        roots.append(
            brentq(lambda b: np.cos(b) * np.cosh(b) + 1.0, guess - 0.3, guess + 0.3)
        )
    while len(roots) < n_modes:
        roots.append((2 * len(roots) + 1) * np.pi / 2)
    beta = np.array(roots[:n_modes]) / spec.length_m
    ei = spec.youngs_modulus_pa * spec.second_moment_m4
    rho_a = spec.density_kg_m3 * spec.area_m2
    return beta**2 * np.sqrt(ei / rho_a)
