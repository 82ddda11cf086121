"""When a sensor's repeated reading means it is stuck: a pure rule from its resolution and
noise.

A real sensor quantises: a hub encoder of 0.01 deg steps at rest reads the same value tick
after tick, and so does any sensor whose noise is well under one step. A frozen sensor
repeats too. What tells them apart is how likely the repetition is for a healthy sensor:

- noise: with noise of rms ``sigma`` and a step of ``q``, a healthy reading stays in the
  same step from one sample to the next with probability at most ``p = 2 Phi(q / (2 sigma))
  - 1`` (the true value in the middle of a step, the best case), so ``n`` equal samples have
  probability at most ``p ** (n - 1)``; below ``FALSE_ALARM`` the repetition is a fault.
  With no noise (``p = 1``) no count of equal samples is improbable;
- motion: a hub whose rate reading says it turns must change its angle reading: ``|rate| *
  (n - 1) * dt`` over more than ``MOTION_STEPS`` angle steps with the angle unchanged is a
  fault whatever the noise.

The rule also keeps the monitor's own floor (its ``stuck_ticks``): nothing is judged stuck
before that many equal samples. ``sensor_quality(rig)`` gives each sensor channel's
resolution (the coarser of the rig file's and the binding's step: a DBC signal's scale, a
CANopen quantity's conversion) and noise, from the rig file. Pure: no bus, no clock.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

SIGMAS = 4.0
"""Standard errors a measurement may stray from the physics by noise alone (4: a false
alarm about once in 16 000 judgements)."""

INTEGRATION_FRACTION = 0.02
"""An angle's change against its rate's integral: the trapezoid of a sampled rate differs
from the sampled angle's change by the sensors' own filtering; 2 % bounds it at the rates
the rig's slews and pulses make."""

FALSE_ALARM = 1e-6
"""The largest probability of a healthy sensor's repetition that is still judged a fault."""

MOTION_STEPS = 3.0
"""Angle steps the rate reading must imply before an unchanged angle is a fault (a rate
reading has its own quantisation and lag)."""


@dataclass(frozen=True)
class ChannelQuality:
    """A sensor channel's resolution (its step, SI; 0: continuous) and noise rms (SI)."""

    resolution: float
    noise_rms: float


def stay_probability(q: ChannelQuality) -> float:
    """The largest probability that a healthy reading stays in the same step from one
    sample to the next at rest (1.0: nothing makes it move)."""
    if q.noise_rms <= 0.0:
        return 1.0
    if q.resolution <= 0.0:
        return 0.0  # continuous and noisy: two equal readings do not happen
    return math.erf(q.resolution / (2.0 * q.noise_rms * math.sqrt(2.0)))


def healthy_repeats(qualities: tuple[ChannelQuality, ...],
                    false_alarm: float = FALSE_ALARM) -> float:
    """How many equal samples in a row (of every channel at once) a healthy sensor at rest
    may give before the repetition is less likely than ``false_alarm``; ``inf`` when it may
    repeat for ever (noise far below its step on every channel)."""
    p = 1.0
    for q in qualities:
        p *= stay_probability(q)
    if p >= 1.0:
        return math.inf
    if p <= 0.0:
        return 1.0
    return 1.0 + math.log(false_alarm) / math.log(p)


def repeated_reading_is_stuck(n_same: int, qualities: tuple[ChannelQuality, ...],
                              stuck_ticks: int, false_alarm: float = FALSE_ALARM) -> bool:
    """Whether ``n_same`` equal samples in a row (every channel of the reading equal) say
    the sensor is stuck: at least ``stuck_ticks`` of them, and more than its noise
    explains."""
    return n_same >= stuck_ticks and n_same > healthy_repeats(qualities, false_alarm)


def hub_is_stuck(n_same: int, rate_rad_s: float, dt_s: float, angle: ChannelQuality,
                 rate: ChannelQuality, stuck_ticks: int,
                 false_alarm: float = FALSE_ALARM) -> bool:
    """Whether the hub sensor's angle and rate, both equal for ``n_same`` samples ``dt_s``
    apart with the rate reading ``rate_rad_s``, say it is stuck: too many equal samples for
    its noise, or a rate that should have moved the angle by ``MOTION_STEPS`` steps."""
    if n_same < stuck_ticks:
        return False
    moved = abs(rate_rad_s) * (n_same - 1) * dt_s
    if moved > MOTION_STEPS * max(angle.resolution, 0.0) and moved > 0.0:
        return True
    return n_same > healthy_repeats((angle, rate), false_alarm)


def binding_step(binding: Any, device: str, quantity: str) -> float:
    """The step of ``quantity`` as the binding carries it (SI), 0 if unknown: a DBC
    signal's scale times the map's, a CANopen quantity's linear conversion."""
    for m in binding.telemetry.get(device, ()):
        for f in getattr(m, "fields", ()):
            if getattr(f, "quantity", None) != quantity:
                continue
            conv = getattr(f, "conv", None)
            if conv is not None:  # CANopen: raw counts times the conversion's scale
                linear = conv.bit is None and conv.mask is None and conv.values is None
                floating = getattr(f.ref, "code", "") in ("f", "d")
                return abs(conv.scale) if linear and not floating else 0.0
            signal = next((s for s in getattr(m.codec, "signals", ())
                           if s.name == getattr(f, "signal", None)), None)
            if signal is None or getattr(signal, "is_float", False):
                return 0.0
            return abs(signal.scale * f.scale)
    return 0.0


# channel -> (device, quantity, rig file section, resolution key, noise key)
_CHANNELS = {
    "hub_sensor.angle": ("hub_sensor", "angle", "hub_sensor", "angle_lsb_rad",
                         "angle_noise_rms_rad"),
    "hub_sensor.rate": ("hub_sensor", "rate", "hub_sensor", "rate_lsb_rad_s",
                        "rate_noise_rms_rad_s"),
    "accelerometer.accel": ("accelerometer", "accel", "accelerometer", "lsb_m_s2",
                            "noise_rms_m_s2"),
    "piezo_amplifier.sensor_ch1": ("piezo_amplifier", "sensor_ch1", "piezo_amplifier",
                                   "sensor_lsb_v", "sensor_noise_rms_v"),
    "piezo_amplifier.sensor_ch2": ("piezo_amplifier", "sensor_ch2", "piezo_amplifier",
                                   "sensor_lsb_v", "sensor_noise_rms_v"),
}


def sensor_quality(rig: Any) -> dict[str, ChannelQuality]:
    """Per sensor channel (``"hub_sensor.angle"``, ...), its resolution and noise from the
    rig file (a ``RigConfig``): the resolution is the coarser of the rig file's and the
    step the device's binding carries. Channels of devices the rig does not have are left
    out."""
    binding = rig.binding
    out = {}
    for channel, (device, quantity, section, res_key, noise_key) in _CHANNELS.items():
        if binding.kinds.get(device) == "none":
            continue
        data = rig.data.get(section) or {}
        resolution = max(float(data.get(res_key) or 0.0),
                         binding_step(binding, device, quantity))
        out[channel] = ChannelQuality(resolution, float(data.get(noise_key) or 0.0))
    return out


# a ratio this close to a factor (within its own limit) names it as the likely cause
FACTORS: tuple[tuple[float, str], ...] = (
    (1000.0, "a factor of 1000 (milli- against base units, e.g. mN.m as N.m, mg as g)"),
    (1e-3, "a factor of 1/1000 (base units against milli-units)"),
    (180 / math.pi, "a factor of 180/pi (degrees read as radians)"),
    (math.pi / 180, "a factor of pi/180 (radians read as degrees)"),
    (2 * math.pi, "a factor of 2 pi (revolutions or Hz read as radians)"),
    (1 / (2 * math.pi), "a factor of 1/(2 pi) (radians read as revolutions)"),
    (60 / (2 * math.pi), "a factor of 60/(2 pi) (rpm read as rad/s)"),
    (2 * math.pi / 60, "a factor of 2 pi/60 (rad/s read as rpm)"),
    (9.80665, "a factor of g (g read as m/s^2)"),
    (1 / 9.80665, "a factor of 1/g (m/s^2 read as g)"),
)


NEAR_FACTOR = 0.05
"""A ratio within this (relative) of a factor, or within its own noise, is named for it."""
NO_RESPONSE = ("no response: the quantity is bound to an object or signal that does not "
               "carry it, or the sensor is pinned at a constant")
NEAR_FACTOR_MAX = 0.25
"""... or within the model's tolerance, up to this."""


def likely_cause(ratio: float, se: float = 0.0, tol: float = 0.0) -> str:
    """What a ratio far from 1 most likely says about the binding: ``se`` is the ratio's
    standard error, ``tol`` the model's own relative uncertainty in it (at most
    ``NEAR_FACTOR_MAX`` is taken). A ratio below half the smallest factor is "no response",
    at any tolerance; else the one factor nearest in log (1, a sign, or one of ``FACTORS``)
    is named when the ratio lies within ``SIGMAS`` standard errors, ``tol`` or
    ``NEAR_FACTOR`` of it; else a ratio within its noise of 0 is "no response". A loose
    tolerance names no other factor: a reversed sign is "a sign", never "a sign and a factor
    of 1000"; g read as m/s^2 is g, not 60/(2 pi)."""
    if not math.isfinite(ratio):
        return "no usable reading (NaN or infinite)"
    sign = ratio < 0
    mag = abs(ratio)
    if not mag >= 0.5e-3:  # below half the smallest factor: nothing there
        return NO_RESPONSE
    factor, text = min(((1.0, ""), *FACTORS), key=lambda f: abs(math.log(mag / f[0])))
    near = max(NEAR_FACTOR, min(tol, NEAR_FACTOR_MAX), SIGMAS * se / mag)
    if sign and factor == 1.0:  # a reversed reading with the model's own error on it
        near = max(near, NEAR_FACTOR_MAX)
    if abs(mag / factor - 1.0) <= near:
        if factor == 1.0:
            if sign:
                return "a sign (the quantity's direction is reversed: a negative scale, or " \
                       "wired the other way)"
            return ("a ratio near 1 beyond its band: the rig file's model (inertia, couple, "
                    "gains) or its tolerances, not a binding's factor")
        return ("a sign and " if sign else "") + text
    if mag <= SIGMAS * se:  # within its noise of 0, near no factor
        return NO_RESPONSE
    return (("a sign and " if sign else "") + f"a factor of {mag:.4g}: a wrong scale, a "
            "wrong object or signal, or the rig file's model (inertia, couple, gains) is off")
