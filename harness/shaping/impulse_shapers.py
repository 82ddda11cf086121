"""Classical impulse shapers (ZV, ZVD, ZVDD, EI), their residual vibration, and command shaping.

Everything is in SI units: times in s, frequencies in rad/s (undamped natural frequency
``omega``), damping as the ratio ``zeta``. A shaper is an :class:`ImpulseSequence`; shaping a
command is convolving it with that sequence:

    u_shaped(t) = sum_i A_i * u(t - t_i).

Residual vibration follows the standard definition (Singer & Seering 1990): for a second-order
mode (omega, zeta) excited by the sequence, the amplitude of the vibration left after the last
impulse (time t_N), divided by that of one unit impulse applied at t_N::

    V = exp(-zeta omega t_N) * | sum_i A_i exp(zeta omega t_i) exp(j omega_d t_i) |,

with omega_d = omega sqrt(1 - zeta^2). :func:`residual_vibration` returns ``100 V`` (percent);
for a sequence whose amplitudes sum to 1 it is also the shaped step's residual vibration over
that of an unshaped unit step applied at t_N (for zeta = 0 the timing does not matter).

Pure functions and one small stateful class (:class:`ShapedCommand`, a fixed-rate shaper for a
control loop); no I/O.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import least_squares, linprog

FloatArray = NDArray[np.float64]

__all__ = [
    "ImpulseSequence",
    "ShapedCommand",
    "convolve",
    "damped_period",
    "ei",
    "multi_mode",
    "residual_vibration",
    "sensitivity_curve",
    "shape_command",
    "si",
    "zv",
    "zvd",
    "zvdd",
]

_MERGE_TOL_S = 1e-12


@dataclass(frozen=True)
class ImpulseSequence:
    """Impulses of amplitude ``amplitudes[i]`` at ``times_s[i]`` (s, sorted, first >= 0)."""

    times_s: FloatArray
    amplitudes: FloatArray

    def __post_init__(self) -> None:
        times = np.array(self.times_s, dtype=float).reshape(-1)
        amps = np.array(self.amplitudes, dtype=float).reshape(-1)
        if times.size == 0:
            raise ValueError("times_s: expected at least one impulse, got none")
        if times.shape != amps.shape:
            raise ValueError(
                f"amplitudes: expected {times.size} values (one per time), got {amps.size}"
            )
        if not (np.all(np.isfinite(times)) and np.all(np.isfinite(amps))):
            raise ValueError("times_s/amplitudes: expected finite values")
        if times[0] < 0.0:
            raise ValueError(f"times_s: expected times >= 0, got {times[0]}")
        if np.any(np.diff(times) < 0.0):
            raise ValueError("times_s: expected non-decreasing times")
        times.setflags(write=False)
        amps.setflags(write=False)
        object.__setattr__(self, "times_s", times)
        object.__setattr__(self, "amplitudes", amps)

    @property
    def duration_s(self) -> float:
        """Time of the last impulse (the delay the shaper adds), s."""
        return float(self.times_s[-1])

    @property
    def total(self) -> float:
        """Sum of amplitudes (the shaper's static gain)."""
        return float(np.sum(self.amplitudes))

    def __len__(self) -> int:
        return int(self.times_s.size)


# --------------------------------------------------------------------------- validation


def _check_omega(omega: float, name: str = "omega") -> float:
    value = float(omega)
    if not (math.isfinite(value) and value > 0.0):
        raise ValueError(f"{name}: expected a finite natural frequency > 0 rad/s, got {omega}")
    return value


def _check_zeta(zeta: float, name: str = "zeta") -> float:
    value = float(zeta)
    if not (math.isfinite(value) and 0.0 <= value < 1.0):
        raise ValueError(f"{name}: expected a damping ratio in [0, 1), got {zeta}")
    return value


def damped_period(omega: float, zeta: float = 0.0) -> float:
    """Damped period 2 pi / (omega sqrt(1 - zeta^2)), s."""
    omega = _check_omega(omega)
    zeta = _check_zeta(zeta)
    return 2.0 * math.pi / (omega * math.sqrt(1.0 - zeta * zeta))


def _k_factor(zeta: float) -> float:
    return math.exp(-zeta * math.pi / math.sqrt(1.0 - zeta * zeta))


# --------------------------------------------------------------------------- shapers


def zv(omega: float, zeta: float = 0.0) -> ImpulseSequence:
    """Zero-vibration shaper: [1, K] / (1 + K) at [0, T/2], T the damped period."""
    period = damped_period(omega, zeta)
    k = _k_factor(zeta)
    return ImpulseSequence(np.array([0.0, period / 2]), np.array([1.0, k]) / (1.0 + k))


def zvd(omega: float, zeta: float = 0.0) -> ImpulseSequence:
    """Zero-vibration-derivative shaper: [1, 2K, K^2] / (1 + K)^2 at [0, T/2, T]."""
    period = damped_period(omega, zeta)
    k = _k_factor(zeta)
    amps = np.array([1.0, 2.0 * k, k * k]) / (1.0 + k) ** 2
    return ImpulseSequence(np.array([0.0, period / 2, period]), amps)


def zvdd(omega: float, zeta: float = 0.0) -> ImpulseSequence:
    """ZVDD shaper: [1, 3K, 3K^2, K^3] / (1 + K)^3 at [0, T/2, T, 3T/2]."""
    period = damped_period(omega, zeta)
    k = _k_factor(zeta)
    amps = np.array([1.0, 3.0 * k, 3.0 * k * k, k**3]) / (1.0 + k) ** 3
    return ImpulseSequence(np.array([0.0, 0.5, 1.0, 1.5]) * period, amps)


def ei(omega: float, zeta: float = 0.0, v_tol: float = 0.05) -> ImpulseSequence:
    """Extra-insensitive shaper (Singhose, Derezinski & Singer 1996), three impulses.

    ``v_tol`` is the tolerated residual vibration as a fraction (0.05 = 5 %). Defining
    conditions: amplitudes sum to 1; V(omega) = v_tol with dV/domega = 0 there (a hump at the
    design frequency); V = 0 at one frequency below and one above. For zeta = 0 the closed form
    [(1+V)/4, (1-V)/2, (1+V)/4] at [0, T/2, T] satisfies them; for zeta > 0 they are solved
    numerically (six equations: the two zeros are complex, in six unknowns A1, A3, t2, t3 and
    the two zero frequencies), starting from the undamped solution.
    """
    omega = _check_omega(omega)
    zeta = _check_zeta(zeta)
    v = float(v_tol)
    if not (math.isfinite(v) and 0.0 < v < 1.0):
        raise ValueError(f"v_tol: expected a fraction in (0, 1), got {v_tol}")
    period = 2.0 * math.pi / omega
    a1 = a3 = (1.0 + v) / 4.0
    if zeta == 0.0:
        amps = np.array([a1, (1.0 - v) / 2.0, a3])
        return ImpulseSequence(np.array([0.0, period / 2, period]), amps)

    wd_factor = math.sqrt(1.0 - zeta * zeta)

    def complex_sum(amps: FloatArray, times: FloatArray, w: float) -> complex:
        s = (zeta + 1j * wd_factor) * w
        return complex(np.sum(amps * np.exp(s * times)) * math.exp(-zeta * w * times[-1]))

    def equations(x: FloatArray) -> FloatArray:
        a1_, a3_, t2, t3, w_lo, w_hi = x
        amps = np.array([a1_, 1.0 - a1_ - a3_, a3_])
        times = np.array([0.0, t2, t3])
        s_n = complex_sum(amps, times, omega)
        s_fac = zeta + 1j * wd_factor
        ds = np.sum(amps * s_fac * times * np.exp(s_fac * omega * times))
        ds *= math.exp(-zeta * omega * t3)
        ds += -zeta * t3 * s_n
        dv2 = 2.0 * (np.conj(s_n) * ds).real * omega  # d|S|^2/d(ln omega)
        lo = complex_sum(amps, times, w_lo)
        hi = complex_sum(amps, times, w_hi)
        return np.array([abs(s_n) - v, dv2, lo.real, lo.imag, hi.real, hi.imag])

    x_zero = math.acos(-(1.0 - v) / (1.0 + v)) / math.pi  # zero at omega * x_zero (undamped)
    x0 = np.array([a1, a3, period / 2, period, omega * x_zero, omega * (2.0 - x_zero)])
    # keep the two zeros on either side of the design frequency (other roots exist, with
    # zeros far away and no insensitivity around the design frequency)
    lower = np.array([0.0, 0.0, 0.25 * period, 0.75 * period, 0.3 * omega, omega * 1.0001])
    upper = np.array([1.0, 1.0, 0.75 * period, 1.5 * period, omega * 0.9999, 1.7 * omega])
    sol = least_squares(
        equations, x0, bounds=(lower, upper), xtol=1e-15, ftol=1e-15, gtol=1e-15
    )
    if not sol.success or np.max(np.abs(sol.fun)) > 1e-9:
        raise RuntimeError(f"ei: EI conditions not met (residual {np.max(np.abs(sol.fun)):.2e})")
    a1_, a3_, t2, t3 = sol.x[:4]
    return ImpulseSequence(np.array([0.0, t2, t3]), np.array([a1_, 1.0 - a1_ - a3_, a3_]))


def si(
    omega_lo: float,
    omega_hi: float,
    zeta_lo: float = 0.0,
    zeta_hi: float | None = None,
    v_tol: float = 0.05,
    *,
    points_per_period: int = 16,
    n_angles: int = 24,
    max_impulses: int = 400,
) -> ImpulseSequence:
    """Specified-insensitivity shaper (Singhose, Seering & Singer 1997): the shortest
    sequence of positive impulses (sum 1) on a time grid whose residual vibration is at most
    ``v_tol`` (a fraction: 0.05 = 5 %) at every frequency of [``omega_lo``, ``omega_hi``]
    (rad/s) and every damping ratio of [``zeta_lo``, ``zeta_hi``] (``zeta_hi`` None: zeta_lo).

    Impulses sit on a grid of ``points_per_period`` per period of ``omega_hi``. For a given
    number of grid points the best amplitudes solve a linear program exactly (minimise v
    subject to Re(exp(-j phi_m) S(omega, zeta)) <= v cos(pi / n_angles) for ``n_angles``
    directions phi_m, which bounds |S| <= v, at the band's sampled frequencies and damping
    ratios, amplitudes >= 0 summing to 1); the shortest grid meeting ``v_tol`` is found by
    bisection (feasibility grows with the grid's length). The result is checked on a dense
    grid with :func:`residual_vibration` (its own last impulse as the reference); if a
    frequency between the samples exceeds ``v_tol``, the band is sampled more finely.
    """
    lo = _check_omega(omega_lo, "omega_lo")
    hi = _check_omega(omega_hi, "omega_hi")
    if hi < lo:
        raise ValueError(f"omega_hi: expected >= omega_lo {lo} rad/s, got {hi}")
    z_lo = _check_zeta(zeta_lo, "zeta_lo")
    z_hi = z_lo if zeta_hi is None else _check_zeta(zeta_hi, "zeta_hi")
    if z_hi < z_lo:
        raise ValueError(f"zeta_hi: expected >= zeta_lo {z_lo}, got {z_hi}")
    v = float(v_tol)
    if not (math.isfinite(v) and 0.0 < v < 1.0):
        raise ValueError(f"v_tol: expected a fraction in (0, 1), got {v_tol}")
    return _si_design(lo, hi, z_lo, z_hi, v, int(points_per_period), int(n_angles),
                      int(max_impulses))


@lru_cache(maxsize=64)
def _si_design(lo: float, hi: float, z_lo: float, z_hi: float, v: float,
               points_per_period: int, n_angles: int, max_impulses: int) -> ImpulseSequence:
    """``si``'s design, its inputs checked. Cached by its inputs: a calibration builds each
    candidate's controller several times (candidates, report, verification runs), each a
    few linear programs; the design is deterministic and the sequence immutable, so a
    cached one is the one the LPs would give again."""
    step = 2.0 * math.pi / hi / points_per_period
    zetas = np.unique([z_lo, 0.5 * (z_lo + z_hi), z_hi])
    dense_w = np.linspace(lo, hi, 401) if hi > lo else np.array([lo])
    phis = 2.0 * np.pi * np.arange(n_angles) / n_angles
    bound = math.cos(math.pi / n_angles)

    def lp(n: int, n_freq: int) -> tuple[float, FloatArray]:
        times = step * np.arange(n + 1)
        ws = np.linspace(lo, hi, n_freq) if hi > lo else np.array([lo])
        rows = []
        for z in zetas:
            s = (z + 1j * math.sqrt(1.0 - z * z)) * ws[:, None]
            terms = np.exp(s * (times - times[-1])[None, :])  # (freq, impulses)
            rows.append((np.exp(-1j * phis)[:, None, None] * terms[None]).real.reshape(
                -1, n + 1))
        a = np.vstack(rows)
        a_ub = np.hstack([a, -np.full((a.shape[0], 1), 1.0 / bound)])
        c = np.zeros(n + 2)
        c[-1] = 1.0
        a_eq = np.r_[np.ones(n + 1), 0.0][None, :]
        res = linprog(c, A_ub=a_ub, b_ub=np.zeros(a.shape[0]), A_eq=a_eq, b_eq=[1.0],
                      bounds=[(0.0, None)] * (n + 1) + [(0.0, None)], method="highs")
        if not res.success:  # pragma: no cover - the LP is always feasible (v large)
            raise RuntimeError(f"si: linear program failed: {res.message}")
        return float(res.x[-1]), np.asarray(res.x[:-1])

    def sequence(amps: FloatArray) -> ImpulseSequence:
        times = step * np.arange(amps.size)
        keep = amps > 1e-10
        return ImpulseSequence(times[keep] - times[keep][0], amps[keep] / amps[keep].sum())

    def worst(seq: ImpulseSequence) -> float:
        return max(float(np.max(residual_vibration(seq, dense_w, z))) for z in zetas) / 100

    n_freq = 25
    for _ in range(4):
        # smallest n with min v <= v_tol: grow geometrically, then bisect
        n_lo, n_hi = 0, max(1, int(points_per_period // 2))
        while lp(n_hi, n_freq)[0] > v:
            n_lo, n_hi = n_hi, 2 * n_hi
            if n_hi > max_impulses:
                raise ValueError(
                    f"si: no sequence of up to {max_impulses} grid impulses keeps the residual "
                    f"vibration below {v:.3g} over [{lo:.4g}, {hi:.4g}] rad/s, damping "
                    f"[{z_lo:.3g}, {z_hi:.3g}]")
        while n_hi - n_lo > 1:
            mid = (n_lo + n_hi) // 2
            n_lo, n_hi = (n_lo, mid) if lp(mid, n_freq)[0] <= v else (mid, n_hi)
        seq = sequence(lp(n_hi, n_freq)[1])
        if worst(seq) <= v * (1.0 + 1e-6):
            return seq
        n_freq = 2 * n_freq - 1
    raise RuntimeError(f"si: residual above {v:.3g} between the sampled frequencies")


def convolve(first: ImpulseSequence, second: ImpulseSequence) -> ImpulseSequence:
    """Convolution of two sequences (multi-mode shaper); coincident impulses are merged."""
    times = (first.times_s[:, None] + second.times_s[None, :]).reshape(-1)
    amps = (first.amplitudes[:, None] * second.amplitudes[None, :]).reshape(-1)
    order = np.argsort(times, kind="stable")
    times, amps = times[order], amps[order]
    merged_t: list[float] = []
    merged_a: list[float] = []
    for t, a in zip(times, amps, strict=True):
        if merged_t and t - merged_t[-1] <= _MERGE_TOL_S * max(1.0, abs(t)):
            merged_a[-1] += a
        else:
            merged_t.append(float(t))
            merged_a.append(float(a))
    return ImpulseSequence(np.array(merged_t), np.array(merged_a))


def multi_mode(sequences: Sequence[ImpulseSequence]) -> ImpulseSequence:
    """Convolve one shaper per mode into a single multi-mode shaper."""
    if len(sequences) == 0:
        raise ValueError("sequences: expected at least one ImpulseSequence")
    result = sequences[0]
    for seq in sequences[1:]:
        result = convolve(result, seq)
    return result


# --------------------------------------------------------------------------- vibration


def residual_vibration(seq: ImpulseSequence, omega: ArrayLike, zeta: float = 0.0) -> FloatArray:
    """Residual vibration V (percent) of mode(s) ``omega`` (rad/s, scalar or array), ratio zeta.

    See the module docstring for the definition; 100 means as much vibration as one unit
    impulse (or an unshaped unit step), 0 means none.
    """
    zeta = _check_zeta(zeta)
    w = np.asarray(omega, dtype=float)
    if np.any(~np.isfinite(w)) or np.any(w <= 0.0):
        raise ValueError("omega: expected finite natural frequencies > 0 rad/s")
    t = seq.times_s
    s = (zeta + 1j * math.sqrt(1.0 - zeta * zeta)) * w[..., None]
    # shift times so the exponent never grows: exp(zeta w (t_i - t_N)) <= 1
    total = np.sum(seq.amplitudes * np.exp(s * (t - t[-1])), axis=-1)
    return 100.0 * np.abs(total)


def sensitivity_curve(
    seq: ImpulseSequence, omega_design: float, zeta: float, ratios: ArrayLike
) -> FloatArray:
    """Residual vibration (percent) at ``ratios * omega_design`` (the shaper's sensitivity)."""
    omega_design = _check_omega(omega_design, "omega_design")
    r = np.asarray(ratios, dtype=float)
    if np.any(~np.isfinite(r)) or np.any(r <= 0.0):
        raise ValueError("ratios: expected finite frequency ratios > 0")
    return residual_vibration(seq, r * omega_design, zeta)


# --------------------------------------------------------------------------- shaping commands


def _sample(
    t: FloatArray, u: FloatArray, tau: FloatArray, initial: float, interpolation: str
) -> FloatArray:
    """u(tau) with u = initial before t[0], held at u[-1] after t[-1].

    A shift that lands within a billionth of a sample interval of a sample time counts as on
    it, so delays that are whole numbers of samples are not spoiled by rounding.
    """
    tol = 1e-9 * (t[-1] - t[0]) / max(t.size - 1, 1) if t.size > 1 else 1e-12
    if interpolation == "linear":
        values = np.interp(tau, t, u)
    else:  # "previous": zero-order hold
        idx = np.clip(np.searchsorted(t, tau + tol, side="right") - 1, 0, t.size - 1)
        values = u[idx]
    return np.where(tau < t[0] - tol, initial, values)


def shape_command(
    t: ArrayLike,
    u: ArrayLike,
    seq: ImpulseSequence,
    *,
    initial: float = 0.0,
    interpolation: str = "linear",
) -> FloatArray:
    """Shaped command ``sum_i A_i u(t - t_i)`` evaluated at the sample times ``t``.

    ``u`` is sampled at ``t`` (strictly increasing, s); between samples it is interpolated
    (``interpolation="linear"``) or held (``"previous"``), before ``t[0]`` it equals
    ``initial`` and after ``t[-1]`` it keeps its last value. Extend ``t`` by
    ``seq.duration_s`` to see the whole shaped command. ``u`` may have extra trailing axes
    (e.g. shape (N, 3) for three axes).
    """
    t_arr = np.asarray(t, dtype=float)
    u_arr = np.asarray(u, dtype=float)
    if t_arr.ndim != 1 or t_arr.size < 1:
        raise ValueError("t: expected a 1-D array of sample times")
    if np.any(np.diff(t_arr) <= 0.0):
        raise ValueError("t: expected strictly increasing sample times")
    if u_arr.shape[:1] != t_arr.shape:
        raise ValueError(f"u: expected first dimension {t_arr.size} (one per t), got {u_arr.shape}")
    if interpolation not in ("linear", "previous"):
        raise ValueError(f"interpolation: expected 'linear' or 'previous', got {interpolation!r}")
    flat = u_arr.reshape(t_arr.size, -1)
    out = np.zeros_like(flat)
    for a_i, t_i in zip(seq.amplitudes, seq.times_s, strict=True):
        tau = t_arr - t_i
        for col in range(flat.shape[1]):
            out[:, col] += a_i * _sample(t_arr, flat[:, col], tau, initial, interpolation)
    return out.reshape(u_arr.shape)


class ShapedCommand:
    """Fixed-rate shaper for a control loop: feed one sample every ``dt_s``, get one back.

    Impulse times are mapped to whole ticks of ``dt_s``:

    * ``rounding="nearest"`` (default): impulse i acts with delay ``floor(t_i/dt + 1/2)`` ticks
      and its full amplitude. The static gain is unchanged, but the impulses move by up to
      dt/2, so the zero-vibration conditions only hold approximately; check
      ``residual_vibration(shaper.quantized_sequence, ...)``.
    * ``rounding="split"``: an impulse at (k + f) dt is split into A(1-f) at tick k and A f at
      tick k+1, which keeps each impulse's amplitude and first moment (time centroid).

    Before the first sample the command is taken to equal ``initial`` (a scalar or an array,
    which fixes the shape of the samples, e.g. three axes).
    """

    def __init__(
        self,
        seq: ImpulseSequence,
        dt_s: float,
        *,
        initial: ArrayLike = 0.0,
        rounding: str = "nearest",
    ) -> None:
        dt = float(dt_s)
        if not (math.isfinite(dt) and dt > 0.0):
            raise ValueError(f"dt_s: expected a sample period > 0 s, got {dt_s}")
        if rounding not in ("nearest", "split"):
            raise ValueError(f"rounding: expected 'nearest' or 'split', got {rounding!r}")
        ticks_f = seq.times_s / dt
        if rounding == "nearest":
            ticks = np.floor(ticks_f + 0.5).astype(int)
            weights = seq.amplitudes.copy()
        else:
            base = np.floor(ticks_f + 1e-9).astype(int)
            frac = np.clip(ticks_f - base, 0.0, 1.0)
            frac[frac < 1e-9] = 0.0
            ticks = np.concatenate([base, base + 1])
            weights = np.concatenate([seq.amplitudes * (1.0 - frac), seq.amplitudes * frac])
        # merge impulses landing on the same tick
        uniq = np.unique(ticks)
        merged = np.array([weights[ticks == k].sum() for k in uniq])
        keep = merged != 0.0
        self._ticks = uniq[keep]
        self._weights = merged[keep]
        self.dt_s = dt
        self.rounding = rounding
        self._initial = np.asarray(initial, dtype=float)
        self._length = int(self._ticks[-1]) + 1 if self._ticks.size else 1
        self.reset()

    @property
    def delay_ticks(self) -> NDArray[np.int_]:
        """Tick delay of each (merged) impulse."""
        return self._ticks.copy()

    @property
    def quantized_sequence(self) -> ImpulseSequence:
        """The sequence actually applied, impulse times on the tick grid."""
        return ImpulseSequence(self._ticks * self.dt_s, self._weights.copy())

    def reset(self, initial: ArrayLike | None = None) -> None:
        """Forget the history; the past command is taken to equal ``initial``."""
        if initial is not None:
            self._initial = np.asarray(initial, dtype=float)
        self._buffer = np.broadcast_to(
            self._initial, (self._length,) + self._initial.shape
        ).copy()
        self._head = 0  # index of the newest sample

    def step(self, u: ArrayLike) -> FloatArray | float:
        """Push the newest raw sample, return the shaped sample for the same tick."""
        value = np.asarray(u, dtype=float)
        if value.shape != self._initial.shape:
            raise ValueError(f"u: expected shape {self._initial.shape}, got {value.shape}")
        self._head = (self._head + 1) % self._length
        self._buffer[self._head] = value
        idx = (self._head - self._ticks) % self._length
        out = np.tensordot(self._weights, self._buffer[idx], axes=1)
        return float(out) if out.ndim == 0 else out

    def process(self, samples: ArrayLike) -> FloatArray:
        """Feed a whole array of samples (first axis = time) and return the shaped samples.

        The same as ``step`` on each sample in turn (the same values, bit for bit, and the
        same state afterwards): every output is the same ``np.dot`` of the weights with the
        delayed samples that ``step`` takes, gathered from the history and ``samples`` at once
        instead of through the ring buffer one sample at a time."""
        arr = np.asarray(samples, dtype=float)
        if arr.ndim == 0 or arr.shape[0] == 0 or arr.shape[1:] != self._initial.shape:
            return np.array([self.step(s) for s in arr])  # step's errors and empty output
        n, length, k = arr.shape[0], self._length, self._ticks.size
        # the buffer oldest first, then the samples: sample i sits at ext[length + i]
        ext = np.concatenate([self._buffer[(self._head + 1 + np.arange(length)) % length], arr])
        delayed = ext[length + np.arange(n)[:, None] - self._ticks[None, :]].reshape(n, k, -1)
        # np.tensordot(weights, buffer[idx], axes=1) in step is this dot of (1, k) by (k, m)
        w = self._weights.reshape(1, k)
        out = np.array([np.dot(w, d)[0] for d in delayed])
        self._head = (self._head + n) % length
        self._buffer[(self._head - np.arange(length)[::-1]) % length] = ext[-length:]
        return out.reshape(arr.shape)
