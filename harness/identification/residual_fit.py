"""The identified modes' residual vibration in a recorded channel, fitted block by block in
bounded memory (pure: arrays in, numbers out).

Model over the window ``t >= t0`` (``tau = t - t0``)::

    y = c + sum_k exp(-zeta_k w_k tau) (a_k cos(w_dk tau) + b_k sin(w_dk tau)) + noise

the least squares of ``harness.calibration.residual.fit_modal_residual``, accumulated as
normal equations (X^T X, X^T y, y^T y) over the blocks, so a run of any length is fitted in
memory bounded by one block. The result is the fitted modal part's peak over the window,
its worst 1-sigma uncertainty (first order, from the residual noise) and each mode's
amplitude at t0: what ``harness calibrate`` measures of a slew, judged by the
``modal_residual:`` criterion (docs/criteria.md).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

EVAL_BLOCK = 65536
"""Points of the modal signal evaluated at once when looking for its peak."""


@dataclass(frozen=True)
class ModalResidual:
    peak: float
    """Peak |fitted modal part| over the window (the channel's unit)."""
    peak_tau_s: float
    """Where it is, after t0 (s)."""
    sigma: float
    """The worst 1-sigma uncertainty of the fitted modal part over the window."""
    noise_rms: float
    """RMS of what the fit leaves (the channel's noise)."""
    amplitudes: tuple[float, ...]
    """Each mode's envelope sqrt(a^2 + b^2) at t0."""
    samples: int


class ModalResidualFit:
    """Feed ``add(t_s, values)`` blocks in time order (t >= t0 only are used), then
    ``result()``. ``modes``: (omega rad/s, damping ratio) pairs."""

    def __init__(self, modes: Sequence[tuple[float, float]], t0_s: float) -> None:
        if not modes:
            raise ValueError("no modes to fit")
        self.modes = [(float(w), float(z)) for w, z in modes]
        self.t0 = float(t0_s)
        m = 1 + 2 * len(self.modes)
        self.xtx = np.zeros((m, m))
        self.xty = np.zeros(m)
        self.yty = 0.0
        self.n = 0
        self.tau_first: float | None = None
        self.tau_last = 0.0

    def basis(self, tau: np.ndarray) -> np.ndarray:
        cols = [np.ones_like(tau)]
        for w, z in self.modes:
            wd = w * math.sqrt(max(0.0, 1.0 - z * z))
            env = np.exp(-z * w * tau)
            cols += [env * np.cos(wd * tau), env * np.sin(wd * tau)]
        return np.column_stack(cols)

    def add(self, t_s: np.ndarray, values: np.ndarray) -> None:
        t = np.asarray(t_s, dtype=float)
        y = np.asarray(values, dtype=float)
        keep = (t >= self.t0 - 1e-9) & np.isfinite(y)
        if not keep.any():
            return
        tau, y = t[keep] - self.t0, y[keep]
        x = self.basis(tau)
        self.xtx += x.T @ x
        self.xty += x.T @ y
        self.yty += float(y @ y)
        self.n += len(y)
        if self.tau_first is None:
            self.tau_first = float(tau[0])
        self.tau_last = float(tau[-1])

    @property
    def needed(self) -> int:
        """Samples a fit needs (four a mode, plus eight)."""
        return 4 * len(self.modes) + 8

    def result(self) -> ModalResidual:
        if self.n < self.needed:
            raise ValueError(f"{self.n} samples after t0 = {self.t0:.3f} s; fitting "
                             f"{len(self.modes)} modes needs {self.needed}")
        try:
            inv = np.linalg.inv(self.xtx)
        except np.linalg.LinAlgError as exc:
            raise ValueError(f"the modes cannot be told apart over this window ({exc})") \
                from exc
        coef = inv @ self.xty
        rss = max(0.0, self.yty - 2.0 * float(coef @ self.xty)
                  + float(coef @ self.xtx @ coef))
        dof = max(1, self.n - len(coef))
        cov = rss / dof * inv
        amps = tuple(float(np.hypot(coef[1 + 2 * k], coef[2 + 2 * k]))
                     for k in range(len(self.modes)))
        # the modal part and its variance on the samples' grid (uniform: the tick), a block
        # of points at a time
        n = self.n
        first = self.tau_first or 0.0
        step = (self.tau_last - first) / (n - 1) if n > 1 else 0.0
        peak, at, var_max = 0.0, first, 0.0
        for i0 in range(0, n, EVAL_BLOCK):
            tau = first + step * np.arange(i0, min(n, i0 + EVAL_BLOCK))
            xm = self.basis(tau)[:, 1:]
            modal = xm @ coef[1:]
            i = int(np.argmax(np.abs(modal)))
            if abs(modal[i]) > peak:
                peak, at = float(abs(modal[i])), float(tau[i])
            var = np.einsum("ij,jk,ik->i", xm, cov[1:, 1:], xm)
            var_max = max(var_max, float(np.max(var)))
        return ModalResidual(peak, at, math.sqrt(var_max), math.sqrt(rss / dof), amps, n)
