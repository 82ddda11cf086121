"""Component synthesis vibration suppression (CSVS) commands (Hu 2006, section 4).

For a mode ``xddot + 2 zeta w xdot + w^2 x = F(t)`` (eq 4) with damped period
``T_d = 2 pi / (w sqrt(1 - zeta^2))``:

* lemma 1: ``n`` similar components at ``0, T_d/n, ..., (n-1) T_d/n`` with amplitudes scaled by
  the attenuation factor ``exp(-zeta w t_k)`` cancel the mode (zero-order robust);
* lemma 2: synthesising (convolving) a p-th-order robust command with a lemma-1 sequence of the
  same mode gives (p+1)-th-order robustness to frequency error;
* lemma 3: convolving with a lemma-1 sequence of another mode adds that mode.

A command is a ``ComponentSequence`` (times, amplitudes summing to one); applied to a base
command ``c(t)`` it gives ``sum_k a_k c(t - t_k)``. The paper's command is "second-order robust
with four components for mode 1" (``robust_sequence(w1, z1, 2, order=2)``: three convolutions of a
two-component sequence, components at 0, T/2, T, 3T/2) and "zero-order robust with two components
for mode 2" (``robust_sequence(w2, z2, 2, order=0)``).

``CSVSShaper`` applies a sequence to a sampled signal (``reset()``/``step(value, dt)``); in the
thruster loop it sits either on the attitude reference, ahead of PD + PWPF (the paper's "shaped
command"), or on the PD torque demand just before the PWPF modulator.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class ComponentSequence:
    """CSVS components: start times (s, ascending, first 0) and amplitudes (sum 1)."""

    times: np.ndarray
    amplitudes: np.ndarray

    def __post_init__(self) -> None:
        t = np.asarray(self.times, dtype=float)
        a = np.asarray(self.amplitudes, dtype=float)
        if t.ndim != 1 or t.shape != a.shape or t.size == 0:
            raise ValueError("times and amplitudes must be 1-D arrays of the same non-zero length")
        if np.any(np.diff(t) <= 0) or t[0] < 0:
            raise ValueError("times must be non-negative and strictly increasing")
        object.__setattr__(self, "times", t)
        object.__setattr__(self, "amplitudes", a)

    @property
    def duration(self) -> float:
        """Time of the last component (s): the delay the command adds."""
        return float(self.times[-1])

    @property
    def n_components(self) -> int:
        return int(self.times.size)

    def convolve(self, other: ComponentSequence, merge_tol: float = 1e-9) -> ComponentSequence:
        """Synthesis of two commands (lemmas 2 and 3): all pairwise time sums, amplitude
        products; components at coinciding times are merged."""
        t = (self.times[:, None] + other.times[None, :]).ravel()
        a = (self.amplitudes[:, None] * other.amplitudes[None, :]).ravel()
        order = np.argsort(t, kind="stable")
        t, a = t[order], a[order]
        times: list[float] = []
        amps: list[float] = []
        for ti, ai in zip(t, a, strict=True):
            if times and ti - times[-1] <= merge_tol * max(1.0, abs(ti)):
                amps[-1] += ai
            else:
                times.append(float(ti))
                amps.append(float(ai))
        return ComponentSequence(np.array(times), np.array(amps))

    def apply(self, base, t: np.ndarray | float) -> np.ndarray:
        """Shaped command ``sum_k a_k base(t - t_k)`` for a vectorised ``base(t)`` that is
        zero (or its initial value) for negative arguments."""
        t = np.asarray(t, dtype=float)
        return sum(a * np.asarray(base(t - tk)) for tk, a in zip(self.times, self.amplitudes,
                                                                 strict=True))


def _check_mode(freq_rad_s: float, zeta: float) -> None:
    if not math.isfinite(freq_rad_s) or freq_rad_s <= 0:
        raise ValueError(f"freq_rad_s must be a positive natural frequency, got {freq_rad_s!r}")
    if not math.isfinite(zeta) or not 0 <= zeta < 1:
        raise ValueError(f"zeta must be a damping ratio in [0, 1), got {zeta!r}")


def damped_period(freq_rad_s: float, zeta: float) -> float:
    """``T_d = 2 pi / (w sqrt(1 - zeta^2))`` (s)."""
    _check_mode(freq_rad_s, zeta)
    return 2 * math.pi / (freq_rad_s * math.sqrt(1 - zeta**2))


def lemma1_sequence(freq_rad_s: float, zeta: float, n_components: int) -> ComponentSequence:
    """Lemma 1: ``n`` components at ``k T_d / n`` scaled by ``exp(-zeta w t_k)``, normalised
    to unit sum (zero-order robust)."""
    _check_mode(freq_rad_s, zeta)
    if int(n_components) != n_components or n_components < 2:
        raise ValueError(f"n_components must be an integer >= 2, got {n_components!r}")
    n = int(n_components)
    times = np.arange(n) * damped_period(freq_rad_s, zeta) / n
    amps = np.exp(-zeta * freq_rad_s * times)
    return ComponentSequence(times, amps / amps.sum())


def robust_sequence(
    freq_rad_s: float, zeta: float, n_components: int, order: int
) -> ComponentSequence:
    """Lemma 2: ``order``-th-order robust command, the lemma-1 sequence synthesised with itself
    ``order`` times (``order = 0`` is lemma 1)."""
    if int(order) != order or order < 0:
        raise ValueError(f"order (of robustness) must be a non-negative integer, got {order!r}")
    base = lemma1_sequence(freq_rad_s, zeta, n_components)
    seq = base
    for _ in range(int(order)):
        seq = seq.convolve(base)
    return seq


@dataclass(frozen=True)
class ModeDesign:
    """One mode of a CSVS design: frequency (rad/s), damping ratio, components per lemma-1
    stage and order of robustness."""

    freq_rad_s: float
    zeta: float
    n_components: int = 2
    order: int = 0


def multimode_sequence(modes: Sequence[ModeDesign]) -> ComponentSequence:
    """Lemma 3: synthesis of the robust sequences of several modes."""
    if len(modes) == 0:
        raise ValueError("modes must list at least one ModeDesign")
    seq: ComponentSequence | None = None
    for m in modes:
        s = robust_sequence(m.freq_rad_s, m.zeta, m.n_components, m.order)
        seq = s if seq is None else seq.convolve(s)
    assert seq is not None
    return seq


def residual_factor(
    seq: ComponentSequence, freq_rad_s: float, zeta: float, derivative: int = 0
) -> complex:
    """``d^j S / d w^j`` of ``S(w) = sum_k a_k exp((zeta w - i w_d) t_k)`` (zeta fixed).

    The response of eq (4) to impulse components is, after the last one,
    ``X(t) = Im[exp((-zeta w + i w_d) t) S(w)] / w_d``; so ``X`` and its first ``p`` frequency
    derivatives vanish for all ``t > t_f`` exactly when ``S`` has a zero of order ``p + 1``.
    """
    _check_mode(freq_rad_s, zeta)
    c = zeta - 1j * math.sqrt(1 - zeta**2)
    t = seq.times
    return complex(np.sum(seq.amplitudes * (c * t) ** derivative * np.exp(c * freq_rad_s * t)))


def residual_vibration(seq: ComponentSequence, freq_rad_s: float, zeta: float) -> float:
    """Residual vibration amplitude after the command, relative to that of a single unit
    impulse applied at the last component's time (0 = fully cancelled, 1 = unshaped)."""
    _check_mode(freq_rad_s, zeta)
    total = float(np.sum(seq.amplitudes))
    s = residual_factor(seq, freq_rad_s, zeta)
    return abs(s) * math.exp(-zeta * freq_rad_s * seq.duration) / abs(total)


def robustness_order(
    seq: ComponentSequence, freq_rad_s: float, zeta: float, max_order: int = 8, tol: float = 1e-9
) -> int:
    """Largest ``n`` with ``d^j S/dw^j = 0`` for ``j <= n`` (relative to the scale of the
    terms); ``-1`` if the mode is not cancelled at all."""
    order = -1
    for j in range(max_order + 1):
        scale = float(np.sum(np.abs(seq.amplitudes) * (seq.times + 1e-300) ** j *
                             np.exp(zeta * freq_rad_s * seq.times)))
        if abs(residual_factor(seq, freq_rad_s, zeta, j)) <= tol * max(scale, 1e-300):
            order = j
        else:
            break
    return order


class CSVSShaper:
    """Streaming CSVS filter: ``y(t) = sum_k a_k u(t - t_k)`` on a sampled signal (values
    held between samples; before the first sample the input is ``initial_value``)."""

    def __init__(self, seq: ComponentSequence, initial_value: float = 0.0) -> None:
        self.seq = seq
        self.initial_value = float(initial_value)
        self.reset()

    def reset(self) -> None:
        self._t = 0.0
        self._times: list[float] = []
        self._values: list[float] = []

    def _value_at(self, t: float) -> float:
        i = bisect.bisect_right(self._times, t + 1e-9) - 1
        return self._values[i] if i >= 0 else self.initial_value

    def step(self, value: float, dt: float) -> float:
        if not dt > 0:
            raise ValueError(f"dt must be positive (s), got {dt!r}")
        self._times.append(self._t)
        self._values.append(float(value))
        out = 0.0
        for tk, a in zip(self.seq.times, self.seq.amplitudes, strict=True):
            out += a * self._value_at(self._t - tk)
        # drop history older than the longest delay (keep one sample before it)
        horizon = self._t - self.seq.duration
        cut = bisect.bisect_right(self._times, horizon) - 2
        if cut > 64 and horizon > 0:
            del self._times[:cut]
            del self._values[:cut]
        self._t += dt
        return out


def shaped_step(step_size: float, seq: ComponentSequence):
    """Staircase reference ``step_size * sum_k a_k H(t - t_k)`` as a vectorised function."""

    def reference(t):
        return seq.apply(lambda tau: step_size * (np.asarray(tau) >= 0), t)

    return reference
