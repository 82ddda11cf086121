"""The rig's model measured from commissioning's recordings: arrays in, a value and its
1-sigma out. Pure (numpy, scipy, ``harness.identification``): no bus, no rig file.

- ``mean_estimate``: a sensor's mean at rest (its bias);
- ``coast_down_friction``: the wheel's bearing friction from its coast-down, J dw/dt =
  -(Coulomb sign(w) + viscous w), fitted on the speed's integral form;
- ``first_order_lag``: a drive's first-order lag (and dead ticks) from its torque reading
  against its command;
- ``ring_down_modes``: the beam's modes (frequency, damping) of a tip-accelerometer
  ring-down, by the project's free-decay identification (``harness identify``'s);
- ``constrained_modes``: those hub-free modes mapped back onto the rig file's keys (each
  constrained mode's frequency factor and damping ratio), through the rig's own model;
- ``momentum_exchange``: the hub's inertia and each valve's impulse from the hub rate
  against the wheel's speed (the total angular momentum is kept by every internal torque:
  the wheel's motor and its friction), the beam's vibration fitted as free decays;
- ``readback_delay``: a valve's delay as far as its read-back's period bounds it.

Every least-squares sigma is the sandwich over contiguous blocks of samples
(``linear_fit``): a residual correlated over less than a block (a slowly varying reading's
quantisation, a sensor's filter) is counted as it is, not as white noise.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

BLOCKS = 40
"""Contiguous blocks of samples the least-squares sigmas are taken over (a cluster
sandwich): enough blocks for the covariance's own spread to be small (about 1/sqrt(2 x 40)
= 11 % on a sigma), each block long against the residuals' correlation."""

MIN_SAMPLES = 50


class EstimateError(ValueError):
    """The data cannot give the estimate (too few samples, no response)."""


@dataclass(frozen=True)
class Estimate:
    value: float
    sigma: float

    def __format__(self, spec: str) -> str:
        spec = spec or ".4g"
        return f"{self.value:{spec}} +- {self.sigma:.2g}"


def _blocks(n: int, blocks: int) -> list[slice]:
    k = max(1, min(blocks, n // 5))
    edges = np.linspace(0, n, k + 1).astype(int)
    return [slice(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:], strict=True) if b > a]


def linear_fit(x: np.ndarray, y: np.ndarray, blocks: int = BLOCKS, floor: float = 0.0
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Least squares ``y ~ x @ beta``: (beta, its covariance, the residuals). The covariance
    is the sandwich ``B^-1 (sum over blocks of g_b g_b^T) B^-1`` with ``B = x^T x`` and
    ``g_b`` the block's sum of ``x_t e_t`` (contiguous blocks of samples, times K / (K - p)
    for K blocks and p parameters): residuals correlated within a block count as they are.
    ``floor``: the reading's resolution as a noise (step / sqrt(12)); residuals smaller than
    it (a quantised reading that did not move) do not make the data know more than its
    resolution: noise of rms ``floor``, the same over a block (a reading that does not move
    repeats its quantisation error), is added in proportion to the shortfall."""
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    n, p = x.shape
    if n < max(p + 2, MIN_SAMPLES):
        raise EstimateError(f"{n} samples for {p} parameters")
    scale = np.sqrt(np.sum(x * x, axis=0))
    scale[scale == 0] = 1.0
    xs = x / scale
    beta_s, *_ = np.linalg.lstsq(xs, y, rcond=None)
    e = y - xs @ beta_s
    b_inv = np.linalg.pinv(xs.T @ xs)
    g = xs * e[:, None]
    parts = _blocks(n, blocks)
    meat = np.zeros((p, p))
    for s in parts:
        gb = g[s].sum(axis=0)
        meat += np.outer(gb, gb)
    k = len(parts)
    meat *= k / max(k - min(p, k - 1), 1)
    cov_s = b_inv @ meat @ b_inv
    if floor > 0:
        shortfall = max(0.0, 1.0 - float(np.mean(e ** 2)) / floor ** 2)
        cov_s = cov_s + shortfall * floor ** 2 * (n / k) * b_inv
    return beta_s / scale, cov_s / np.outer(scale, scale), e


def mean_estimate(values: np.ndarray, resolution: float = 0.0, blocks: int = BLOCKS
                  ) -> Estimate:
    """The mean of ``values`` and its sigma from the spread of block means (noise
    correlated within a block counted as it is; no less than the reading's ``resolution``
    allows, ``linear_fit``)."""
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    if v.size < MIN_SAMPLES:
        raise EstimateError(f"{v.size} samples")
    beta, cov, _ = linear_fit(np.ones((v.size, 1)), v, blocks, resolution / math.sqrt(12))
    return Estimate(float(beta[0]), math.sqrt(float(cov[0, 0])))


# ----------------------------------------------------------------------------- friction
@dataclass(frozen=True)
class Friction:
    coulomb_n_m: Estimate
    viscous_n_m_s: Estimate
    covariance: np.ndarray  # of (coulomb, viscous)
    speed_range_rad_s: tuple[float, float]  # the |speeds| the coast-downs covered
    samples: int

    def torque_at(self, speed_rad_s: float) -> Estimate:
        """The friction torque (N m) at ``speed_rad_s`` and its sigma."""
        w = abs(speed_rad_s)
        var = self.covariance[0, 0] + w * w * self.covariance[1, 1] + \
            2 * w * self.covariance[0, 1]
        return Estimate(self.coulomb_n_m.value + self.viscous_n_m_s.value * w,
                        math.sqrt(max(var, 0.0)))


def _cumtrapz(y: np.ndarray, t: np.ndarray) -> np.ndarray:
    return np.concatenate(([0.0], np.cumsum(0.5 * (y[1:] + y[:-1]) * np.diff(t))))


def coast_down_friction(t: np.ndarray, speed: np.ndarray,
                        windows: Sequence[tuple[float, float]], rotor_inertia_kg_m2: float,
                        min_speed_rad_s: float, resolution: float = 0.0) -> Friction:
    """Coulomb and viscous friction of a wheel coasting (no motor torque) over ``windows``
    (s): ``J dw/dt = -(c sign(w) + v w)``, fitted in its integral form over each window,
    ``w(t) = w_i - (c / J) int sign(w) dt - (v / J) int w dt``, with one start speed per
    window. A window ends where the speed comes within ``min_speed_rad_s`` of zero (the
    wheel stopping; friction never reverses it). The viscous term is told apart only by
    the speeds' spread: its sigma says how well the windows' speeds allow it.
    ``resolution``: the speed reading's step (``linear_fit``'s floor)."""
    t = np.asarray(t, dtype=float)
    speed = np.asarray(speed, dtype=float)
    j = float(rotor_inertia_kg_m2)
    cols: list[list[np.ndarray]] = []
    ys, speeds = [], []
    used = []
    for t0, t1 in windows:
        sel = np.flatnonzero((t >= t0) & (t < t1) & np.isfinite(speed))
        if sel.size < MIN_SAMPLES:
            continue
        w = speed[sel]
        tt = t[sel]
        moving = np.abs(w) > min_speed_rad_s
        if not moving[0]:
            continue
        stop = int(np.argmin(moving)) if not moving.all() else w.size
        same = np.sign(w[:stop]) == np.sign(w[0])
        stop = min(stop, int(np.argmin(same)) if not same.all() else stop)
        if stop < MIN_SAMPLES:
            continue
        w, tt = w[:stop], tt[:stop]
        used.append(len(ys))
        ys.append(w)
        speeds.append(np.abs(w))
        cols.append([-_cumtrapz(np.sign(w), tt) / j, -_cumtrapz(w, tt) / j])
    if not ys:
        raise EstimateError("no coast-down window with the wheel turning")
    n = sum(y.size for y in ys)
    k = len(ys)
    x = np.zeros((n, k + 2))
    row = 0
    for i, (y, (cs, cw)) in enumerate(zip(ys, cols, strict=True)):
        x[row:row + y.size, i] = 1.0
        x[row:row + y.size, k] = cs
        x[row:row + y.size, k + 1] = cw
        row += y.size
    beta, cov, _ = linear_fit(x, np.concatenate(ys), floor=resolution / math.sqrt(12))
    c_cov = cov[k:, k:]
    allw = np.concatenate(speeds)
    return Friction(Estimate(float(beta[k]), math.sqrt(float(c_cov[0, 0]))),
                    Estimate(float(beta[k + 1]), math.sqrt(float(c_cov[1, 1]))), c_cov,
                    (float(allw.min()), float(allw.max())), n)


# ----------------------------------------------------------------------------- lag
@dataclass(frozen=True)
class Lag:
    lag_s: Estimate
    gain: Estimate
    dead_ticks: int  # whole ticks between the command's record and its first effect
    residual_rms: float


def lag_response(command: np.ndarray, lag_s: float, dt_s: float, dead_ticks: int
                 ) -> np.ndarray:
    """A first-order lag's response, zero-order hold: ``y[k+1] = y[k] + a (u[k - d] -
    y[k])``, ``a = 1 - exp(-dt / lag)``, from rest."""
    from scipy.signal import lfilter

    u = np.asarray(command, dtype=float)
    if dead_ticks:
        u = np.concatenate((np.zeros(dead_ticks), u[:-dead_ticks]))
    a = 1.0 - math.exp(-dt_s / lag_s) if lag_s > 0 else 1.0
    return lfilter([0.0, a], [1.0, -(1.0 - a)], u)


def first_order_lag(command: np.ndarray, reading: np.ndarray, dt_s: float,
                    max_dead_ticks: int = 4, max_lag_s: float = 1.0,
                    resolution: float = 0.0) -> Lag:
    """A drive's torque loop as ``reading = gain x lag(command)`` (``lag_response``): the
    lag and the gain by least squares, for each whole number of dead ticks up to
    ``max_dead_ticks`` (the loop's own: the command recorded at a tick acts from the
    next); the dead ticks that fit best are kept. Samples from rest (the arrays start
    with the command at 0). ``resolution``: the reading's step (``linear_fit``'s floor)."""
    from scipy.optimize import minimize_scalar

    u = np.asarray(command, dtype=float)
    r = np.asarray(reading, dtype=float)
    ok = np.isfinite(u) & np.isfinite(r)
    u, r = np.where(ok, u, 0.0), r
    if not np.any(u[ok] != 0):
        raise EstimateError("the command never moved")

    def sse(log_tau: float, d: int) -> float:
        y = lag_response(u, math.exp(log_tau), dt_s, d)[ok]
        g = float(y @ r[ok]) / max(float(y @ y), 1e-300)
        return float(np.sum((r[ok] - g * y) ** 2))

    lo, hi = math.log(dt_s / 50), math.log(max_lag_s)
    best = None
    for d in range(max_dead_ticks + 1):
        grid = np.linspace(lo, hi, 25)
        vals = [sse(x, d) for x in grid]
        i = int(np.argmin(vals))
        a, b = grid[max(i - 1, 0)], grid[min(i + 1, grid.size - 1)]
        res = minimize_scalar(lambda x, d=d: sse(x, d), bounds=(a, b), method="bounded",
                              options={"xatol": 1e-6})
        if best is None or res.fun < best[0]:
            best = (float(res.fun), d, float(res.x))
    assert best is not None
    _, d, log_tau = best
    tau = math.exp(log_tau)
    y = lag_response(u, tau, dt_s, d)
    g = float(y[ok] @ r[ok]) / float(y[ok] @ y[ok])
    h = tau * 1e-4
    dy = (lag_response(u, tau + h, dt_s, d) - lag_response(u, tau - h, dt_s, d)) / (2 * h)
    x = np.column_stack((y, g * dy))[ok]
    delta, cov, e = linear_fit(x, r[ok] - g * y[ok], floor=resolution / math.sqrt(12))
    return Lag(Estimate(tau + float(delta[1]), math.sqrt(float(cov[1, 1]))),
               Estimate(g + float(delta[0]), math.sqrt(float(cov[0, 0]))), d,
               float(np.sqrt(np.mean(e ** 2))))


# ----------------------------------------------------------------------------- modes
@dataclass(frozen=True)
class Mode:
    omega_rad_s: Estimate  # undamped natural frequency
    damping_ratio: Estimate
    amplitude: float  # at the ring-down's start, in the record's unit


MAX_MODE_DAMPING = 0.3
"""A fitted pole more damped than this is not taken for a beam mode (a structure's modes
are lightly damped; such a pole is a sensor's own dynamics, a charge amplifier's, or the
fit's): ``ring_down_modes`` leaves it out."""


def ring_down_modes(t: np.ndarray, accel: np.ndarray, start_s: float, end_s: float,
                    n_modes: int | None = None, clip_level: float | None = None
                    ) -> tuple[list[Mode], list[str]]:
    """The modes of the free decay in ``accel`` (any reading of the beam's vibration) over
    [start_s, end_s) by the project's identification (``harness.identification.identify``:
    matrix pencil, then nonlinear least squares with 1-sigma from its Jacobian), lowest
    first (at most ``n_modes``), those damped beyond ``MAX_MODE_DAMPING`` left out; the
    identification's notes."""
    from harness.identification.api import DEFAULT_CLIP_LEVEL_M_S2, identify

    sel = (t >= start_s - 1e-9) & (t < end_s)
    if int(sel.sum()) < 4 * MIN_SAMPLES:
        raise EstimateError(f"{int(sel.sum())} samples in the ring-down")
    try:
        with np.errstate(divide="ignore", invalid="ignore"):  # a record that does not ring
            res = identify(t[sel], accel[sel], n_modes=n_modes, start_s=start_s,
                           clip_level_m_s2=clip_level or DEFAULT_CLIP_LEVEL_M_S2)
    except ValueError as exc:
        raise EstimateError(str(exc)) from exc
    modes = [Mode(Estimate(m.omega_rad_s, m.sigma_omega_rad_s),
                  Estimate(m.damping_ratio, m.sigma_damping), abs(m.amplitude))
             for m in res.modes if math.isfinite(m.sigma_omega_rad_s)
             and math.isfinite(m.sigma_damping) and m.damping_ratio <= MAX_MODE_DAMPING]
    return modes, list(res.notes)


def _weighted(values: Sequence[Estimate]) -> tuple[Estimate, float]:
    """The inverse-variance mean of ``values`` and the Birge ratio sqrt(chi^2 / (n - 1))
    (1 for one value); the mean's sigma is inflated by the ratio when it exceeds 1 (the
    values scatter more than their sigmas say)."""
    w = np.array([1.0 / max(v.sigma, 1e-300) ** 2 for v in values])
    x = np.array([v.value for v in values])
    mean = float(np.sum(w * x) / np.sum(w))
    sigma = float(1.0 / math.sqrt(np.sum(w)))
    ratio = 1.0
    if len(values) > 1:
        ratio = math.sqrt(float(np.sum(w * (x - mean) ** 2)) / (len(values) - 1))
    return Estimate(mean, sigma * max(ratio, 1.0)), ratio


def combine_modes(sources: Sequence[tuple[str, Sequence[Mode]]], model_omegas: Sequence[float]
                  ) -> tuple[list[Mode | None], list[str]]:
    """One mode per model mode (ascending rad/s) from several readings of one ring-down
    (the tip acceleration, the hub rate, a patch sensor: the same hub-free modes): each
    source's modes, strongest first, matched to the model's (``match_modes``), then per
    model mode the inverse-variance mean of frequency and damping over the sources that
    found it (``_weighted``: sigma inflated when they disagree). None where no source
    found it."""
    n = len(model_omegas)
    found: list[list[tuple[str, Mode]]] = [[] for _ in range(n)]
    for name, modes in sources:
        if not modes:
            continue
        top = max(m.amplitude for m in modes) or 1.0
        order = sorted(range(len(modes)), key=lambda i: -modes[i].amplitude)
        pick = match_modes([modes[i].omega_rad_s.value for i in order], model_omegas)
        for k, i in enumerate(pick):
            if i is not None:
                m = modes[order[i]]
                found[k].append((name, Mode(m.omega_rad_s, m.damping_ratio,
                                            m.amplitude / top)))
    out: list[Mode | None] = [None] * n
    notes = []
    for k, got in enumerate(found):
        if not got:
            continue
        w, rw = _weighted([m.omega_rad_s for _, m in got])
        z, rz = _weighted([m.damping_ratio for _, m in got])
        out[k] = Mode(w, z, max(m.amplitude for _, m in got))
        if max(rw, rz) > 2.0:
            notes.append(f"mode {k + 1}: its readings ({', '.join(n for n, _ in got)}) "
                         f"disagree (Birge ratio {max(rw, rz):.2g}): its sigmas are "
                         "inflated by it")
    return out, notes


@dataclass
class ConstrainedModes:
    """The rig file's beam keys that reproduce the measured hub-free modes: per kept mode
    its frequency factor and damping ratio (None where no measured mode matched it)."""

    factors: list[Estimate | None]
    dampings: list[Estimate | None]
    matched: list[int | None]  # per kept mode, the index of the measured mode
    notes: list[str] = field(default_factory=list)


HubFree = Callable[[Sequence[float], Sequence[float]], tuple[np.ndarray, np.ndarray]]


def constrained_modes(measured: Sequence[Mode], hub_free: HubFree,
                      factors0: Sequence[float], dampings0: Sequence[float],
                      iterations: int = 12) -> ConstrainedModes:
    """Invert the rig model's map from its constrained modes' (frequency factor, damping
    ratio) to the hub-free modes the tip accelerometer sees (``hub_free(factors,
    dampings) -> (omega, zeta)``, ascending): each measured mode is matched to the model's
    hub-free mode nearest it in log frequency (``match_modes``, the strongest first), then
    the matched modes' factors and dampings are corrected in turn until the model's
    hub-free modes are the measured ones. The sigmas map the measured ones through the
    local slope of each mode's own map (the small cross terms left out)."""
    f = np.array(factors0, dtype=float)
    z = np.array(dampings0, dtype=float)
    n = f.size
    w0, _ = hub_free(f, z)
    order = sorted(range(len(measured)), key=lambda i: -abs(measured[i].amplitude))
    pick = match_modes([measured[i].omega_rad_s.value for i in order], w0[:n])
    matched: list[int | None] = [None if i is None else order[i] for i in pick]
    notes = [f"a measured mode at {measured[i].omega_rad_s.value:.4g} rad/s matches none of "
             "the model's" for i in range(len(measured)) if i not in matched]
    for _ in range(iterations):
        w, zz = hub_free(f, z)
        for k, i in enumerate(matched):
            if i is None:
                continue
            m = measured[i]
            f[k] *= m.omega_rad_s.value / w[k]
            if zz[k] > 0 and z[k] > 0:
                z[k] *= m.damping_ratio.value / zz[k]
            else:
                z[k] = max(z[k] + m.damping_ratio.value - zz[k], 0.0)
    w, zz = hub_free(f, z)
    factors: list[Estimate | None] = [None] * n
    dampings: list[Estimate | None] = [None] * n
    for k, i in enumerate(matched):
        if i is None:
            continue
        m = measured[i]
        hf, hz = 1e-4 * f[k], max(1e-4 * z[k], 1e-6)
        f2, z2 = f.copy(), z.copy()
        f2[k] += hf
        z2[k] += hz
        dw = (hub_free(f2, z)[0][k] - w[k]) / hf
        dz = (hub_free(f, z2)[1][k] - zz[k]) / hz
        factors[k] = Estimate(float(f[k]), m.omega_rad_s.sigma / abs(dw))
        dampings[k] = Estimate(float(z[k]), m.damping_ratio.sigma / abs(dz) if dz else math.inf)
        if abs(w[k] / m.omega_rad_s.value - 1) > 1e-6:
            notes.append(f"mode {k + 1}: the model reaches {w[k]:.5g} rad/s, measured "
                         f"{m.omega_rad_s.value:.5g}")
    return ConstrainedModes(factors, dampings, matched, notes)


# ----------------------------------------------------------------------------- momentum
@dataclass(frozen=True)
class Segment:
    """A stretch of samples with no torque from outside the hub-wheel-beam (no valve, no
    piezo, no rotor): ``excited`` when the beam may ring in it (it follows an excitation)."""

    start_s: float
    end_s: float
    excited: bool


@dataclass(frozen=True)
class Momentum:
    inertia_kg_m2: Estimate | None  # None: fitted without the wheel's speed
    impulses_n_m_s: list[Estimate] | None  # per step, in order (with the inertia)
    rate_steps_rad_s: list[Estimate]  # per step: the hub rate's change (impulse / inertia)
    samples: int
    residual_rms: float


def momentum_exchange(t: np.ndarray, rate: np.ndarray, speed: np.ndarray | None,
                      rotor_inertia_kg_m2: float, segments: Sequence[Segment],
                      steps_s: Sequence[float], modes: Sequence[tuple[float, float]],
                      resolution: float = 0.0) -> Momentum:
    """The hub's inertia J and the impulses of outside torques from the angular momentum
    about the axis, ``J rate + J_r w + beam = H``: every internal torque (the wheel's motor,
    its friction) keeps ``H``; an outside one (a valve) changes it at its step. Over the
    quiet ``segments`` (s) the hub rate is fitted as

        rate = c + s w + sum_j p_j [t > step_j] + beam,

    the beam as a free decay of each mode (omega, zeta) in each excited segment (a cosine
    and a sine times its decay, from the segment's start); then ``J = -J_r / s`` and the
    impulse of step j is ``p_j J``. A constant rate bias is in ``c``. ``speed`` None (no
    wheel): the rate's steps ``p_j`` only."""
    t = np.asarray(t, dtype=float)
    rate = np.asarray(rate, dtype=float)
    ok = np.isfinite(rate) if speed is None else np.isfinite(rate) & np.isfinite(speed)
    rows = []
    for seg in segments:
        sel = np.flatnonzero((t >= seg.start_s) & (t < seg.end_s) & ok)
        if sel.size >= 10:
            rows.append((seg, sel))
    if not rows:
        raise EstimateError("no quiet segment")
    idx = np.concatenate([sel for _, sel in rows])
    n = idx.size
    cols = [np.ones(n)]
    if speed is not None:
        cols.append(np.asarray(speed, dtype=float)[idx])
    first_step = len(cols)
    cols += [(t[idx] > s).astype(float) for s in steps_s]
    row = 0
    for seg, sel in rows:
        if seg.excited:
            tau = t[sel] - seg.start_s
            for omega, zeta in modes:
                wd = omega * math.sqrt(max(1.0 - zeta * zeta, 0.0))
                env = np.exp(-zeta * omega * tau)
                for part in (np.cos(wd * tau), np.sin(wd * tau)):
                    c = np.zeros(n)
                    c[row:row + sel.size] = env * part
                    cols.append(c)
        row += sel.size
    x = np.column_stack(cols)
    beta, cov, e = linear_fit(x, rate[idx], floor=resolution / math.sqrt(12))
    steps = [Estimate(float(beta[first_step + i]),
                      math.sqrt(float(cov[first_step + i, first_step + i])))
             for i in range(len(steps_s))]
    rms = float(np.sqrt(np.mean(e ** 2)))
    if speed is None:
        return Momentum(None, None, steps, n, rms)
    s, var_s = float(beta[1]), float(cov[1, 1])
    if not math.isfinite(s) or not abs(s) > 2.0 * math.sqrt(var_s):
        raise EstimateError(f"the hub rate does not follow the wheel's speed (its share "
                            f"{s:.3g} +- {math.sqrt(var_s):.2g} rad/s per rad/s is no more "
                            "than its noise)")
    jr = float(rotor_inertia_kg_m2)
    impulses = []
    for i in range(len(steps_s)):
        k = first_step + i
        p, var_p, c_ps = float(beta[k]), float(cov[k, k]), float(cov[1, k])
        var = jr * jr * (var_p / s ** 2 + p * p * var_s / s ** 4 - 2 * p * c_ps / s ** 3)
        impulses.append(Estimate(-jr * p / s, math.sqrt(max(var, 0.0))))
    return Momentum(Estimate(-jr / s, jr * math.sqrt(var_s) / (s * s)), impulses, steps, n,
                    rms)


def match_modes(measured: Sequence[float], model: Sequence[float]) -> list[int | None]:
    """Per model mode (ascending rad/s), the index of the measured frequency nearest it in
    log frequency, within half the log distance to its neighbours (the strongest, i.e. the
    first listed, when two fall in one); None where none does."""
    lw = np.log(np.asarray(model, dtype=float))
    n = lw.size
    out: list[int | None] = [None] * n
    for i, w in enumerate(measured):
        x = math.log(w)
        k = int(np.argmin(np.abs(lw - x)))
        lo = -np.inf if k == 0 else 0.5 * (lw[k - 1] + lw[k])
        hi = np.inf if k == n - 1 else 0.5 * (lw[k] + lw[k + 1])
        if lo <= x <= hi and out[k] is None:
            out[k] = i
    return out


# ----------------------------------------------------------------------------- valves
def readback_delay(t: np.ndarray, state: np.ndarray, t_command: float, want: float,
                   period_s: float, until_s: float) -> Estimate | None:
    """The delay from a command taking effect at ``t_command`` to the read-back showing
    ``want``: the read-back answers every ``period_s``, so the change happened in
    (first sample showing it - period, first sample showing it]; the middle of that
    interval (from ``t_command`` on), sigma its width / sqrt(12) (uniform). None when the
    read-back never shows it before ``until_s``."""
    sel = np.flatnonzero((t >= t_command) & (t < until_s))
    hit = sel[state[sel] == want]
    if hit.size == 0:
        return None
    t1 = float(t[hit[0]]) - t_command
    lo = max(t1 - period_s, 0.0)
    return Estimate(0.5 * (lo + t1), (t1 - lo) / math.sqrt(12.0))
