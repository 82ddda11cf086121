"""Two-constant-amplitude fuel-efficient shapers LHHL and HLLH (Parman 2022, eqs 6-13).

A shaper is a sequence of eight impulses (amplitudes in units of the high torque T, the low
level being T/2) convolved with a step: the torque is T * sum_i A_i step(t - t_i).

    LHHL: A = [0.5, -0.5, 1, -1, -1, 1, -0.5, 0.5]          (eq 6)
    HLLH: A = [1, -1, 0.5, -0.5, -0.5, 0.5, -1, 1]          (eq 12)

Times are symmetric (eq 7): t1 = 0, t3 = t2 + b, t4 = t3 + c, t5 = t4 + 2d, t6 = t5 + c,
t7 = t6 + b, t8 = t7 + t2, so the manoeuvre ends at rest. With a = T / I the rigid-body
angle is (eqs 8 and 13, written for first/second pulse levels p1, p2)

    theta = 2 a [p1 t2^2 / 2 + p1 t2 (b + c) + p2 c^2 / 2 + (p1 t2 + p2 c) d].

The residual vibration at w, relative to the bang-bang manoeuvre of the same angle (eqs 9-10;
bang-bang impulses [1, -2, 1] at 0, tau, 2 tau with a tau^2 = theta), is

    V(w) = |sum_i A_i exp(j w t_i)| / |1 - 2 exp(j w tau) + exp(2 j w tau)|  (x 100 %).

`design_two_amplitude` finds the shortest t8 meeting V(w_k) <= Vmax_k for every given mode.
The problem is not convex. It is solved in the distances of the impulses from the centre,
x = (t8/2, b + c + d, c + d, d): the objective is linear, the angle equation a quadric and
every residual a sum of four cosines (see `_Problem`). Search:
  1. multi-start: SLSQP from a scrambled Sobol set of starts over the ordered box
     t8/2 >= x2 >= x3 >= x4 >= 0 (t8 <= max_t8_s), analytic gradients, then a Newton
     projection onto any limit missed by round-off;
  2. an independent dense scan of t8 upwards from the bang-bang duration: for each t8 a grid
     over (x2, x4) with x3 from the angle equation; the tightest mode is treated as an
     equality located by sign changes between grid points and the other limits are checked
     at the interpolated crossing. Its first feasible t8 is reported, and the points found
     there are polished by SLSQP and adopted if better than the multi-start result.
`SearchReport` says how many starts reached the returned optimum and where the scan first
found a feasible point. When the scan saw nothing feasible below the returned t8
(`grid_consistent`), that t8 is the global minimum to the scan's resolution (a feasible
region thinner than one grid cell could still be missed by the scan, not by construction).

`evaluate_sequence` reports the same quantities for any given impulse sequence.
All functions are pure (no I/O).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from functools import cached_property
from typing import Literal

import numpy as np
from scipy.optimize import minimize

ShaperKind = Literal["LHHL", "HLLH"]
LOW_FRACTION = 0.5  # the low torque level as a fraction of the high one
# (first pulse level p1, second pulse level p2) of the accelerating half
_LEVELS: dict[str, tuple[float, float]] = {
    "LHHL": (LOW_FRACTION, 1.0),
    "HLLH": (1.0, LOW_FRACTION),
}


# --------------------------------------------------------------------------- inputs


@dataclass(frozen=True)
class ModeConstraint:
    """A mode to suppress: V(freq_rad_s) <= vmax_percent."""

    freq_rad_s: float
    vmax_percent: float

    def __post_init__(self) -> None:
        if not math.isfinite(self.freq_rad_s) or self.freq_rad_s <= 0:
            raise ValueError(f"freq_rad_s must be positive, got {self.freq_rad_s!r}")
        if not math.isfinite(self.vmax_percent) or self.vmax_percent <= 0:
            raise ValueError(f"vmax_percent must be positive, got {self.vmax_percent!r}")

    @classmethod
    def parse(cls, text: str) -> ModeConstraint:
        """'FREQ_RAD_S:VMAX_PERCENT', e.g. '0.3354:0.001'."""
        parts = text.split(":")
        if len(parts) != 2:
            raise ValueError(f"mode must be FREQ_RAD_S:VMAX_PERCENT, got {text!r}")
        try:
            return cls(float(parts[0]), float(parts[1]))
        except ValueError as exc:
            raise ValueError(f"mode {text!r}: {exc}") from exc


def _positive(name: str, value: float) -> float:
    value = float(value)
    if not math.isfinite(value) or value <= 0:
        raise ValueError(f"{name} must be a positive finite number, got {value!r}")
    return value


def shaper_amplitudes(kind: ShaperKind) -> tuple[float, ...]:
    """The eight impulse amplitudes (units of T) of eq. 6 (LHHL) or eq. 12 (HLLH)."""
    p1, p2 = _levels(kind)
    return (p1, -p1, p2, -p2, -p2, p2, -p1, p1)


def _levels(kind: str) -> tuple[float, float]:
    try:
        return _LEVELS[kind.upper()]
    except KeyError:
        raise ValueError(f"kind must be 'LHHL' or 'HLLH', got {kind!r}") from None


def symmetric_times(t2: float, b: float, c: float, d: float) -> tuple[float, ...]:
    """t1..t8 of eq. 7."""
    t3 = t2 + b
    t4 = t3 + c
    t5 = t4 + 2 * d
    t6 = t5 + c
    t7 = t6 + b
    return (0.0, t2, t3, t4, t5, t6, t7, t7 + t2)


def shaper_angle_rad(
    kind: ShaperKind, t2: float, b: float, c: float, d: float, accel_rad_s2: float
) -> float:
    """Rigid-body rotation of eq. 8 (LHHL) / eq. 13 (HLLH); accel = T / I."""
    p1, p2 = _levels(kind)
    half = p1 * t2**2 / 2 + p1 * t2 * (b + c) + p2 * c**2 / 2 + (p1 * t2 + p2 * c) * d
    return 2 * accel_rad_s2 * half


# --------------------------------------------------------------------------- evaluator


@dataclass(frozen=True)
class SequenceReport:
    """What a torque sequence T * sum A_i step(t - t_i) does to a rigid axis and its modes."""

    times_s: tuple[float, ...]
    amplitudes: tuple[float, ...]  # units of the high torque
    torque_n_m: float
    inertia_kg_m2: float
    angle_rad: float  # rigid-body rotation once the torque has ended
    final_rate_rad_s: float
    reference_angle_rad: float  # angle of the bang-bang reference of eq. 10
    bang_bang_duration_s: float
    mode_freqs_rad_s: tuple[float, ...]
    residual_percent: tuple[float, ...]  # V(w) of eq. 9 at each mode
    vmax_percent: tuple[float, ...] | None
    t8_s: float  # last impulse time minus first
    fuel_on_time_s: float  # time with any torque on
    high_on_time_s: float  # time at |torque| = T
    low_on_time_s: float  # time at 0 < |torque| < T
    impulse_n_m_s: float  # integral of |torque| dt

    @property
    def constraints_met(self) -> bool:
        if self.vmax_percent is None:
            return True
        return all(v <= vm for v, vm in zip(self.residual_percent, self.vmax_percent, strict=True))

    def to_dict(self) -> dict:
        out = asdict(self)
        out["constraints_met"] = self.constraints_met
        return out


def bang_bang_half_time_s(angle_rad: float, inertia_kg_m2: float, torque_n_m: float) -> float:
    """tau with (T / I) tau^2 = |angle|: the bang-bang switch time (eq. 10)."""
    return math.sqrt(abs(angle_rad) * inertia_kg_m2 / torque_n_m)


def _bang_bang_magnitude(freq: np.ndarray, tau: float) -> np.ndarray:
    """|1 - 2 e^{j w tau} + e^{2 j w tau}| = 4 sin^2(w tau / 2)."""
    return 4.0 * np.sin(freq * tau / 2.0) ** 2


def evaluate_sequence(
    times_s: Sequence[float],
    amplitudes: Sequence[float],
    *,
    inertia_kg_m2: float,
    torque_n_m: float,
    freqs_rad_s: Sequence[float] = (),
    vmax_percent: Sequence[float] | None = None,
    reference_angle_rad: float | None = None,
) -> SequenceReport:
    """Evaluate any impulse sequence (amplitudes in units of T; they must sum to zero).

    V(w) is taken against the bang-bang manoeuvre of `reference_angle_rad` (default: the
    angle the sequence itself produces).
    """
    t = np.asarray(times_s, dtype=float)
    amp = np.asarray(amplitudes, dtype=float)
    if t.ndim != 1 or t.size < 2 or t.shape != amp.shape:
        raise ValueError("times_s and amplitudes must be 1-D, of equal length >= 2")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(amp))):
        raise ValueError("times_s and amplitudes must be finite")
    if np.any(np.diff(t) < 0):
        raise ValueError("times_s must be non-decreasing")
    if abs(amp.sum()) > 1e-9:
        raise ValueError(f"amplitudes must sum to zero (torque off at the end), sum={amp.sum()}")
    inertia = _positive("inertia_kg_m2", inertia_kg_m2)
    torque = _positive("torque_n_m", torque_n_m)
    freqs = np.asarray(freqs_rad_s, dtype=float)
    if np.any(~np.isfinite(freqs)) or np.any(freqs <= 0):
        raise ValueError("freqs_rad_s must be positive")
    if vmax_percent is not None and len(vmax_percent) != len(freqs):
        raise ValueError("vmax_percent must give one limit per frequency")
    accel = torque / inertia
    t_end = float(t[-1])
    angle = float(accel * np.sum(amp * (t_end - t) ** 2) / 2)
    rate = float(accel * np.sum(amp * (t_end - t)))
    ref = angle if reference_angle_rad is None else float(reference_angle_rad)
    if ref == 0:
        raise ValueError("reference_angle_rad must be non-zero (the sequence produces no angle)")
    tau = bang_bang_half_time_s(ref, inertia, torque)
    den = _bang_bang_magnitude(freqs, tau)
    if np.any(den < 1e-12):
        raise ValueError("a mode frequency makes the bang-bang reference vanish (w tau = 2 k pi)")
    num = np.abs(np.exp(1j * np.outer(freqs, t)) @ amp)
    v = 100.0 * num / den if freqs.size else np.zeros(0)
    # torque levels between impulses
    levels = np.cumsum(amp)[:-1]
    dur = np.diff(t)
    on = np.abs(levels) > 1e-9
    high = np.abs(np.abs(levels) - 1.0) < 1e-9
    return SequenceReport(
        times_s=tuple(float(x) for x in t),
        amplitudes=tuple(float(x) for x in amp),
        torque_n_m=torque,
        inertia_kg_m2=inertia,
        angle_rad=angle,
        final_rate_rad_s=rate,
        reference_angle_rad=ref,
        bang_bang_duration_s=2 * tau,
        mode_freqs_rad_s=tuple(float(x) for x in freqs),
        residual_percent=tuple(float(x) for x in v),
        vmax_percent=None if vmax_percent is None else tuple(float(x) for x in vmax_percent),
        t8_s=float(t[-1] - t[0]),
        fuel_on_time_s=float(dur[on].sum()),
        high_on_time_s=float(dur[high].sum()),
        low_on_time_s=float(dur[on & ~high].sum()),
        impulse_n_m_s=float(torque * np.sum(np.abs(levels) * dur)),
    )


# --------------------------------------------------------------------------- solver


@dataclass(frozen=True)
class SearchReport:
    """How the global minimum was searched for and how well the searches agree."""

    n_starts: int
    n_feasible: int  # multi-start local optima that met every constraint
    n_agree: int  # of those, how many are within agree_tol_s of the returned t8
    agree_tol_s: float
    distinct_minima_s: tuple[float, ...]  # t8 of the distinct local optima found (<= 8)
    grid_t8_s: float | None  # smallest t8 with a grid-feasible point (None: none found)
    grid_step_t8_s: float  # the scan's step in t8
    grid_points: int  # (x2, x4) points per t8 level
    improved_by_grid: bool  # the scan found a better basin than the multi-start
    grid_consistent: bool  # the scan found nothing feasible below t8 - one step
    max_t8_s: float  # the searched box: t8 <= max_t8_s


@dataclass(frozen=True)
class TwoAmplitudeDesign:
    """Shortest LHHL / HLLH sequence found; times in s, amplitudes in units of T (signed)."""

    kind: str
    t2_s: float
    b_s: float
    c_s: float
    d_s: float
    times_s: tuple[float, ...]
    amplitudes: tuple[float, ...]
    mode_freqs_rad_s: tuple[float, ...]
    residual_percent: tuple[float, ...]
    vmax_percent: tuple[float, ...]
    t8_s: float
    fuel_on_time_s: float
    impulse_n_m_s: float
    report: SequenceReport
    search: SearchReport

    @property
    def constraints_met(self) -> bool:
        return self.report.constraints_met

    def to_dict(self) -> dict:
        out = asdict(self)
        out["report"] = self.report.to_dict()
        out["constraints_met"] = self.constraints_met
        return out


# The search works with the distances of the first four impulses from the centre t8 / 2:
#   x1 = t8/2 = t2 + b + c + d,  x2 = b + c + d,  x3 = c + d,  x4 = d,
# so x1 >= x2 >= x3 >= x4 >= 0, the objective is x1, the angle equation is the quadric
#   p1 (x1^2 - x2^2) + p2 (x3^2 - x4^2) = theta / a,
# and for the symmetric sequence sum A_i exp(j w t_i) = exp(j w x1) R(w) with the real
#   R(w) = 2 [p1 cos w x1 - p1 cos w x2 + p2 cos w x3 - p2 cos w x4],
# whose gradient is bounded by 2 w p: every residual limit is equally well conditioned.


@dataclass(frozen=True)
class _Problem:
    p1: float
    p2: float
    theta_a: float  # theta / a, s^2
    omegas: np.ndarray
    tols: np.ndarray  # limit on |R_k|
    min_pulse_s: float

    @cached_property
    def weights(self) -> np.ndarray:
        return np.array([self.p1, -self.p1, self.p2, -self.p2])

    def residuals(self, x: np.ndarray) -> np.ndarray:
        """R_k for x of shape (4, ...) -> (n_modes, ...)."""
        x = np.asarray(x)
        wts = self.weights
        # the four terms summed left to right from 0, in the order sum() over them takes
        if x.ndim == 1:  # one point (the local solver's): the 4 x n_modes cosines in one call
            t = wts * np.cos(np.multiply.outer(self.omegas, x))
            return 2 * ((((0 + t[:, 0]) + t[:, 1]) + t[:, 2]) + t[:, 3])
        w = self.omegas.reshape((-1,) + (1,) * (x.ndim - 1))
        return _four_terms(wts, w, x[0], x[1], x[2], x[3])

    def residual_jac(self, x: np.ndarray) -> np.ndarray:
        return -2 * self.omegas[:, None] * self.weights[None, :] * np.sin(np.outer(self.omegas, x))

    def angle_gap(self, x: np.ndarray) -> float:
        """Angle equation residual in s^2 (zero when the manoeuvre has the wanted angle)."""
        return self.p1 * (x[0] ** 2 - x[1] ** 2) + self.p2 * (x[2] ** 2 - x[3] ** 2) - self.theta_a

    def angle_grad(self, x: np.ndarray) -> np.ndarray:
        return 2 * np.array([self.p1 * x[0], -self.p1 * x[1], self.p2 * x[2], -self.p2 * x[3]])

    def feasible(self, x: np.ndarray) -> bool:
        t2, b, c, d = x[0] - x[1], x[1] - x[2], x[2] - x[3], x[3]
        if min(t2, c) < self.min_pulse_s or min(b, d) < 0:
            return False
        if abs(self.angle_gap(x)) > 1e-9 * self.theta_a:
            return False
        return bool(np.all(np.abs(self.residuals(x)) <= self.tols))


_ORDER = np.array([[1.0, -1, 0, 0], [0, 1, -1, 0], [0, 0, 1, -1], [0, 0, 0, 1]])


def _margins(prob: _Problem, x: np.ndarray, lo: np.ndarray, gscale: np.ndarray) -> np.ndarray:
    """The inequalities, >= 0 when met: the order of the impulses (_ORDER @ x >= lo), then
    (tol_k - R_k, tol_k + R_k) / gscale_k (R_k once). One function for SLSQP, which stacks
    its inequality functions' outputs in the same rows."""
    r = prob.residuals(x)
    return np.concatenate([_ORDER @ x - lo, (prob.tols - r) / gscale, (prob.tols + r) / gscale])


def _margins_jac(prob: _Problem, x: np.ndarray, gscale: np.ndarray) -> np.ndarray:
    jac = prob.residual_jac(x)
    return np.vstack([_ORDER, -jac / gscale[:, None], jac / gscale[:, None]])


def _local_solve(prob: _Problem, x0: np.ndarray, h_max: float) -> np.ndarray | None:
    """SLSQP (minimise x1) from x0, then a Newton projection onto any slightly violated
    residual limit or angle equation. None if it fails."""
    lo = np.array([prob.min_pulse_s, 0.0, prob.min_pulse_s, 0.0])
    gscale = 4 * prob.omegas * (prob.p1 + prob.p2)  # bound on |grad R_k|: limits in seconds
    ascale = 2 * math.sqrt(prob.theta_a)
    constraints = [
        {
            "type": "eq",
            "fun": lambda x: np.array([prob.angle_gap(x) / ascale]),
            "jac": lambda x: prob.angle_grad(x)[None, :] / ascale,
        },
        {
            "type": "ineq",
            "fun": lambda x: _margins(prob, x, lo, gscale),
            "jac": lambda x: _margins_jac(prob, x, gscale),
        },
    ]
    try:
        with np.errstate(all="ignore"):
            res = minimize(
                lambda x: x[0],
                x0,
                jac=lambda x: np.array([1.0, 0.0, 0.0, 0.0]),
                method="SLSQP",
                bounds=[(0.0, h_max)] * 4,
                constraints=constraints,
                options={"maxiter": 400, "ftol": 1e-13},
            )
    except (ValueError, FloatingPointError, np.linalg.LinAlgError):
        return None
    x = np.asarray(res.x, dtype=float)
    if not np.all(np.isfinite(x)):
        return None
    for _ in range(10):  # Newton projection (min-norm steps) onto the violated limits
        r = prob.residuals(x)
        excess = r - np.clip(r, -prob.tols, prob.tols)
        gap = prob.angle_gap(x)
        if not np.any(excess) and abs(gap) <= 1e-12 * prob.theta_a:
            break
        rows = excess != 0
        jac = np.vstack([prob.angle_grad(x)[None, :], prob.residual_jac(x)[rows]])
        target = np.concatenate(
            [[gap], excess[rows] + np.sign(excess[rows]) * 1e-3 * prob.tols[rows]]
        )
        x = x - np.linalg.lstsq(jac, target, rcond=None)[0]
    return x


def _mode_residual(
    prob: _Problem, k: int, x1: np.ndarray, x2: np.ndarray, x3: np.ndarray, x4: np.ndarray
) -> np.ndarray:
    """R_k alone, with the arithmetic of `_Problem.residuals` (the same terms summed in the same
    order, so the same values); x1..x4 broadcast against each other."""
    return _four_terms(prob.weights, prob.omegas[k], x1, x2, x3, x4)


def _four_terms(wts: np.ndarray, w: np.ndarray | float, x1: np.ndarray, x2: np.ndarray,
                x3: np.ndarray, x4: np.ndarray) -> np.ndarray:
    """2 sum_i wts_i cos(w x_i), the four terms summed left to right from 0 (the order the
    residuals' values, and so the scan's candidates, depend on)."""
    return 2 * (
        (((0 + wts[0] * np.cos(w * x1)) + wts[1] * np.cos(w * x2)) + wts[2] * np.cos(w * x3))
        + wts[3] * np.cos(w * x4)
    )


def _grid_scan(
    prob: _Problem, x1_lo: float, x1_hi: float, n_side: int, x1_step: float
) -> tuple[float, list[np.ndarray]]:
    """Scan x1 = t8/2 upwards over a dense (x2, x4) grid, x3 from the angle equation.

    Returns the first x1 with a grid-feasible point and candidates there; (inf, []) if none.
    The tightest mode is an equality located by sign changes between neighbouring grid
    points; at the interpolated crossing b >= 0 and every other mode's limit are checked.
    A feasible region thinner than the grid spacing is missed, so the scan's x1 is, to its
    resolution, an independent upper estimate of the optimum reached from below.

    Only the tightest mode is evaluated on the whole grid, and only its sign test is taken
    on every pair of neighbours: the crossing's fraction and b only where the sign changes,
    the other modes only at the two ends of the crossings that passed b >= 0, with the same
    arithmetic as ``_Problem.residuals`` (x1 is one value per level, x2 one per row and x4 one
    per column, so their cosines are taken once per level and broadcast): the same points and
    candidates as evaluating everything everywhere (tests/test_two_amplitude.py compares).
    """
    k_star = int(np.argmin(prob.tols))
    others = [k for k in range(len(prob.tols)) if k != k_star]
    cuts = (
        ((slice(None, -1), slice(None)), (slice(1, None), slice(None))),
        ((slice(None), slice(None, -1)), (slice(None), slice(1, None))),
    )
    # index offsets of the second end of a crossing, per cut
    steps = ((1, 0), (0, 1))
    u = np.linspace(0.0, 1.0, n_side)
    for x1 in np.arange(x1_lo, x1_hi + x1_step / 2, x1_step):
        x2_lo = math.sqrt(max(x1**2 - prob.theta_a / prob.p1, 0.0))
        x2g = x2_lo + (x1 - prob.min_pulse_s - x2_lo) * u
        x4g = x1 * u
        x2 = x2g[:, None]
        x4 = x4g[None, :]
        area = (prob.theta_a - prob.p1 * (x1**2 - x2**2)) / prob.p2
        x3 = np.sqrt(x4**2 + np.maximum(area, 0.0))
        b = x2 - x3
        valid = area >= 0
        if not (valid & (b >= 0)).any():
            continue
        x1a = np.array([x1])  # one value per level
        rs = np.where(valid, _mode_residual(prob, k_star, x1a, x2, x3, x4), np.nan)
        cands: list[np.ndarray] = []
        for (sl0, sl1), (di, dj) in zip(cuts, steps, strict=True):
            # neighbours with a sign change (NaN, outside the angle's reach, compares false);
            # the crossing's fraction and the checks only there
            with np.errstate(invalid="ignore"):
                i0, j0 = np.nonzero(rs[sl0] * rs[sl1] <= 0)
            if not i0.size:
                continue
            i1, j1 = i0 + di, j0 + dj
            r0, r1 = rs[i0, j0], rs[i1, j1]
            with np.errstate(invalid="ignore", divide="ignore"):
                frac = r0 / (r0 - r1)
            keep = np.isfinite(frac)
            b0 = b[i0, j0]
            keep &= b0 + frac * (b[i1, j1] - b0) >= 0
            i0, j0, i1, j1, frac = i0[keep], j0[keep], i1[keep], j1[keep], frac[keep]
            if others and i0.size:
                keep = np.ones(i0.size, dtype=bool)
                with np.errstate(invalid="ignore"):
                    for k in others:
                        q0 = _mode_residual(prob, k, x1a, x2g[i0], x3[i0, j0], x4g[j0])
                        q1 = _mode_residual(prob, k, x1a, x2g[i1], x3[i1, j1], x4g[j1])
                        keep &= np.abs(q0 + frac * (q1 - q0)) <= prob.tols[k]
                i0, j0, frac = i0[keep], j0[keep], frac[keep]
            for i, j, f in zip(i0[:4], j0[:4], frac[:4], strict=True):
                p0 = np.array([x1, x2g[i], x3[i, j], x4g[j]])
                p1 = np.array([x1, x2g[i + di], x3[i + di, j + dj], x4g[j + dj]])
                cands.append(p0 * (1 - f) + p1 * f)
        if cands:
            return float(x1), cands
    return math.inf, []


def design_two_amplitude(
    kind: ShaperKind,
    *,
    inertia_kg_m2: float,
    torque_n_m: float,
    angle_rad: float,
    modes: Sequence[ModeConstraint],
    n_starts: int = 64,
    seed: int = 0,
    max_t8_s: float | None = None,
    grid_points: int = 200,
    grid_step_t8_s: float = 0.02,
    agree_tol_s: float = 1e-3,
    margin: float = 1e-3,
) -> TwoAmplitudeDesign:
    """Shortest LHHL / HLLH sequence meeting V(w_k) <= Vmax_k at every mode (eqs 6-13).

    `angle_rad` may be negative (the amplitudes are then negated, as the paper notes).
    `max_t8_s` bounds the searched box (default: three bang-bang durations). Residual limits
    are designed to (1 - margin) Vmax so that the returned sequence meets them strictly.
    `grid_points` (per side; 0 skips the scan) and `grid_step_t8_s` set the dense scan.
    """
    p1, p2 = _levels(kind)
    inertia = _positive("inertia_kg_m2", inertia_kg_m2)
    torque = _positive("torque_n_m", torque_n_m)
    angle = float(angle_rad)
    if not math.isfinite(angle) or angle == 0:
        raise ValueError(f"angle_rad must be finite and non-zero, got {angle_rad!r}")
    if not modes:
        raise ValueError("modes must hold at least one ModeConstraint")
    if n_starts < 1:
        raise ValueError(f"n_starts must be >= 1, got {n_starts!r}")
    if grid_points < 0 or grid_points == 1:
        raise ValueError(f"grid_points must be 0 or >= 2, got {grid_points!r}")
    _positive("grid_step_t8_s", grid_step_t8_s)
    if not 0 <= margin < 1:
        raise ValueError(f"margin must be in [0, 1), got {margin!r}")
    modes = [m if isinstance(m, ModeConstraint) else ModeConstraint(*m) for m in modes]
    theta_a = abs(angle) * inertia / torque
    tau = math.sqrt(theta_a)
    omegas = np.array([m.freq_rad_s for m in modes])
    vmax = np.array([m.vmax_percent for m in modes])
    den = _bang_bang_magnitude(omegas, tau)
    if np.any(den < 1e-12):
        raise ValueError("a mode frequency makes the bang-bang reference vanish (w tau = 2 k pi)")
    prob = _Problem(p1, p2, theta_a, omegas, (1 - margin) * vmax / 100 * den, 1e-6 * tau)
    max_t8 = 6 * tau if max_t8_s is None else _positive("max_t8_s", max_t8_s)
    if max_t8 <= 2 * tau:
        raise ValueError(f"max_t8_s must exceed the bang-bang duration {2 * tau:.3f} s")
    h_max = max_t8 / 2

    # multi-start: Sobol points in the ordered box h_max >= x1 >= x2 >= x3 >= x4 >= 0
    base2 = max(0, math.ceil(math.log2(n_starts)))
    # imported here: scipy.stats is a quarter of a harness process's start
    from scipy.stats import qmc

    raw = qmc.Sobol(4, scramble=True, seed=seed).random_base2(base2)[:n_starts]
    starts = np.sort(raw, axis=1)[:, ::-1] * h_max
    found: list[tuple[float, np.ndarray]] = []
    for x0 in starts:
        x = _local_solve(prob, x0, h_max)
        if x is not None and prob.feasible(x) and x[0] <= h_max + 1e-9:
            found.append((2 * float(x[0]), x))
    found.sort(key=lambda item: item[0])
    multi_t8 = [t8 for t8, _ in found]
    multi_best = multi_t8[0] if found else math.inf

    grid_t8 = None
    improved = False
    if grid_points:
        step = grid_step_t8_s / 2
        x1_hi = multi_best / 2 + 3 * step if found else h_max
        x1_grid, cands = _grid_scan(prob, tau, x1_hi, grid_points, step)
        if cands:
            grid_t8 = 2 * x1_grid
        for x0 in cands:
            x = _local_solve(prob, x0, h_max)
            if x is not None and prob.feasible(x):
                found.append((2 * float(x[0]), x))
        found.sort(key=lambda item: item[0])
        improved = bool(found) and found[0][0] < multi_best - agree_tol_s
    if not found:
        raise ValueError(
            "no feasible sequence found within max_t8_s; loosen vmax_percent or raise max_t8_s"
        )
    best_t8, best = found[0]
    distinct: list[float] = []
    for t8, _ in found:
        if not distinct or t8 - distinct[-1] > agree_tol_s:
            distinct.append(t8)
    t2, b, c, d = (float(v) for v in _ORDER @ best)
    sign = 1.0 if angle > 0 else -1.0
    times = symmetric_times(t2, b, c, d)
    amps = tuple(sign * a for a in shaper_amplitudes(kind))
    report = evaluate_sequence(
        times,
        amps,
        inertia_kg_m2=inertia,
        torque_n_m=torque,
        freqs_rad_s=omegas,
        vmax_percent=vmax,
        reference_angle_rad=angle,
    )
    search = SearchReport(
        n_starts=n_starts,
        n_feasible=len(multi_t8),
        n_agree=sum(1 for t8 in multi_t8 if t8 - best_t8 <= agree_tol_s),
        agree_tol_s=agree_tol_s,
        distinct_minima_s=tuple(distinct[:8]),
        grid_t8_s=grid_t8,
        grid_step_t8_s=grid_step_t8_s,
        grid_points=grid_points**2,
        improved_by_grid=improved,
        grid_consistent=grid_t8 is None or grid_t8 >= best_t8 - grid_step_t8_s,
        max_t8_s=max_t8,
    )
    return TwoAmplitudeDesign(
        kind=kind.upper(),
        t2_s=t2,
        b_s=b,
        c_s=c,
        d_s=d,
        times_s=report.times_s,
        amplitudes=report.amplitudes,
        mode_freqs_rad_s=report.mode_freqs_rad_s,
        residual_percent=report.residual_percent,
        vmax_percent=tuple(float(v) for v in vmax),
        t8_s=report.t8_s,
        fuel_on_time_s=report.fuel_on_time_s,
        impulse_n_m_s=report.impulse_n_m_s,
        report=report,
        search=search,
    )
