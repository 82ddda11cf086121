"""Each bound quantity against the physics, written as criteria (docs/commission.md).

Every check is a row: the device and quantity, what was compared, the value, what the
physics expects, the limit, the margin (limit minus the distance from the expected value;
negative: a miss), the verdict, and for a miss the likely cause. The limits come from the
rig file: its noise specs and resolutions (``hub_sensor``, ``accelerometer``,
``piezo_amplifier``, the binding's counts) and its ``tolerances`` (how well it knows the
inertias, the torque, the couple, the beam's response), never from what a run measured:

- a ratio of a measured change to the one the physics predicts (expected 1) may differ
  from 1 by the sum of the model tolerances it depends on plus ``SIGMAS`` times its own
  standard error from the noise (``sigma / sqrt(sum of the prediction squared)``, each
  sample counted once at the device's own rate);
- a mean at rest may differ from 0 by the sensor's bias tolerance plus ``SIGMAS`` standard
  errors of the mean plus half a resolution step;
- a standard deviation at rest within [1 / noise_factor, noise_factor] x the spec (noise
  and quantisation combined); the lower bound only where the noise is at least a
  resolution step (a coarse sensor repeating its reading at rest is not stuck).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np

from harness.core.plausibility import (  # noqa: F401 (re-exported for the checks' users)
    FACTORS,
    INTEGRATION_FRACTION,
    SIGMAS,
    likely_cause,
)

READBACK_MIN_FRACTION = 0.8
"""A valve's read-back must show it open (and the other closed) over this fraction of the
commanded on-time after its opening delay (the valves answer every few SYNCs)."""

@dataclass
class Check:
    device: str
    quantity: str
    check: str
    value: float | None
    expected: float | None
    limit: float | list[float] | None
    unit: str
    margin: float | None
    verdict: str  # PASS, FAIL, NOT RUN; a rig-file key: DIFFERS, INFO, NOT JUDGED too
    cause: str = ""
    why: str = ""
    # (time s, measured, expected) of a ratio check, for commission.rrd; not in the JSON
    series: tuple[np.ndarray, np.ndarray, np.ndarray] | None = field(default=None, repr=False)
    sigma: float | None = None  # a measured rig-file key's 1-sigma
    key: str = ""  # the rig-file key a row measures (hub.inertia_kg_m2), else ""

    def to_dict(self) -> dict[str, Any]:
        d = {f.name: getattr(self, f.name) for f in fields(self) if f.name != "series"}
        for k in ("value", "expected", "margin", "sigma"):
            if isinstance(d[k], float) and not math.isfinite(d[k]):
                d[k] = None
        return d

    @property
    def name(self) -> str:
        return f"{self.device}.{self.quantity}"


HUB_READ = ("thruster_valves", "hub.inertia_kg_m2", "thruster_valves.couple_n_m",
            "thruster_valves.couple_negative_n_m")
"""What commissioning reads through the hub's rate: the valves' impulse, the inertia and
the couples (momentum exchange)."""


def attribute_causes(checks: list[Check]) -> None:
    """One cause, named once: a check whose failure follows from another's says so and is
    not judged on its own (in place).

    - the hub sensor's rate failing its own checks (against the wheel's torque and
      momentum): everything read through the hub's rate (``HUB_READ``) follows from it;
    - the valves failing their impulse (the hub's rate passing): the accelerometer's
      ring-down against the model, which the valves' commands drive too, follows from
      them."""
    def root(device: str, quantity: str | None = None) -> Check | None:
        return next((c for c in checks if c.verdict == "FAIL" and not c.key
                     and c.device == device and (quantity is None or c.quantity == quantity)),
                    None)

    def follows(c: Check, from_: Check) -> None:
        c.verdict = "NOT JUDGED"
        c.cause = (f"follows from {from_.name} ({from_.check}: {from_.cause}): judged again "
                   f"once that is fixed; on its own: {c.cause}")

    hub = root("hub_sensor", "rate")
    if hub is not None:
        for c in checks:
            if c.verdict == "FAIL" and (c.device in HUB_READ or c.key in HUB_READ):
                follows(c, hub)
        return
    valves = root("thruster_valves")
    if valves is not None:
        both = [c for c in checks if c.verdict == "FAIL" and not c.key
                and c.device == "thruster_valves" and c.value is not None and c.value < 0]
        if {c.quantity for c in both} >= {"valve_pos", "valve_neg"}:
            for c in both:  # each valve turns the hub the other way: one cause, both valves
                c.cause = ("the positive and negative valve swapped (their commands and "
                           "read-back), or the couple's sign: both valves turn the hub the "
                           f"other way (ratio {c.value:+.3g})")
        for c in checks:
            if c.verdict != "FAIL" or c is valves:
                continue
            if (c.device == "accelerometer" and "ring-down" in c.check) or (
                    c.key in HUB_READ[2:] and c.value is not None and c.value < 0):
                follows(c, valves)


def nearest_factor(ratio: float, spread: float) -> str:
    """The factor of ``FACTORS`` nearest a ratio of noises (a scale error multiplies the
    noise by it), when within ``spread`` (the noise's own, noise_factor) either way."""
    if not ratio > 0:
        return ""
    best = min(FACTORS, key=lambda f: abs(math.log(ratio / f[0])))
    return best[1] if abs(math.log(ratio / best[0])) <= math.log(max(spread, 1.0001)) else ""


def ratio_check(device: str, quantity: str, check: str, meas: np.ndarray,
                pred: np.ndarray, sigma: float, tol: float, every: int = 1,
                why: str = "", t: np.ndarray | None = None) -> Check:
    """``meas`` against ``pred`` (both changes from a baseline, same samples): the least-
    squares ratio, expected 1 within ``tol`` + SIGMAS standard errors."""
    ok = np.isfinite(meas) & np.isfinite(pred)
    m, p = meas[ok], pred[ok]
    power = float(np.sum(p * p)) / max(every, 1)
    if power <= 0.0:
        return Check(device, quantity, check, None, 1.0, None, "", None, "NOT RUN",
                     why="the model predicts no response here")
    r = float(np.sum(m * p) / np.sum(p * p))
    se = sigma / math.sqrt(power)
    limit = tol + SIGMAS * se
    margin = limit - abs(r - 1.0)
    verdict = "PASS" if margin >= 0 else "FAIL"
    return Check(device, quantity, check, r, 1.0, limit, "ratio", margin, verdict,
                 "" if verdict == "PASS" else likely_cause(r, se, tol),
                 (why + "; " if why else "") + f"standard error {se:.2g}, tolerance {tol:g}",
                 None if t is None else (t[ok], m, p))


def mean_check(device: str, quantity: str, values: np.ndarray, unit: str, noise: float,
               res: float, bias: float, every: int = 1, expected: float = 0.0) -> Check:
    """The mean at rest against ``expected`` (the rig file's model of the sensor's reading
    at rest: its bias, 0 unless the file gives one) within the bias tolerance ``bias``."""
    v = values[np.isfinite(values)][::max(every, 1)]
    if v.size < 2:
        return Check(device, quantity, "offset at rest", None, expected, None, unit, None,
                     "NOT RUN", why="no samples")
    mean = float(np.mean(v))
    sigma = math.sqrt(noise ** 2 + res ** 2 / 12)
    limit = bias + SIGMAS * sigma / math.sqrt(v.size) + 0.5 * res
    margin = limit - abs(mean - expected)
    verdict = "PASS" if margin >= 0 else "FAIL"
    return Check(device, quantity, "offset at rest", mean, expected, limit, unit, margin,
                 verdict,
                 "" if verdict == "PASS" else "an offset: a sensor's offset applied twice "
                 "or not at all, an offset in the wrong unit (the reading's, not SI), or the "
                 "device is not at rest",
                 f"mean of {v.size} samples; bias tolerance {bias:g} {unit}, noise "
                 f"{noise:g}, resolution {res:g}")


def noise_check(device: str, quantity: str, values: np.ndarray, unit: str, noise: float,
                lsb: float, factor: float, every: int = 1, res: float = 0.0) -> Check:
    """The standard deviation at rest against the spec: the rig file's noise and its
    resolution ``lsb`` (the sensor's reading as the rig file knows it); ``res``: the
    binding's step, a quantisation allowed on top."""
    v = values[np.isfinite(values)][::max(every, 1)]
    if v.size < 3:
        return Check(device, quantity, "noise at rest", None, None, None, unit, None,
                     "NOT RUN", why="no samples")
    std = float(np.std(v - np.polyval(np.polyfit(np.arange(v.size), v, 1),
                                      np.arange(v.size))))
    spec = math.sqrt(noise ** 2 + lsb ** 2 / 12)
    hi = factor * spec + 0.5 * max(res, lsb)
    lo = spec / factor if noise >= lsb and noise > 0 else 0.0
    margin = min(std - lo, hi - std) if lo > 0 else hi - std
    verdict = "PASS" if margin >= 0 else "FAIL"
    cause = ""
    if verdict == "FAIL":
        cause = ("the reading does not move as its noise says it must: the sensor is "
                 "pinned at a constant, or the quantity is bound to an object or signal "
                 "that does not carry it (or far coarser than the rig file's resolution)"
                 if std < lo else
                 f"{std / spec:.3g} x noisier than its spec: "
                 + (nearest_factor(std / spec, factor) or "a wrong scale (too large)")
                 + ", or a loose or noisy connection, or the rig is not at rest")
    return Check(device, quantity, "noise at rest", std, spec, [lo, hi], unit, margin,
                 verdict, cause, f"standard deviation (trend removed) of {v.size} samples; "
                 f"spec noise {noise:g} {unit}, resolution {lsb:g} (the binding's step "
                 f"{res:g}), noise_factor {factor:g}")


def fraction_check(device: str, quantity: str, check: str, fraction: float,
                   minimum: float, why: str, cause: str) -> Check:
    margin = fraction - minimum
    verdict = "PASS" if margin >= 0 else "FAIL"
    return Check(device, quantity, check, fraction, 1.0, minimum, "fraction", margin, verdict,
                 "" if verdict == "PASS" else cause, why)


def resolution(binding: Any, device: str, quantity: str) -> float:
    """One step of the quantity as the binding carries it (SI): the DBC signal's scale
    times the rig file's conversion, or a CANopen count's; 0 for a float."""
    kind = binding.kinds.get(device)
    if kind == "canopen":
        co = binding.canopen
        spec = co.nodes.get(co.node_of.get(device, -1))
        if spec is None:
            return 0.0
        for q in spec.telemetry.get(device, ()):
            if q.quantity == quantity:
                return 0.0 if q.ref.code in "fd" else abs(q.conv.scale)
        return 0.0
    for m in binding.telemetry.get(device, ()):
        for f in m.fields:
            if f.quantity == quantity:
                sig = next((s for s in m.codec.signals if s.name == f.signal), None)
                if sig is None or getattr(sig, "is_float", False):
                    return 0.0
                return abs(float(sig.scale) * f.scale)
    return 0.0
