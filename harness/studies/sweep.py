"""The frequency-ratio / amplitude-ratio sweep of paper 003 on the rig model (no bus).

For each lambda the rotor spins at w = lambda w_ref and puts A sin(w t) on the hub
(A = m_m P_m sigma_m w^2); the ideal wheel answers -beta A sign(sin(w t)) (the paper assumes
an ideal square wave here). The hub-beam model is stepped exactly (ZOH) with every beta of the
grid at once (one state column per beta), until the free transient has died, and the
steady-state amplitudes of the tip acceleration and of the tip's elastic deflection are taken
from a harmonic fit over whole periods (``harness.core.periodic``). Lambdas are spread over worker
processes or a Dask cluster (``harness.engine``).

``harmonic_steady_state`` gives the same steady state in closed form (sum of the square
wave's harmonics through the plant's frequency response); the tests check one against the
other.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from harness.core.periodic import steady_state_amplitude
from harness.engine import Engine, make_engine
from rig_models.flexible_hub import HubBeamModel


@dataclass(frozen=True)
class SweepSpec:
    lambdas: np.ndarray
    betas: np.ndarray
    omega_ref_rad_s: float
    mass_kg: float
    eccentricity_m: float
    dish_radius_m: float
    dt_s: float = 0.004
    settle_s: float = 60.0  # free transient allowed to die out
    periods: int = 5  # steady-state window

    def amplitude_n_m(self, omega: float) -> float:
        return self.mass_kg * self.dish_radius_m * self.eccentricity_m * omega**2


def _outputs(model: HubBeamModel) -> tuple[np.ndarray, np.ndarray]:
    """Rows of (C, D) for tip acceleration and tip elastic deflection phi(L) eta."""
    n = model.n_modes
    c_acc, d_acc = model.c[2], model.d[2]
    c_def = np.zeros(model.n_states)
    c_def[1 : 1 + n] = model.modes.tip_deflection
    return np.vstack([c_acc, c_def]), np.vstack([d_acc, np.zeros_like(d_acc)])


def simulate_lambdas(model: HubBeamModel, spec: SweepSpec, lams: np.ndarray) -> np.ndarray:
    """Steady amplitudes [lambda, beta, (accel m/s^2, deflection m)] for a batch of lambdas,
    every (lambda, beta) pair one column of the state matrix, stepped together."""
    lams = np.atleast_1d(np.asarray(lams, dtype=float))
    nb, nl = len(spec.betas), len(lams)
    omegas = lams * spec.omega_ref_rad_s
    periods = 2 * math.pi / omegas
    ends = spec.settle_s + spec.periods * periods
    d = model.discretise(spec.dt_s)
    c_out, d_out = _outputs(model)
    n_steps = int(math.ceil(ends.max() / spec.dt_s))
    t = np.arange(n_steps) * spec.dt_s
    first = int(math.floor(spec.settle_s / spec.dt_s))
    amps = spec.amplitude_n_m(omegas)  # (nl,)
    betas = spec.betas
    x = np.zeros((model.n_states, nl * nb))
    ys = np.empty((n_steps - first, 2, nl * nb))
    b_hub = d.bd[:, 0:1]
    ad = d.ad
    d_hub = d_out[:, 0:1]
    for k in range(n_steps):
        # input held over [t_k, t_k+1]: evaluate at the interval's middle
        s = np.sin(omegas * (t[k] + 0.5 * spec.dt_s))  # (nl,)
        torque = ((amps * s)[:, None] - np.outer(np.sign(s) * amps, betas)).ravel()
        if k >= first:
            ys[k - first] = c_out @ x + d_hub * torque
        x = ad @ x + b_hub * torque
    out = np.empty((nl, nb, 2))
    tt = t[first:]
    for i in range(nl):
        sel = tt <= ends[i] + 1e-9
        for j in range(nb):
            for o in range(2):
                out[i, j, o] = steady_state_amplitude(
                    tt[sel], ys[sel, o, i * nb + j], omegas[i], spec.periods * periods[i],
                    n_harmonics=25)
    return out


def simulate_lambda(model: HubBeamModel, spec: SweepSpec, lam: float) -> np.ndarray:
    """Steady amplitudes [beta, (accel, deflection)] for one lambda."""
    return simulate_lambdas(model, spec, np.array([lam]))[0]


def harmonic_steady_state(model: HubBeamModel, omega: float, amp: float, beta: float,
                          n_harmonics: int = 401) -> tuple[float, float]:
    """Closed-form steady amplitudes (accel, deflection) for disturbance A sin(wt) and
    compensation -beta A sign(sin(wt)), through the plant's frequency response."""
    c_out, d_out = _outputs(model)
    tt = np.linspace(0, 2 * math.pi / omega, 4096, endpoint=False)
    y = np.zeros((2, len(tt)))
    eye = np.eye(model.n_states)
    for k in range(1, n_harmonics + 1, 2):
        coef = (-4 * beta * amp / (math.pi * k)) + (amp if k == 1 else 0.0)  # sin(k w t)
        h = c_out @ np.linalg.solve(1j * k * omega * eye - model.a, model.b[:, 0]) + d_out[:, 0]
        y += coef * np.imag(np.outer(h, np.exp(1j * k * omega * tt)))
    return (float(0.5 * np.ptp(y[0])), float(0.5 * np.ptp(y[1])))


def _worker(args: tuple[HubBeamModel, SweepSpec, np.ndarray]) -> np.ndarray:
    return simulate_lambdas(*args)


def run_sweep(model: HubBeamModel, spec: SweepSpec, workers: int | None = None,
              progress: Callable[[int, int], None] | None = None,
              batch: int = 4, engine: Engine | None = None) -> np.ndarray:
    """Amplitudes [lambda, beta, (accel, deflection)]: batches of lambdas spread over an
    engine (``harness.engine``: ``workers`` local processes by default, or a Dask
    cluster)."""
    out = np.empty((len(spec.lambdas), len(spec.betas), 2))
    idx = np.arange(len(spec.lambdas))
    chunks = [idx[i : i + batch] for i in range(0, len(idx), batch)]
    own = engine is None
    if engine is None:
        engine = make_engine(workers=workers, preload=("harness.studies.sweep",))
    try:
        futures = [engine.submit(_worker, (model, spec, spec.lambdas[c])) for c in chunks]
        done = 0
        for c, fut in zip(chunks, futures, strict=True):
            out[c] = fut.result()
            done += len(c)
            if progress:
                progress(done, len(idx))
    except BaseException:
        engine.stop()
        raise
    finally:
        if own:
            engine.close()
    return out
