"""Open-loop excitation for frequency responses (``harness frf``, docs/frf.md).

Two controller types, each driving one input channel (``input: wheel`` a torque in N m,
``piezo1`` / ``piezo2`` a patch pair's voltage in V) with a peak of ``amplitude_fraction``
times the device's limit (``reaction_wheel.max_torque_n_m``, ``piezo_amplifier.max_voltage_v``),
so that the limit plan accepts it and the drivers never clamp it:

- ``multisine``: a periodic multisine, every line of the grid ``k / period_s`` in the band
  ``[f0_hz, f1_hz]`` with equal amplitude and Schroeder's phases (a low crest factor, about
  1.5-1.7), repeated for ``settle_periods`` (the transient dies out; not analysed) then
  ``periods`` measured periods. Zero mean: the wheel stays near rest. The band defaults to
  0.5 x the rig model's first hub-free mode to 1.5 x its last (``rig.plant.hub_free_modes()``).
  With ``signal: prbs``, one period is a maximum-length pseudo-random binary sequence
  instead (crest factor 1; every line of its grid up to its clock excited, falling as
  sinc^2), analysed the same way. With ``signal: random``, band-limited Gaussian noise
  (seeded: ``seed``) over the ``settle_periods + periods`` periods, never repeated, made one
  period at a time (``RandomSegments``: memory one period whatever the run's length), its
  peaks clipped at ``RANDOM_CREST_FACTOR`` times its rms; analysed by Welch segments of one
  period (``segment_s`` in its design).
- ``chirp``: a sine sweep from ``f0_hz`` to ``f1_hz`` (``law: linear`` or ``log``) over
  ``sweep_s``, repeated ``sweeps`` times (analysed by Welch segments of one sweep).

Each reports its design (``design_report()``, summary.json ``controller_design``): the band,
the lines, the peak and rms, the crest factor, when the measured part starts and ends; the
analysis reads it back from the run's config.yaml.

Imports: ``harness.controllers.api``, ``harness.state``, ``rig_models``, numpy.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from harness.controllers.api import controller_factory
from harness.state import RigCommand, RigState
from rig_models.rig_file import RigConfig
from rig_models.schema import Field

INPUTS = ("wheel", "piezo1", "piezo2")
"""The input channels an excitation can drive."""

BAND_MARGIN = (0.5, 1.5)
"""The default band: this times the model's first and last hub-free mode."""


def input_limit(rig: RigConfig, channel: str) -> tuple[float, str, str]:
    """(the device's limit in SI, its unit, the rig file key it comes from) of an input."""
    if channel == "wheel":
        return float(rig.section("reaction_wheel")["max_torque_n_m"]), "N m", \
            "reaction_wheel.max_torque_n_m"
    if channel in ("piezo1", "piezo2"):
        if len(rig.piezo_gains) < int(channel[-1]):
            raise ValueError(f"input {channel}: the rig has {len(rig.piezo_gains)} piezo "
                             "patch pair(s)")
        return float(rig.section("piezo_amplifier")["max_voltage_v"]), "V", \
            "piezo_amplifier.max_voltage_v"
    raise ValueError(f"input: expected one of {', '.join(INPUTS)}, got {channel!r}")


def default_band_hz(rig: RigConfig) -> tuple[float, float]:
    """(f0, f1) in Hz: ``BAND_MARGIN`` times the model's first and last hub-free mode."""
    omega = rig.plant.hub_free_modes()[0]
    return (BAND_MARGIN[0] * float(omega[0]) / (2 * math.pi),
            BAND_MARGIN[1] * float(omega[-1]) / (2 * math.pi))


def schroeder_multisine(n_samples: int, dt_s: float, f0_hz: float, f1_hz: float
                        ) -> tuple[np.ndarray, np.ndarray]:
    """One period (``n_samples`` ticks of ``dt_s``) of a multisine with every DFT line
    ``k / (n_samples dt_s)`` in ``[f0_hz, f1_hz]`` at equal amplitude and Schroeder's phases
    ``-pi k (k - 1) / N``, scaled to a peak of 1; and its line indices ``k``."""
    period_s = n_samples * dt_s
    k0 = max(1, math.ceil(f0_hz * period_s - 1e-9))
    k1 = min(math.floor(f1_hz * period_s + 1e-9), n_samples // 2 - 1)
    if k1 < k0:
        raise ValueError(f"band {f0_hz:g}-{f1_hz:g} Hz holds no line of the grid "
                         f"1/period = {1 / period_s:g} Hz below Nyquist")
    lines = np.arange(k0, k1 + 1)
    n = len(lines)
    phases = -math.pi * np.arange(1, n + 1) * np.arange(0, n) / n
    spectrum = np.zeros(n_samples // 2 + 1, dtype=complex)
    spectrum[lines] = np.exp(1j * phases)
    x = np.fft.irfft(spectrum, n_samples)
    return x / np.max(np.abs(x)), lines


PRBS_BAND_SHARE = 0.4
"""A PRBS's clock is f1 / this: its lines' power falls as sinc^2(f / clock), to 0.57 (-2.4 dB)
at f1 and to nothing at the clock."""


def prbs_period(period_s: float, dt_s: float, f1_hz: float) -> tuple[np.ndarray, int, int]:
    """One period of a maximum-length pseudo-random binary sequence (``scipy.signal.
    max_len_seq``), each bit held ``ticks_per_bit`` ticks so that its clock is about
    ``f1_hz / PRBS_BAND_SHARE``, of the order whose period is nearest ``period_s`` from
    above; zero mean, scaled to a peak of 1. Returns (table, order, ticks_per_bit)."""
    from scipy.signal import max_len_seq

    ticks = max(1, int(round(PRBS_BAND_SHARE / (f1_hz * dt_s))))
    bits = period_s / (ticks * dt_s)
    order = min(max(3, math.ceil(math.log2(bits + 1) - 1e-9)), 20)
    seq = 2.0 * max_len_seq(order)[0] - 1.0
    table = np.repeat(seq - seq.mean(), ticks)
    return table / np.max(np.abs(table)), order, ticks


RANDOM_CREST_FACTOR = 3.0
"""Band-limited random noise is clipped at this many times its rms (a Gaussian exceeds 3
sigma 0.27 % of the time): the peak that ``amplitude_fraction`` sets then leaves the rms a
third of it, where unclipped noise's peak would grow with the record's length."""


def band_limited_noise(n_samples: int, dt_s: float, f0_hz: float, f1_hz: float,
                       seed: int | tuple[int, ...],
                       crest_factor: float = RANDOM_CREST_FACTOR) -> np.ndarray:
    """``n_samples`` of Gaussian noise (``numpy.random.default_rng(seed)``) with every DFT
    line outside ``[f0_hz, f1_hz]`` removed, clipped at ``crest_factor`` times its rms, zero
    mean, scaled to a peak of 1."""
    if n_samples < 2:
        raise ValueError(f"random: {n_samples} samples, at least 2 are needed")
    spectrum = np.fft.rfft(np.random.default_rng(seed).standard_normal(n_samples))
    f = np.fft.rfftfreq(n_samples, dt_s)
    spectrum[(f < f0_hz) | (f > f1_hz) | (f == 0)] = 0.0
    if not np.any(spectrum):
        raise ValueError(f"band {f0_hz:g}-{f1_hz:g} Hz holds no line of the record's grid "
                         f"{1 / (n_samples * dt_s):g} Hz")
    x = np.fft.irfft(spectrum, n_samples)
    x = np.clip(x / np.std(x), -crest_factor, crest_factor)
    x -= np.mean(x)
    return x / np.max(np.abs(x))


class RandomSegments:
    """Band-limited random noise as a table of ``segments`` x ``n`` samples, made one segment
    at a time when a tick reaches it (each ``band_limited_noise`` of ``n`` samples, seeded by
    ``(seed, k)`` for segment k, times ``scale``): the memory of one segment whatever the
    record's length, where the whole record's noise would grow with it (a day at 500 Hz:
    350 MB). The segments are independent, so the noise never repeats; where two meet the
    signal steps, which the Welch analysis's windows see as any random signal's leakage."""

    def __init__(self, n: int, segments: int, dt_s: float, f0_hz: float, f1_hz: float,
                 seed: int, scale: float) -> None:
        self.n, self.segments = n, segments
        self.dt_s, self.f0_hz, self.f1_hz = dt_s, f0_hz, f1_hz
        self.seed, self.scale = seed, scale
        self._k = -1
        self._segment = np.empty(0)

    def segment(self, k: int) -> np.ndarray:
        """Segment ``k``'s samples (made again if it is not the one held)."""
        if k != self._k:
            self._segment = self.scale * band_limited_noise(
                self.n, self.dt_s, self.f0_hz, self.f1_hz, (self.seed, k))
            self._k = k
        return self._segment

    def __len__(self) -> int:
        return self.n * self.segments

    def __getitem__(self, i: int) -> float:
        k, j = divmod(int(i), self.n)
        return float(self.segment(k)[j])

    def rms(self) -> float:
        """The rms over every segment, made one after the other (the design's figure)."""
        total = sum(float(np.sum(self.segment(k) ** 2)) for k in range(self.segments))
        return math.sqrt(total / len(self))


def _command(channel: str, value: float) -> RigCommand:
    if channel == "wheel":
        return RigCommand(wheel_torque_n_m=value)
    return RigCommand(piezo_v=(value, 0.0) if channel == "piezo1" else (0.0, value))


QUICKLOOK_OUTPUTS = {"wheel": ("hub_rate", "tip_accel"),
                     "piezo1": ("tip_accel", "piezo_sensor1"),
                     "piezo2": ("tip_accel", "piezo_sensor2")}
"""The outputs a multisine's quick look follows for each input (as ``harness frf``'s
defaults)."""


def model_vectors(rig: RigConfig, channel: str, output: str
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """(A, b, c, d) of the rig model from an input channel to an output (SI): a piezo input
    through its patch's modal forces per volt, a sensor patch output through its volts per
    modal coordinate."""
    p = rig.plant
    if channel == "wheel":
        b, d_in = p.b[:, 0], p.d[:, 0]
    else:
        g = rig.piezo_gains[int(channel[-1]) - 1]
        b, d_in = p.b[:, 1:] @ g.actuator, p.d[:, 1:] @ g.actuator
    if output == "hub_rate":
        return p.a, b, p.c[1], float(d_in[1])
    if output == "tip_accel":
        return p.a, b, p.c[2], float(d_in[2])
    c = np.zeros(p.n_states)
    c[1:1 + p.n_modes] = rig.piezo_gains[int(output[-1]) - 1].sensor
    return p.a, b, c, 0.0


def model_response(rig: RigConfig, channel: str, output: str, freq_hz: np.ndarray
                   ) -> np.ndarray:
    """The rig model's frequency response from an input channel to an output (SI): the
    plant ``C (sI - A)^-1 B + D`` (``model_vectors``)."""
    a, b, c, d = model_vectors(rig, channel, output)
    eye = np.eye(len(a))
    return np.array([c @ np.linalg.solve(2j * math.pi * f * eye - a, b) + d
                     for f in np.asarray(freq_hz, dtype=float)])


class QuickLook:
    """The frequency response at the lines nearest the model's hub-free modes, averaged over
    the measured periods while the run goes (the measured input and the outputs of every
    tick kept for one period, a DFT at those few lines at each period's end): coherence and
    magnitude against the model in summary.json, for a run file's or a suite's criteria.
    ``harness frf`` is the full analysis."""

    def __init__(self, rig: RigConfig, channel: str, period_samples: int, dt_s: float,
                 lines: np.ndarray) -> None:
        self.channel = channel
        self.outputs = QUICKLOOK_OUTPUTS[channel]
        n = period_samples
        omega = rig.plant.hub_free_modes()[0]
        freq = lines / (n * dt_s)
        self.modes: list[tuple[int, int]] = []  # (model mode number, line)
        for i, w in enumerate(omega):
            f = w / (2 * math.pi)
            if freq[0] <= f <= freq[-1]:
                self.modes.append((i + 1, int(lines[np.argmin(np.abs(freq - f))])))
        ks = np.array([k for _, k in self.modes], dtype=float)
        self.freq_hz = ks / (n * dt_s)
        self.kernel = np.exp(-2j * math.pi * np.outer(ks, np.arange(n)) / n)
        self.model = {o: model_response(rig, channel, o, self.freq_hz) for o in self.outputs}
        self.buffer = np.zeros((1 + len(self.outputs), n))
        m = len(self.modes)
        self.gxx = np.zeros(m)
        self.gyy = np.zeros((len(self.outputs), m))
        self.gxy = np.zeros((len(self.outputs), m), dtype=complex)
        self.periods = 0

    def add(self, j: int, u: float, state: RigState) -> None:
        """Sample ``j`` of a measured period: the measured input ``u`` and the outputs."""
        b = self.buffer
        b[0, j] = u
        for r, o in enumerate(self.outputs, start=1):
            if o == "hub_rate":
                b[r, j] = state.hub_rate_rad_s
            elif o == "tip_accel":
                b[r, j] = state.tip_accel_m_s2
            else:
                b[r, j] = state.piezo_sensor_v[int(o[-1]) - 1]
        if j == b.shape[1] - 1 and self.modes:
            spectra = self.kernel @ b.T  # (modes, 1 + outputs)
            uf = spectra[:, 0]
            self.gxx += np.abs(uf) ** 2
            for r in range(len(self.outputs)):
                yf = spectra[:, r + 1]
                self.gyy[r] += np.abs(yf) ** 2
                self.gxy[r] += np.conj(uf) * yf
            self.periods += 1

    def report(self) -> dict[str, Any]:
        out: dict[str, Any] = {"periods": self.periods, "outputs": {}}
        for r, o in enumerate(self.outputs):
            modes = {}
            for i, (number, _) in enumerate(self.modes):
                if self.periods and self.gxx[i] > 0 and self.gyy[r, i] > 0:
                    h1 = self.gxy[r, i] / self.gxx[i]
                    coh = float(abs(self.gxy[r, i]) ** 2 / (self.gxx[i] * self.gyy[r, i]))
                    ratio = float(abs(h1) / abs(self.model[o][i]))
                else:
                    coh = ratio = None
                modes[f"mode{number}"] = {"freq_hz": float(self.freq_hz[i]),
                                          "coherence": coh,
                                          "magnitude_ratio_to_model": ratio}
            out["outputs"][o] = modes
        return out


class Multisine:
    """A table played from ``start_s``: ``settle_periods + periods`` periods of
    ``period_samples`` (default: the table's length, repeated; a random signal's table is
    all the periods)."""

    def __init__(self, channel: str, table: np.ndarray | RandomSegments, dt_s: float,
                 start_s: float,
                 settle_periods: int, periods: int, report: dict[str, Any],
                 quicklook: QuickLook | None = None,
                 period_samples: int | None = None) -> None:
        self.channel = channel
        self.table = table
        self.dt_s = dt_s
        self.start_s = start_s
        n = len(table) if period_samples is None else int(period_samples)
        self.settle_ticks = n * settle_periods
        self.n_ticks = n * (settle_periods + periods)
        if self.n_ticks > len(table) and len(table) % n:
            raise ValueError(f"a table of {len(table)} samples is not whole periods of {n}")
        self.report = report
        self.quicklook = quicklook

    def reset(self) -> None:
        pass

    def value(self, t_s: float) -> float:
        i = int(round((t_s - self.start_s) / self.dt_s))
        if i < 0 or i >= self.n_ticks:
            return 0.0
        return float(self.table[i % len(self.table)])

    def step(self, state: RigState) -> RigCommand:
        i = int(round((state.time_s - self.start_s) / self.dt_s))
        value = float(self.table[i % len(self.table)]) if 0 <= i < self.n_ticks else 0.0
        ql = self.quicklook
        if ql is not None and self.settle_ticks <= i < self.n_ticks:
            # the wheel's measured torque; the amplifier has no read-back: its command
            u = state.wheel_torque_n_m if self.channel == "wheel" else value
            ql.add((i - self.settle_ticks) % len(self.table), u, state)
        return _command(self.channel, value)

    def design_report(self) -> dict[str, Any]:
        out = dict(self.report)
        if self.quicklook is not None:
            out["quicklook"] = self.quicklook.report()
        return out


class Chirp:
    """A sine sweep repeated ``sweeps`` times from ``start_s``."""

    def __init__(self, channel: str, amplitude: float, f0_hz: float, f1_hz: float,
                 sweep_s: float, sweeps: int, law: str, start_s: float,
                 report: dict[str, Any]) -> None:
        self.channel, self.amplitude = channel, amplitude
        self.f0_hz, self.f1_hz, self.sweep_s = f0_hz, f1_hz, sweep_s
        self.sweeps, self.law, self.start_s = sweeps, law, start_s
        self.report = report

    def reset(self) -> None:
        pass

    def value(self, t_s: float) -> float:
        t = t_s - self.start_s
        if t < 0 or t >= self.sweeps * self.sweep_s:
            return 0.0
        tau = math.fmod(t, self.sweep_s)
        f0, f1, span = self.f0_hz, self.f1_hz, self.sweep_s
        if self.law == "linear":
            phase = 2 * math.pi * (f0 * tau + 0.5 * (f1 - f0) * tau * tau / span)
        else:
            k = f1 / f0
            phase = 2 * math.pi * f0 * span / math.log(k) * (k ** (tau / span) - 1.0)
        return self.amplitude * math.sin(phase)

    def step(self, state: RigState) -> RigCommand:
        return _command(self.channel, self.value(state.time_s))

    def design_report(self) -> dict[str, Any]:
        return dict(self.report)


COMMON_SCHEMA = {
    "type": Field("str", required=True),
    "input": Field("str", default="wheel", choices=INPUTS),
    "amplitude_fraction": Field("number", default=0.5, exclusive_minimum=0.0, maximum=1.0),
    # 0: the default band from the rig model's hub-free modes (BAND_MARGIN)
    "f0_hz": Field("number", "Hz", default=0.0, minimum=0.0),
    "f1_hz": Field("number", "Hz", default=0.0, minimum=0.0),
    "start_s": Field("number", "s", default=0.5, minimum=0.0),
}


def _band(c: dict[str, Any], rig: RigConfig, dt_s: float) -> tuple[float, float, str]:
    d0, d1 = default_band_hz(rig)
    f0 = c["f0_hz"] or d0
    f1 = c["f1_hz"] or d1
    if not 0 < f0 < f1:
        raise ValueError(f"f0_hz {f0:g} must be below f1_hz {f1:g}")
    if f1 >= 0.5 / dt_s:
        raise ValueError(f"f1_hz {f1:g} must be below the loop's Nyquist frequency "
                         f"{0.5 / dt_s:g} Hz")
    source = "run file" if c["f0_hz"] and c["f1_hz"] else \
        f"rig model hub-free modes x {BAND_MARGIN}"
    return f0, f1, source


@controller_factory({
    **COMMON_SCHEMA,
    "period_s": Field("number", "s", default=40.0, exclusive_minimum=0.0),
    # schroeder: the band's lines only, equal amplitude; prbs: a periodic binary sequence
    # (crest factor 1) clocked at f1_hz / PRBS_BAND_SHARE, its period the nearest
    # 2^n - 1 bits at or above period_s; random: band-limited Gaussian noise, never
    # repeated, its period the Welch segment
    "signal": Field("str", default="schroeder", choices=("schroeder", "prbs", "random")),
    "periods": Field("int", default=4, minimum=2),
    "settle_periods": Field("int", default=1, minimum=0),
    # random: the noise generator's seed (the same seed, the same excitation)
    "seed": Field("int", default=1, minimum=0),
})
def build_multisine(c: dict[str, Any], rig: RigConfig, dt_s: float) -> Multisine:
    limit, unit, key = input_limit(rig, c["input"])
    f0, f1, source = _band(c, rig, dt_s)
    extra: dict[str, Any] = {}
    total = c["settle_periods"] + c["periods"]
    if c["signal"] == "random":
        n = int(round(c["period_s"] / dt_s))
        shape = RandomSegments(n, total, dt_s, f0, f1, c["seed"], 1.0)
        shape.segment(0)  # a band with no line of the grid is refused here
        lines = np.arange(max(1, math.ceil(f0 * n * dt_s - 1e-9)),
                          math.floor(f1 * n * dt_s + 1e-9) + 1)
        if not len(lines):
            raise ValueError(f"band {f0:g}-{f1:g} Hz holds no line of the grid "
                             f"1/period = {1 / (n * dt_s):g} Hz")
        extra = {"seed": c["seed"], "clip_crest_factor": RANDOM_CREST_FACTOR,
                "segment_s": n * dt_s, "analysis": "welch"}
    elif c["signal"] == "prbs":
        shape, order, ticks = prbs_period(c["period_s"], dt_s, f1)
        n = len(shape)
        k0 = max(1, math.ceil(f0 * n * dt_s - 1e-9))
        lines = np.arange(k0, math.floor(f1 * n * dt_s + 1e-9) + 1)
        if not len(lines):
            raise ValueError(f"band {f0:g}-{f1:g} Hz holds no line of the PRBS's grid "
                             f"1/period = {1 / (n * dt_s):g} Hz")
        extra = {"prbs_order": order, "prbs_bits": 2**order - 1,
                "prbs_clock_hz": 1.0 / (ticks * dt_s)}
    else:
        n = int(round(c["period_s"] / dt_s))
        shape, lines = schroeder_multisine(n, dt_s, f0, f1)
    peak = c["amplitude_fraction"] * limit
    period_s = n * dt_s
    if isinstance(shape, RandomSegments):
        rms = shape.rms()
        shape = RandomSegments(n, total, dt_s, f0, f1, c["seed"], peak)
    else:
        rms = float(np.sqrt(np.mean(shape**2)))
        shape = peak * shape
    measure_start = c["start_s"] + c["settle_periods"] * period_s
    report = {
        "excitation": "multisine", "signal": c["signal"], **extra,
        "input": c["input"], "unit": unit,
        "peak": peak, "rms": peak * rms, "crest_factor": 1.0 / rms,
        "limit": limit, "limit_key": key,
        "f0_hz": float(lines[0] / period_s), "f1_hz": float(lines[-1] / period_s),
        "band_from": source, "n_lines": len(lines),
        "frequency_step_hz": 1.0 / period_s, "period_s": period_s,
        "period_samples": n, "settle_periods": c["settle_periods"],
        "periods": c["periods"], "start_s": c["start_s"],
        "measure_start_s": measure_start, "end_s": measure_start + c["periods"] * period_s,
    }
    # the quick look's period-by-period DFT needs a periodic signal
    quicklook = None if c["signal"] == "random" else QuickLook(rig, c["input"], n, dt_s,
                                                                lines)
    return Multisine(c["input"], shape, dt_s, c["start_s"], c["settle_periods"],
                     c["periods"], report, quicklook, period_samples=n)


@controller_factory({
    **COMMON_SCHEMA,
    "law": Field("str", default="log", choices=("linear", "log")),
    "sweep_s": Field("number", "s", default=60.0, exclusive_minimum=0.0),
    "sweeps": Field("int", default=3, minimum=1),
})
def build_chirp(c: dict[str, Any], rig: RigConfig, dt_s: float) -> Chirp:
    limit, unit, key = input_limit(rig, c["input"])
    f0, f1, source = _band(c, rig, dt_s)
    peak = c["amplitude_fraction"] * limit
    report = {
        "excitation": "chirp", "input": c["input"], "unit": unit, "peak": peak,
        "rms": peak / math.sqrt(2), "crest_factor": math.sqrt(2), "limit": limit,
        "limit_key": key, "f0_hz": f0, "f1_hz": f1, "band_from": source, "law": c["law"],
        "sweep_s": c["sweep_s"], "sweeps": c["sweeps"], "start_s": c["start_s"],
        "measure_start_s": c["start_s"], "end_s": c["start_s"] + c["sweeps"] * c["sweep_s"],
    }
    return Chirp(c["input"], peak, f0, f1, c["sweep_s"], c["sweeps"], c["law"],
                 c["start_s"], report)
