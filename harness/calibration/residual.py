"""Residual vibration of a slew, read two ways (pure functions; shared by ``harness
calibrate`` and the shaped-rig study).

* :func:`fit_modal_residual`: least squares of the identified modes' free decay to the
  recorded tip acceleration over a window (what the lab rig measures with its own
  accelerometer and identified modes; the noise averages out over the window's samples).
* :func:`true_residual`: the virtual rig's noise-free tip acceleration over the window, from
  its own final state (every mode included).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import scipy.linalg as sla

from harness.controllers.shaped_wheel_slew import Mode


def fit_modal_residual(t: np.ndarray, accel: np.ndarray, modes: Sequence[Mode],
                       t0_s: float, with_signal: bool = False) -> dict[str, Any]:
    """Least-squares fit of the modes' free decay to ``accel`` over t >= t0 (pure).

    Model: c + sum_k exp(-zeta w tau) (a_k cos(w_d tau) + b_k sin(w_d tau)), tau = t - t0.
    Returns the peak and rms of the fitted modal part, its worst 1-sigma uncertainty, the
    rms of what the fit leaves (the noise) and, per mode, its amplitude at t0 (the envelope
    sqrt(a_k^2 + b_k^2)) with its 1-sigma (first order). ``with_signal``: also the fitted
    modal signal over the window (``signal``, an array; not JSON)."""
    t = np.asarray(t, dtype=float)
    a = np.asarray(accel, dtype=float)
    sel = t >= t0_s - 1e-9
    if np.count_nonzero(sel) < 4 * len(modes) + 8:
        raise ValueError(f"t0_s {t0_s}: too few samples after it to fit {len(modes)} modes")
    tau, y = t[sel] - t0_s, a[sel]
    cols = [np.ones_like(tau)]
    for m in modes:
        wd = m.omega_rad_s * math.sqrt(1 - m.damping_ratio**2)
        env = np.exp(-m.damping_ratio * m.omega_rad_s * tau)
        cols += [env * np.cos(wd * tau), env * np.sin(wd * tau)]
    x = np.column_stack(cols)
    coef, *_ = np.linalg.lstsq(x, y, rcond=None)
    left = y - x @ coef
    dof = max(1, len(y) - x.shape[1])
    cov = float(left @ left) / dof * np.linalg.inv(x.T @ x)
    xm = x[:, 1:]
    modal = xm @ coef[1:]
    var = np.einsum("ij,jk,ik->i", xm, cov[1:, 1:], xm)
    by_mode = []
    for k in range(len(modes)):
        i = 1 + 2 * k
        ab = coef[i:i + 2]
        amp = float(np.hypot(*ab))
        grad = ab / amp if amp > 0 else np.array([1.0, 0.0]) / math.sqrt(2)
        by_mode.append({"amplitude_m_s2": amp,
                        "sigma_m_s2": float(np.sqrt(grad @ cov[i:i + 2, i:i + 2] @ grad))})
    out: dict[str, Any] = {"peak_m_s2": float(np.max(np.abs(modal))),
                           "rms_m_s2": float(np.sqrt(np.mean(modal**2))),
                           "sigma_m_s2": float(np.sqrt(np.max(var))),
                           "noise_rms_m_s2": float(np.sqrt(float(left @ left) / dof)),
                           "by_mode_at_start": by_mode}
    if with_signal:
        out["signal"] = modal
    return out


def true_residual(rig: Any, t0_s: float, with_signal: bool = False) -> dict[str, Any]:
    """Noise-free tip acceleration of a virtual rig over [t0, its last tick]: its final state
    propagated back to t0 through the free plant, then forward tick by tick (``with_signal``:
    also that signal, ``signal``)."""
    dt = rig.dt_s
    n = int(round((rig.time_s - t0_s) / dt))
    if n < 1:
        raise ValueError(f"t0_s {t0_s}: not before the rig's last tick {rig.time_s}")
    a_cont = rig.rig.plant.a
    c, ad = rig.plant.c[2], rig.plant.ad
    tail = getattr(rig, "truth_tail", None)
    if tail and tail[0][0] <= t0_s + 1e-9:
        # recorded forward (VirtualRig.record_truth_tail): the truth whatever acted on the
        # hub after t0 (friction, gravity), where the free plant's back-propagation below
        # amplifies any input by the modes' damping run backwards
        kept = [(x, y) for t, x, y in tail if t >= t0_s - 1e-9]
        x0 = kept[0][0]
        poles, vec = np.linalg.eig(a_cont)
        share = 2 * np.abs((c @ vec) * np.linalg.solve(vec, x0))
        osc = np.nonzero(poles.imag > 1e-9)[0]
        signal = np.array([y for _, y in kept])
        res = {"peak_m_s2": float(np.max(np.abs(signal))),
               "rms_m_s2": float(np.sqrt(np.mean(signal**2))),
               "by_mode_at_start_m_s2": [float(share[i]) for i in
                                         osc[np.argsort(np.abs(poles[osc]))]]}
        if with_signal:
            res["signal"] = signal
        return res
    x = sla.expm(-a_cont * n * dt) @ rig.x
    # each hub-free mode's share at t0: envelope 2 |c v_i z_i| of its pole pair
    poles, vec = np.linalg.eig(a_cont)
    share = 2 * np.abs((c @ vec) * np.linalg.solve(vec, x))
    osc = np.nonzero(poles.imag > 1e-9)[0]
    by_mode = [float(share[i]) for i in osc[np.argsort(np.abs(poles[osc]))]]
    out = np.empty(n + 1)
    for k in range(n + 1):
        out[k] = c @ x
        x = ad @ x
    res: dict[str, Any] = {"peak_m_s2": float(np.max(np.abs(out))),
                           "rms_m_s2": float(np.sqrt(np.mean(out**2))),
                           "by_mode_at_start_m_s2": by_mode}
    if with_signal:
        res["signal"] = out
    return res
