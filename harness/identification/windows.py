"""Several free-decay windows of one record: modes that decay at very different rates.

One long free decay after all the excitation identifies the slow modes well, but a fast
mode (SGSRT mode 3: 36.9 rad/s, zeta 0.05, time constant 0.54 s) has rung down before the
slow modes' excitation is over, and the wheel's torque limit caps its resonant tip response
at about 0.014 m/s^2, three times the accelerometer's noise (0.005 m/s^2 rms): one 2 s
decay gives its frequency to about 0.5 % and its damping to about 10 % (1 sigma). So the
free-decay run excites it on its own, seven times, each burst followed by a short free decay
(run file: ``free_decay_s`` and ``repeat`` of a ``wheel_bursts`` burst), and
``identify_windows`` analyses every free-decay window on its own:

1. Each window (``AnalysisWindow``: start, end, and the nominal frequency of the burst
   before it, which only groups windows) is fitted by ``identify`` (matrix pencil + NLS,
   every significant mode in the window fitted together; FFT peaks of the window).
2. With several windows, a window's component takes part only if it is determined there
   (``_determined_in_window``: frequency to 5 %, damping in (0, 0.5) and to 50 %, 1 sigma);
   the rest (a short window's fit of noise or drift) is listed in the notes.
3. Windows after bursts of the same nominal frequency are repetitions of one experiment.
   Their estimates of a mode (frequencies within ``MATCH_SIGMAS`` combined sigma or
   ``MATCH_REL``, never two from one window) are combined: equal-weight mean of frequency,
   damping and amplitude (see ``_mean_of_repetitions`` for why not inverse-variance), whose
   1-sigma is scaled up by the Birge ratio sqrt(chi^2 / dof) when the repetitions scatter
   more than their own sigmas say (never scaled down). The final window (to the end of the
   record) is always an experiment of its own, as is every window without a burst frequency.
   With three repetitions or more, a mode must be found in at least half of them (a noise
   component of one short window is not reproduced by the others).
   Each mode is reported from the experiment that determines its frequency best (smallest
   relative 1-sigma); the same mode seen less well by other experiments (within 3 sigma,
   3 %, or the better estimate's half-power half-width zeta w) is listed in ``also_seen``
   and not averaged in.
4. Second pass: every window that does not show one of the modes so identified is fitted
   again with that mode held at its frequency and damping, only its amplitude and phase
   free (``fit_free_decay(known_modes=...)``), and steps 2-3 are repeated. A leftover below
   a window's own detection threshold (SGSRT: mode 1 and 2 at ~0.002-0.004 m/s^2 in the
   mode-3 windows, mode 3 at ~0.003 m/s^2 at the start of the long decay) otherwise biases
   the modes fitted there: on the virtual rig's noise-free record with 60 noise
   realisations added, mode 3's damping came out 1-3 % low without this pass (depending on
   the burst length) and mode 2's frequency 0.4 sigma low; with it every mean error is
   below 0.25 sigma.

No frequency is assumed: windows come from the run's burst schedule, modes from the data.

The FFT view of a short window is coarse: a 1.9 s window has a Rayleigh resolution of
3.3 rad/s, about mode 3's half-power bandwidth (3.7 rad/s), so its peak frequency (the mean
over the repetitions) and its half-power damping are rough; ``MultiWindowResult.notes`` says
so for every mode whose half-power bandwidth spans fewer than ``SHORT_WINDOW_RESOLUTIONS``
Rayleigh resolutions of its windows.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from harness.identification.api import IdentificationResult, identify
from harness.identification.decay_fit import KNOWN_MATCH_REL, IdentifiedMode

MATCH_SIGMAS = 3.0  # two estimates are one mode within this many combined sigma ...
MATCH_REL = 0.03  # ... or within this relative frequency difference
# With several windows, a reported mode must be determined (see ``_determined``):
MAX_REL_SIGMA = 0.05  # 1-sigma of its frequency at most this fraction of it
MAX_REL_SIGMA_DAMPING = 0.5  # 1-sigma of its damping ratio at most this fraction of it
MAX_DAMPING = 0.5  # damping ratio below this (above: a short window's drift, not a mode)
SHORT_WINDOW_RESOLUTIONS = 2.0  # FFT view "rough" if the peak spans fewer resolutions


@dataclass(frozen=True)
class AnalysisWindow:
    """A free decay inside a record: [start_s, end_s) (end None: to the record's end).

    ``burst_omega_rad_s``: nominal frequency of the excitation before it (None: unknown);
    bounded windows (``end_s`` given) with the same value are repetitions of one experiment
    and are combined."""

    start_s: float
    end_s: float | None = None
    burst_omega_rad_s: float | None = None

    def label(self) -> str:
        end = "end" if self.end_s is None else f"{self.end_s:.2f}"
        return f"[{self.start_s:.2f}, {end}) s"


@dataclass(frozen=True)
class WindowedMode:
    """A mode combined over the windows of one experiment (1-sigma after Birge scaling)."""

    omega_rad_s: float
    damping_ratio: float
    sigma_omega_rad_s: float
    sigma_damping: float
    amplitude: float  # m/s^2 at the start of a window (mean over the windows)
    sigma_amplitude: float
    experiment: int  # index into MultiWindowResult.experiments
    windows: tuple[int, ...]  # indices into MultiWindowResult.windows
    birge_ratio_omega: float  # sqrt(chi^2/dof) of the repetitions (1.0 with one window)
    birge_ratio_damping: float
    fft_peak_omega_rad_s: float | None  # mean FFT peak over the windows that show it
    fft_damping_half_power_rough: float | None
    fft_rough: bool  # the windows are too short for the FFT view to resolve the peak
    also_seen: tuple[tuple[int, float, float], ...] = ()  # (experiment, omega, sigma_omega)
    phase_rad: float | None = None  # at the window's start; one window only
    sigma_phase_rad: float | None = None

    @property
    def freq_hz(self) -> float:
        return self.omega_rad_s / (2.0 * np.pi)

    @property
    def sigma_freq_hz(self) -> float:
        return self.sigma_omega_rad_s / (2.0 * np.pi)

    @property
    def omega_damped_rad_s(self) -> float:
        return self.omega_rad_s * float(np.sqrt(max(1.0 - self.damping_ratio**2, 0.0)))


@dataclass
class MultiWindowResult:
    """Modes of several free-decay windows. ``modes``: one per physical mode, by frequency."""

    modes: list[WindowedMode]
    windows: list[AnalysisWindow]
    results: list[IdentificationResult]  # one per window
    experiments: list[tuple[int, ...]]  # window indices of each experiment
    notes: list[str] = field(default_factory=list)

    @property
    def primary(self) -> IdentificationResult:
        """The longest window's result (the long free decay)."""
        return max(self.results, key=lambda r: r.duration_s)

    def experiment_label(self, k: int) -> str:
        idx = self.experiments[k]
        w = self.windows[idx[0]]
        dur = np.mean([self.results[i].duration_s for i in idx])
        after = ("" if w.burst_omega_rad_s is None
                 else f" after {w.burst_omega_rad_s:g} rad/s bursts")
        if len(idx) == 1:
            return f"{dur:.1f} s window {w.label()}{after}"
        return f"{len(idx)} x {dur:.1f} s windows{after}"

    def to_dict(self) -> dict[str, Any]:
        modes = []
        for m in self.modes:
            modes.append({
                "omega_rad_s": m.omega_rad_s,
                "freq_hz": m.freq_hz,
                "omega_damped_rad_s": m.omega_damped_rad_s,
                "damping_ratio": m.damping_ratio,
                "amplitude_m_s2": m.amplitude,
                "sigma_omega_rad_s": m.sigma_omega_rad_s,
                "sigma_freq_hz": m.sigma_freq_hz,
                "sigma_damping": m.sigma_damping,
                "sigma_amplitude_m_s2": m.sigma_amplitude,
                "phase_rad": m.phase_rad,
                "sigma_phase_rad": m.sigma_phase_rad,
                "fft_peak_omega_rad_s": m.fft_peak_omega_rad_s,
                "fft_damping_half_power_rough": m.fft_damping_half_power_rough,
                "fft_rough": m.fft_rough,
                "source": {
                    "experiment": self.experiment_label(m.experiment),
                    "windows": list(m.windows),
                    "n_windows": len(m.windows),
                    "birge_ratio_omega": m.birge_ratio_omega,
                    "birge_ratio_damping": m.birge_ratio_damping,
                },
                "also_seen": [
                    {"experiment": self.experiment_label(k), "omega_rad_s": w,
                     "sigma_omega_rad_s": s}
                    for k, w, s in m.also_seen
                ],
            })
        windows = []
        for w, r in zip(self.windows, self.results, strict=True):
            windows.append({
                "start_s": w.start_s,
                "end_s": w.end_s,
                "burst_omega_rad_s": w.burst_omega_rad_s,
                "fit_start_s": r.fit_start_s,
                "duration_s": r.duration_s,
                "n_clipped": r.n_clipped,
                "fft_resolution_rad_s": 2.0 * np.pi * r.spectrum.resolution_hz,
                "noise_rms_estimate_m_s2": r.fit.noise_rms_estimate,
                "modes": [
                    {"omega_rad_s": m.omega_rad_s, "sigma_omega_rad_s": m.sigma_omega_rad_s,
                     "damping_ratio": m.damping_ratio, "sigma_damping": m.sigma_damping,
                     "amplitude_m_s2": m.amplitude}
                    for m in r.fit.modes
                ],
                "held_modes": [
                    {"omega_rad_s": m.omega_rad_s, "damping_ratio": m.damping_ratio,
                     "amplitude_m_s2": m.amplitude, "sigma_amplitude_m_s2": m.sigma_amplitude}
                    for m in r.fit.fixed_modes
                ],
                "notes": list(r.notes),
            })
        return {"modes": modes, "windows": windows, "notes": list(self.notes)}


def _same_mode(w1: float, s1: float, w2: float, s2: float, zeta: float = 0.0) -> bool:
    """Within MATCH_SIGMAS combined sigma, MATCH_REL, or (``zeta`` of the better-known
    estimate) the half-power half-width zeta w: closer than that, windows that each show
    one of two modes could not tell them apart."""
    return abs(w1 - w2) <= max(MATCH_SIGMAS * float(np.hypot(s1, s2)),
                               max(MATCH_REL, zeta) * min(w1, w2))


def _mean_of_repetitions(values: np.ndarray, sigmas: np.ndarray) -> tuple[float, float, float]:
    """Equal-weight mean of repetitions, its 1-sigma (scaled up by the Birge ratio if > 1),
    and the Birge ratio sqrt(chi^2 / dof) of the scatter against the windows' own sigmas.

    Equal weights: the repetitions are the same experiment, so their true sigmas are equal;
    weighting by each window's own sigma would favour the windows whose noise made the
    mode look less damped (a lower fitted damping gives a smaller sigma) and bias the mean."""
    n = values.size
    mean = float(np.mean(values))
    sigma = float(np.sqrt(np.sum(sigmas**2))) / n
    if n < 2:
        return mean, sigma, 1.0
    birge = float(np.sqrt(np.sum(((values - mean) / np.maximum(sigmas, np.finfo(float).tiny))
                                 ** 2) / (n - 1)))
    return mean, sigma * max(birge, 1.0), birge


def _combine(
    experiment: int,
    members: list[tuple[int, IdentifiedMode]],
    results: list[IdentificationResult],
) -> WindowedMode:
    omega, s_omega, b_omega = _mean_of_repetitions(
        np.array([m.omega_rad_s for _, m in members]),
        np.array([m.sigma_omega_rad_s for _, m in members]))
    zeta, s_zeta, b_zeta = _mean_of_repetitions(
        np.array([m.damping_ratio for _, m in members]),
        np.array([m.sigma_damping for _, m in members]))
    first = members[0][1]
    amp, s_amp, _ = _mean_of_repetitions(
        np.array([m.amplitude for _, m in members]),
        np.array([m.sigma_amplitude for _, m in members]))
    peaks, zetas, rough = [], [], False
    for i, m in members:
        res = results[i]
        peak = res.matching_fft_peak(m)
        # the FFT view resolves a decaying peak if its half-power bandwidth (2 zeta w)
        # spans SHORT_WINDOW_RESOLUTIONS Rayleigh resolutions of the window or more
        resolution = 2.0 * np.pi * res.spectrum.resolution_hz
        if SHORT_WINDOW_RESOLUTIONS * resolution > 2.0 * m.damping_ratio * m.omega_rad_s:
            rough = True
        if peak is not None:
            peaks.append(peak.omega_rad_s)
            if peak.damping_ratio_half_power_rough is not None:
                zetas.append(peak.damping_ratio_half_power_rough)
    return WindowedMode(
        omega_rad_s=omega,
        damping_ratio=zeta,
        sigma_omega_rad_s=s_omega,
        sigma_damping=s_zeta,
        amplitude=amp,
        sigma_amplitude=s_amp,
        experiment=experiment,
        windows=tuple(i for i, _ in members),
        birge_ratio_omega=b_omega,
        birge_ratio_damping=b_zeta,
        fft_peak_omega_rad_s=float(np.mean(peaks)) if peaks else None,
        fft_damping_half_power_rough=float(np.mean(zetas)) if zetas else None,
        fft_rough=rough,
        phase_rad=first.phase_rad if len(members) == 1 else None,
        sigma_phase_rad=first.sigma_phase_rad if len(members) == 1 else None,
    )


def _experiment_modes(
    experiment: int, window_idx: Sequence[int], results: list[IdentificationResult],
    screen: bool,
) -> list[WindowedMode]:
    """Cluster the windows' estimates into modes (never two from one window), combine.
    ``screen``: only estimates that ``_determined_in_window`` accepts take part (an
    undetermined one would weigh as much as the others in the equal-weight mean)."""
    clusters: list[list[tuple[int, IdentifiedMode]]] = []
    for i in window_idx:
        own = [m for m in results[i].fit.modes if not screen or _determined_in_window(m)]
        for m in sorted(own, key=lambda m: m.sigma_omega_rad_s / m.omega_rad_s):
            best, best_d = None, np.inf
            for c in clusters:
                if any(j == i for j, _ in c):
                    continue
                ref = min((x for _, x in c), key=lambda x: x.sigma_omega_rad_s)
                if _same_mode(m.omega_rad_s, m.sigma_omega_rad_s, ref.omega_rad_s,
                              ref.sigma_omega_rad_s):
                    d = abs(m.omega_rad_s - ref.omega_rad_s)
                    if d < best_d:
                        best, best_d = c, d
            if best is None:
                clusters.append([(i, m)])
            else:
                best.append((i, m))
    return [_combine(experiment, c, results) for c in clusters]


def _experiments(windows: Sequence[AnalysisWindow]) -> list[tuple[int, ...]]:
    """Window indices of each experiment: bounded windows after bursts of the same nominal
    frequency together; every other window on its own."""
    experiments: list[tuple[int, ...]] = []
    keys: dict[tuple[float, bool], int] = {}
    for k, w in enumerate(windows):
        key = None if w.burst_omega_rad_s is None else (w.burst_omega_rad_s, w.end_s is None)
        if key is not None and key in keys:
            experiments[keys[key]] = (*experiments[keys[key]], k)
        else:
            if key is not None:
                keys[key] = len(experiments)
            experiments.append((k,))
    return experiments


def _merge(
    experiments: list[tuple[int, ...]],
    results: list[IdentificationResult],
    screen: bool,
) -> tuple[list[WindowedMode], list[WindowedMode]]:
    """(modes by frequency, screened-out components): each mode from the experiment that
    determines its frequency best. ``screen``: leave out components that ``_determined``
    refuses."""
    cands = [m for e, idx in enumerate(experiments)
             for m in _experiment_modes(e, idx, results, screen)]
    rejected = []
    if screen:
        rejected = [m for m in cands if not _determined(m, len(experiments[m.experiment]))]
        cands = [m for m in cands if _determined(m, len(experiments[m.experiment]))]
    cands.sort(key=lambda m: m.sigma_omega_rad_s / m.omega_rad_s)
    accepted: list[WindowedMode] = []
    seen: dict[int, list[tuple[int, float, float]]] = {}
    for m in cands:
        twin = next((j for j, a_ in enumerate(accepted)
                     if _same_mode(m.omega_rad_s, m.sigma_omega_rad_s, a_.omega_rad_s,
                                   a_.sigma_omega_rad_s, a_.damping_ratio)), None)
        if twin is None:
            seen[len(accepted)] = []
            accepted.append(m)
        else:
            seen[twin].append((m.experiment, m.omega_rad_s, m.sigma_omega_rad_s))
    modes = sorted((replace(m, also_seen=tuple(seen[j])) for j, m in enumerate(accepted)),
                   key=lambda m: m.omega_rad_s)
    return modes, rejected


def _determined_in_window(m: IdentifiedMode | WindowedMode) -> bool:
    """Frequency known to MAX_REL_SIGMA, damping in (0, MAX_DAMPING) and known to
    MAX_REL_SIGMA_DAMPING (1 sigma)."""
    return (m.sigma_omega_rad_s <= MAX_REL_SIGMA * m.omega_rad_s
            and 0.0 < m.damping_ratio < MAX_DAMPING
            and m.sigma_damping <= MAX_REL_SIGMA_DAMPING * m.damping_ratio)


def _determined(m: WindowedMode, n_repetitions: int) -> bool:
    """Determined once combined, and, with three repetitions or more, found in at least
    half of them (a noise component of one short window is not reproduced by the others)."""
    return _determined_in_window(m) and (n_repetitions < 3
                                         or 2 * len(m.windows) >= n_repetitions)


def identify_windows(
    t: np.ndarray,
    accel: np.ndarray,
    windows: Sequence[AnalysisWindow],
    *,
    n_modes: int | None = None,
    f_max_hz: float | None = None,
    **kwargs: Any,
) -> MultiWindowResult:
    """Identify the modes of several free-decay ``windows`` of one record (see the module
    docstring). ``n_modes``: report the ``n_modes`` lowest modes (each window still fits
    every significant mode it holds; with a single window it is passed on to ``identify``,
    whose result is then reported unchanged). Other keyword arguments go to ``identify``."""
    t = np.asarray(t, dtype=float)
    a = np.asarray(accel, dtype=float)
    return identify_window_segments([(t, a)] * len(windows), windows, n_modes=n_modes,
                                    f_max_hz=f_max_hz, **kwargs)


def identify_window_segments(
    segments: Sequence[tuple[np.ndarray, np.ndarray]],
    windows: Sequence[AnalysisWindow],
    *,
    n_modes: int | None = None,
    f_max_hz: float | None = None,
    **kwargs: Any,
) -> MultiWindowResult:
    """``identify_windows`` with each window's own samples: ``segments[k]`` is (t, accel) of
    a stretch of the record that holds window k's samples (those in [start_s, end_s), or
    from start_s on when end_s is None: a segment may end before the record does, and the
    window then ends with it). A record need not be held whole to be identified: only the
    samples of its windows."""
    if not windows:
        raise ValueError("windows must hold at least one AnalysisWindow")
    if len(segments) != len(windows):
        raise ValueError(f"{len(segments)} segments for {len(windows)} windows")
    several = len(windows) > 1

    def run(k: int, known: Sequence[tuple[float, float]] = ()) -> IdentificationResult:
        w = windows[k]
        t, a = segments[k]
        try:
            return identify(t, a, start_s=w.start_s, end_s=w.end_s, f_max_hz=f_max_hz,
                            n_modes=None if several else n_modes, known_modes=known, **kwargs)
        except ValueError as exc:
            raise ValueError(f"window {k} {w.label()}: {exc}") from exc

    results = [run(k) for k in range(len(windows))]
    experiments = _experiments(windows)
    modes, rejected = _merge(experiments, results, several)
    if several:
        # second pass: every mode identified is held in the windows that do not show it
        known = [(m.omega_rad_s, m.damping_ratio) for m in modes]
        for k, res in enumerate(results):
            missing = [kn for kn in known if not any(
                abs(f.omega_rad_s - kn[0]) <= KNOWN_MATCH_REL * kn[0] for f in res.fit.modes)]
            if missing:
                results[k] = run(k, known)
        modes, rejected = _merge(experiments, results, several)
    notes = [f"window {k} {w.label()}: {n}"
             for k, (w, r) in enumerate(zip(windows, results, strict=True)) for n in r.notes]
    if several:
        for k, (w, r) in enumerate(zip(windows, results, strict=True)):
            junk = [m for m in r.fit.modes if not _determined_in_window(m)]
            if junk:
                notes.append(
                    f"window {k} {w.label()}: not taken as modes (not determined): " + ", ".join(
                        f"{m.omega_rad_s:.4g} +- {m.sigma_omega_rad_s:.2g} rad/s, damping "
                        f"{m.damping_ratio:.2g} +- {m.sigma_damping:.2g}" for m in junk))
    for m in rejected:
        notes.append(
            f"not reported as a mode: a component at {m.omega_rad_s:.4g} +- "
            f"{m.sigma_omega_rad_s:.2g} rad/s, damping {m.damping_ratio:.2g} (window"
            f"{'s' if len(m.windows) > 1 else ''} {', '.join(map(str, m.windows))} of "
            f"{len(experiments[m.experiment])}): not determined (frequency to "
            f"{MAX_REL_SIGMA:.0%}, damping to {MAX_REL_SIGMA_DAMPING:.0%}, damping below "
            f"{MAX_DAMPING:g}, found in at least half of the repetitions)")
    if n_modes is not None and several:
        if len(modes) < n_modes:
            notes.append(f"asked for {n_modes} modes, found {len(modes)}")
        modes = modes[:n_modes]
    elif n_modes is not None:
        modes = modes[:n_modes]
    result = MultiWindowResult(modes=modes, windows=list(windows), results=results,
                               experiments=experiments, notes=notes)
    for i, m in enumerate(modes):
        if m.fft_rough:
            res = [results[j] for j in m.windows]
            dur = float(np.mean([r.duration_s for r in res]))
            resolution = float(np.mean([2 * np.pi * r.spectrum.resolution_hz for r in res]))
            fft = ("no FFT peak" if m.fft_peak_omega_rad_s is None
                   else f"FFT peak {m.fft_peak_omega_rad_s:.4g} rad/s")
            if m.fft_damping_half_power_rough is not None:
                fft += f", half-power damping {m.fft_damping_half_power_rough:.2g}"
            notes.append(
                f"mode {i + 1} ({m.omega_rad_s:.4g} rad/s) comes from "
                f"{result.experiment_label(m.experiment)}; the FFT view of a {dur:.1f} s "
                f"window does not resolve it (Rayleigh resolution {resolution:.2g} rad/s, "
                f"half-power bandwidth {2 * m.damping_ratio * m.omega_rad_s:.2g} rad/s): "
                f"{fft} are rough, the parametric fit is the estimate")
        if max(m.birge_ratio_omega, m.birge_ratio_damping) > 2.0:
            notes.append(
                f"mode {i + 1} ({m.omega_rad_s:.4g} rad/s): its {len(m.windows)} windows scatter "
                f"{max(m.birge_ratio_omega, m.birge_ratio_damping):.1f} x more than their "
                f"sigmas say (sigma scaled up accordingly)")
    return result
