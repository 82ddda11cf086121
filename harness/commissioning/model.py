"""The rig file's model against the rig, measured by the commissioning runs.

``measure`` runs the estimators (``estimates``) on the two recordings and writes one row
per rig-file key it measured: the file's value, the measured value and its 1-sigma, the
limit (the file's tolerance for it plus ``SIGMAS`` sigmas) and a verdict:

- PASS: within the file's tolerance;
- DIFFERS: beyond it, by a factor a rig can differ from its model by (``MODEL_FACTOR_MAX``):
  the rig differs from its file (not a binding error): the lab runs ``harness commission
  --write-rig FILE`` and reviews the file;
- FAIL: an inertia or a couple measured off the file's by a binding's factor (a sign, 1000,
  180/pi, ...) or not at all: the hub rate, the wheel's speed or a valve is misread (their
  own checks say which), never a model difference;
- INFO: measured and reported, judged elsewhere (a sensor's bias at rest: the offset
  check) or not judgeable (a valve's delay beyond what its read-back's period bounds).

The binding checks (``analysis``) then compare each quantity with the physics of the
*measured* model (``MeasuredModel.data``): the file's model with every measurement that
is not a binding's factor in place of the file's value, so that a correctly wired rig
whose friction, lag, inertia, couples or beam differ from its file is judged against what
it is, and a binding error still shows its factor. An estimate never stands in for the
quantity it was measured with (the hub rate's scale is not taken from an inertia that the
hub rate gave): an inertia or a couple a binding's factor away is not taken into the model.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from harness.commissioning import estimates as est
from harness.commissioning.checks import FACTORS, SIGMAS, Check, likely_cause, resolution
from harness.commissioning.plan import CommissionPlan

MODEL_FACTOR_MAX = math.exp(0.5 * min(abs(math.log(f)) for f, _ in FACTORS))
"""How far (a factor, either way) an inertia or a couple may be measured from the rig
file's and still be read as the rig differing from its file: the geometric middle between
1 and the nearest binding factor of ``FACTORS`` (2 pi), sqrt(2 pi) = 2.51. A ratio nearer
1 than that is nearer 1 than any binding error; one beyond it (or negative, or near 0) is
read as a misread quantity."""

SETTLE_LAGS = 10
"""After a wheel torque ends, this many of its lags pass before the wheel is taken to
coast (its motor torque is then e^-10 of what it was)."""
SETTLE_MIN_S = 0.1
"""The shortest settling after any excitation: the valves' closing (the rig file's few ms)
and a telemetry period or two."""
WRITE_SIGMA_FRACTION = 0.5
"""``--write-rig`` writes a measured value that is within the file's tolerance only when
its sigma is under this fraction of the tolerance: the measurement knows it at least twice
as well as the file claims to (a value that DIFFERS is always written)."""

TOLERANCE_OF = {
    "hub.inertia_kg_m2": ("inertia_fraction", "fraction"),
    "thruster_valves.couple_n_m": ("couple_fraction", "fraction"),
    "thruster_valves.couple_negative_n_m": ("couple_fraction", "fraction"),
    "reaction_wheel.torque_lag_s": ("timing_s", "absolute"),
    "reaction_wheel.friction_coulomb_n_m": ("wheel_friction_n_m", "absolute"),
    "reaction_wheel.friction_viscous_n_m_s": ("wheel_friction_n_m", "at max speed"),
    "beam.frequency_factors": ("frequency_fraction", "fraction"),
    "beam.damping_ratios": ("damping_fraction", "fraction"),
    "hub_sensor.rate_bias_rad_s": ("rate_bias_rad_s", "absolute"),
    "accelerometer.bias_m_s2": ("accel_bias_m_s2", "absolute"),
}


@dataclass
class MeasuredModel:
    """The measurements, their rows, and the model the binding checks are judged with."""

    rig: Any  # the rig file under test (RigConfig)
    rows: list[Check] = field(default_factory=list)
    adopted: dict[str, Any] = field(default_factory=dict)  # key -> value in the model
    notes: list[str] = field(default_factory=list)
    rate_bias_rad_s: float = 0.0
    speed_scale: float | None = None  # the wheel speed's change over the -torque integral
    ring_sources: list[str] = field(default_factory=list)  # the readings the modes came from
    _data: dict[str, Any] | None = None
    _physics: Any = None

    @property
    def data(self) -> dict[str, Any]:
        """The rig file's data with the adopted measurements in its model keys."""
        if self._data is None:
            self._data = model_data(self.rig.data, self.adopted)
        return self._data

    @property
    def physics(self) -> Any:
        """A RigConfig of ``data`` for its physics (plant, sections); no device binding."""
        if self._physics is None:
            self._physics = physics_rig(self.data)
        return self._physics

    def row(self, key: str) -> Check | None:
        return next((r for r in self.rows if r.key == key), None)


def _set(data: dict[str, Any], key: str, value: Any) -> None:
    section, name = key.split(".", 1)
    data[section][name] = value


def model_data(data: dict[str, Any], adopted: dict[str, Any]) -> dict[str, Any]:
    out = copy.deepcopy(data)
    for key, value in adopted.items():
        _set(out, key, value)
    return out


def physics_rig(data: dict[str, Any]) -> Any:
    """The rig model of ``data`` for its physics only: no device speaks on a bus here (no
    binding built), no ``as_built:`` overlay (the harness's model, never the rig's truth)."""
    from rig_models.rig_file import rig_from_dict

    quiet = copy.deepcopy(data)
    quiet["devices"] = None
    quiet["as_built"] = None
    if isinstance(quiet.get("bus"), dict):
        quiet["bus"] = dict(quiet["bus"], sync=None, heartbeat=None)
    return rig_from_dict(quiet, source="the measured model")


# ----------------------------------------------------------------------------- rows
def _file_value(rig: Any, key: str, index: int | None = None) -> float:
    section, name = key.split(".", 1)
    d = rig.data[section]
    if key == "thruster_valves.couple_negative_n_m":
        v = d.get(name)
        return float(d["couple_n_m"] if v is None else v)
    if key == "beam.frequency_factors":
        f = d.get("frequency_factors") or []
        return float(f[index]) if index is not None and index < len(f) else 1.0
    if key == "beam.damping_ratios":
        z = d.get("damping_ratios") or []
        return float(z[index]) if index is not None and index < len(z) else \
            float(d["damping_ratio"])
    v = d.get(name)
    return 0.0 if v is None else float(v)


def _tolerance(rig: Any, key: str, expected: float) -> tuple[float, str]:
    """The file's tolerance for ``key`` as an absolute bound on its value, and its text."""
    tkey, kind = TOLERANCE_OF[key.split("[")[0]]
    tol = float(rig.data["tolerances"][tkey])
    if kind == "fraction":
        return tol * abs(expected), f"tolerances.{tkey} {tol:g} x {expected:.4g}"
    if kind == "at max speed":
        w = float(rig.section("reaction_wheel")["max_speed_rad_s"])
        return tol / w, f"tolerances.{tkey} {tol:g} N m at max_speed_rad_s {w:g}"
    return tol, f"tolerances.{tkey} {tol:g}"


def model_row(rig: Any, key: str, label: str, estimate: est.Estimate, unit: str, how: str,
              index: int | None = None, scale_like: bool = False) -> Check:
    """A measured rig-file key against the file's value (see the module docstring).
    ``scale_like``: an estimate that a misread quantity scales (an inertia, a couple):
    a binding's factor away from the file's is a FAIL, not a difference."""
    expected = _file_value(rig, key, index)
    name = key if index is None else f"{key}[{index}]"
    section, quantity = name.split(".", 1)
    tol, tol_text = _tolerance(rig, key, expected)
    value, sigma = estimate.value, estimate.sigma
    limit = tol + SIGMAS * sigma
    margin = limit - abs(value - expected)
    why = f"{how}; measured {value:.5g} +- {sigma:.2g} (1 sigma), the file's {expected:.5g}; " \
        f"limit: {tol_text} + {SIGMAS:g} sigma"
    if not math.isfinite(value) or not math.isfinite(sigma):
        return Check(section, quantity, label, None, expected, None, unit, None, "NOT RUN",
                     why=f"{how}: no finite estimate", key=name)
    verdict, cause = "PASS", ""
    if margin < 0:
        ratio = value / expected if expected else math.inf
        if scale_like and not (ratio > 0 and abs(math.log(ratio)) < math.log(MODEL_FACTOR_MAX)):
            verdict = "FAIL"
            se = sigma / abs(expected) if expected else 0.0
            cause = (f"measured {ratio:.4g} x the file's: " + likely_cause(ratio, se) +
                     "; a binding's factor, not a model difference: a quantity it is measured "
                     "from is misread (their own checks say which)")
        else:
            verdict = "DIFFERS"
            times = f" ({ratio:.4g} x)" if expected and math.isfinite(ratio) else ""
            cause = (f"the rig differs from its file: {name} is {expected:.5g} in the file, "
                     f"measured {value:.5g} +- {sigma:.2g}{times}, beyond the file's "
                     "tolerance: run harness commission --write-rig FILE and review it")
    return Check(section, quantity, label, value, expected, limit, unit, margin, verdict,
                 cause, why, sigma=sigma, key=name)


def info_row(rig: Any, key: str, label: str, estimate: est.Estimate, unit: str, how: str
             ) -> Check:
    expected = _file_value(rig, key)
    section, quantity = key.split(".", 1)
    return Check(section, quantity, label, estimate.value, expected, None, unit, None, "INFO",
                 why=f"{how}; measured {estimate.value:.5g} +- {estimate.sigma:.2g} (1 sigma)",
                 sigma=estimate.sigma, key=key)


def not_run(key: str, label: str, why: str) -> Check:
    section, quantity = key.split(".", 1)
    return Check(section, quantity, label, None, None, None, "", None, "NOT RUN", why=why,
                 key=key)


def adoptable(row: Check | None) -> bool:
    """A measurement the binding checks are judged with: within the file's tolerance or
    differing from it as a rig can, never a binding's factor."""
    return row is not None and row.verdict in ("PASS", "DIFFERS") and row.value is not None


def written(row: Check, rig: Any) -> bool:
    """Whether ``--write-rig`` writes this row's value (``WRITE_SIGMA_FRACTION``)."""
    if row.key.split("[")[0] not in TOLERANCE_OF:
        return False
    if row.verdict == "DIFFERS":
        return True
    if row.verdict not in ("PASS", "INFO") or row.value is None or row.sigma is None:
        return False
    expected = row.expected if isinstance(row.expected, float) else 0.0
    tol, _ = _tolerance(rig, row.key, expected)
    return row.sigma < WRITE_SIGMA_FRACTION * tol


# ----------------------------------------------------------------------------- measure
def _col(cols: Any, name: str) -> np.ndarray | None:
    try:
        return np.asarray(cols.column(name), dtype=float)
    except (ValueError, KeyError):
        return None


def _every(rig: Any, device: str) -> int:
    return int(rig.data["bus"]["sync_divider"][device])


def measure(plan: CommissionPlan, rest_cols: Any, cols: Any, dt_s: float) -> MeasuredModel:
    """Every estimate the two runs allow, its row, and the measured model (module
    docstring). ``cols``: the moving run's recording (None: it did not run)."""
    from harness.commissioning.analysis import SETTLE_S

    rig = plan.rig
    m = MeasuredModel(rig)
    bound = plan.bound
    # ---- at rest: the sensors' biases (judged by the offset checks)
    t_rest = rest_cols.time_s[: rest_cols.rows]
    win = t_rest >= SETTLE_S
    if "hub_sensor" in bound:
        rate = np.radians(rest_cols.column("/attitude/rate_deg_s"))[win]
        try:
            e = est.mean_estimate(rate[:: _every(rig, "hub_sensor")],
                                  resolution(rig.binding, "hub_sensor", "rate"))
            m.rate_bias_rad_s = e.value
            m.rows.append(info_row(rig, "hub_sensor.rate_bias_rad_s", "the hub rate's bias "
                                   "at rest", e, "rad/s", "the rest run's mean (judged by "
                                   "its offset check)"))
            m.adopted["hub_sensor.rate_bias_rad_s"] = e.value
        except est.EstimateError as exc:
            m.rows.append(not_run("hub_sensor.rate_bias_rad_s", "the hub rate's bias at rest",
                                  str(exc)))
    if "accelerometer" in bound:
        acc = rest_cols.column("/tip/accel_m_s2")[win]
        try:
            e = est.mean_estimate(acc[:: _every(rig, "accelerometer")],
                                  resolution(rig.binding, "accelerometer", "accel"))
            m.rows.append(info_row(rig, "accelerometer.bias_m_s2", "the accelerometer's "
                                   "reading at rest", e, "m/s^2", "the rest run's mean, with "
                                   "the gravity a tilted axis picks up at the hub's angle then "
                                   "(judged by its offset check)"))
            m.adopted["accelerometer.bias_m_s2"] = e.value
        except est.EstimateError as exc:
            m.rows.append(not_run("accelerometer.bias_m_s2", "the accelerometer's reading "
                                  "at rest", str(exc)))
    if cols is None:
        return m
    t = np.asarray(cols.time_s[: cols.rows], dtype=float)
    t_end = float(t[-1]) if t.size else 0.0
    done = {p.name: p for p in plan.phases if p.quiet_end_s <= t_end + 1e-9}
    modes = _ring_down(m, plan, cols, t, done)
    _wheel(m, plan, cols, t, dt_s, done)
    _momentum(m, plan, cols, t, dt_s, done, modes)
    if modes:
        _beam(m, modes)
    return m


RING_LABEL = "the beam's modes from the ring-down"


RING_SOURCES = (("accelerometer", "/tip/accel_m_s2", "the tip acceleration"),
                ("hub_sensor", "/attitude/rate_deg_s", "the hub rate"),
                ("piezo_amplifier", "/piezo/sensor_ch1_v", "patch sensor 1"),
                ("piezo_amplifier", "/piezo/sensor_ch2_v", "patch sensor 2"))
"""The readings of the ring-down whose modes are combined: every bound sensor that sees the
beam (the tip accelerometer, the hub rate with the wheel's momentum taken out, the patch
sensors, which are not driven then)."""


def _ring_down(m: MeasuredModel, plan: CommissionPlan, cols: Any, t: np.ndarray,
               done: dict[str, Any]) -> list[est.Mode]:
    """The hub-free modes of the ring-down: each bound sensor's, combined per mode
    (``estimates.combine_modes``)."""
    rig = m.rig
    ring = done.get("ring")
    if ring is None:
        m.notes.append("the beam's modes were not measured (no ring-down): the file's are "
                       "kept")
        return []
    start, end = ring.end_s + SETTLE_MIN_S, ring.quiet_end_s
    if "reaction_wheel" in plan.bound:
        # a wheel left turning by its friction stops within the ring-down: its friction's
        # torque on the hub ends there, a step the beam answers (no free decay across it);
        # the decay is taken after the stop (or before it, whichever is longer)
        w = cols.column("/wheel/speed_rad_s")
        turning = np.flatnonzero((t >= start) & (t < end) & (np.abs(w) > 0))
        if turning.size and float(t[turning[-1]]) < end - SETTLE_MIN_S:
            stop = float(t[turning[-1]]) + SETTLE_MIN_S
            if stop - start < end - stop:
                start = stop
            else:
                end = float(t[turning[-1]])
    sources = []
    used = []
    for device, channel, name in RING_SOURCES:
        if device not in plan.bound or (device == "piezo_amplifier"
                                        and not rig.piezo_patches):
            continue
        x = _col(cols, channel)
        if x is None:
            continue
        clip = None
        if device == "accelerometer":
            clip = rig.accel_range_m_s2
        if device == "hub_sensor":
            x = np.radians(x)
            if "reaction_wheel" in plan.bound:  # the wheel's momentum exchange taken out
                j_r = float(rig.section("reaction_wheel")["rotor_inertia_kg_m2"])
                x = x + j_r / float(rig.plant.inertia_kg_m2) * cols.column(
                    "/wheel/speed_rad_s")
        try:
            modes, _ = est.ring_down_modes(t, x, start, end, clip_level=clip)
        except est.EstimateError as exc:
            m.notes.append(f"the ring-down in {name}: {exc}")
            continue
        sources.append((name, modes))
        used.append(f"{name} ({len(modes)})")
    wn = rig.plant.hub_free_modal_damping()[0]
    combined, notes = est.combine_modes(sources, wn)
    m.notes += notes
    modes = [x for x in combined if x is not None]
    if not modes:
        m.rows.append(not_run("beam.frequency_factors", RING_LABEL,
                              f"no mode found in the ring-down from {start:.2f} s to "
                              f"{end:.2f} s ({', '.join(used) or 'no sensor'}; "
                              "the sensors' own checks say why)"))
        return []
    m.ring_sources = used
    return modes


def _beam(m: MeasuredModel, modes: list[est.Mode]) -> None:
    """The ring-down's hub-free modes as the rig file's beam keys (each constrained mode's
    frequency factor and damping ratio), through the model with the measured inertia."""
    from rig_models.flexible_hub import build_hub_beam

    rig = m.rig
    inertia = float(m.adopted.get("hub.inertia_kg_m2", rig.plant.inertia_kg_m2))
    row_j = m.row("hub.inertia_kg_m2")
    sigma_j = row_j.sigma if adoptable(row_j) and row_j is not None and row_j.sigma else 0.0
    tip = rig.data["hub"]["radius_m"] + rig.data["beam"]["length_m"]
    beam_modes = rig.beam_modes

    def hub_free_at(j: float) -> est.HubFree:
        def hub_free(f: Any, z: Any) -> tuple[np.ndarray, np.ndarray]:
            plant = build_hub_beam(inertia_kg_m2=j, modes=beam_modes,
                                   damping_ratio=np.asarray(z, dtype=float), tip_radius_m=tip,
                                   frequency_factors=np.asarray(f, dtype=float))
            return plant.hub_free_modal_damping()
        return hub_free

    n = len(beam_modes.omega_rad_s)
    f0 = [_file_value(rig, "beam.frequency_factors", k) for k in range(n)]
    z0 = [_file_value(rig, "beam.damping_ratios", k) for k in range(n)]
    inv = est.constrained_modes(modes, hub_free_at(inertia), f0, z0)
    m.notes += inv.notes
    if sigma_j > 0:
        # the hub-free modes move with the hub's inertia: its sigma is in the keys' too
        shifted = est.constrained_modes(modes, hub_free_at(inertia + sigma_j), f0, z0)
        for old, new, out in ((inv.factors, shifted.factors, inv.factors),
                              (inv.dampings, shifted.dampings, inv.dampings)):
            for k, (a, b) in enumerate(zip(old, new, strict=True)):
                if a is not None and b is not None:
                    out[k] = est.Estimate(a.value, math.hypot(a.sigma, b.value - a.value))
    w_file = rig.plant.hub_free_modal_damping()[0]
    factors, dampings = list(f0), list(z0)
    for k, i in enumerate(inv.matched):
        if i is None:
            m.notes.append(f"beam mode {k + 1} was not seen in the ring-down: the file's "
                           "frequency and damping are kept for it")
            continue
        mode = modes[i]
        how = (f"mode {k + 1} in the ring-down ({', '.join(m.ring_sources)}): hub-free "
               f"{mode.omega_rad_s.value / (2 * math.pi):.5g} +- "
               f"{mode.omega_rad_s.sigma / (2 * math.pi):.2g} Hz, damping "
               f"{mode.damping_ratio.value:.4g} +- {mode.damping_ratio.sigma:.2g} (the file's "
               f"model: {w_file[k] / (2 * math.pi):.5g} Hz); mapped onto the constrained mode "
               f"through the model with the hub inertia {inertia:.4g} +- {sigma_j:.2g} kg m^2, "
               "its sigma included")
        fe, ze = inv.factors[k], inv.dampings[k]
        assert fe is not None and ze is not None
        rf = model_row(rig, "beam.frequency_factors", f"mode {k + 1}'s frequency factor", fe,
                       "x", how, index=k)
        rz = model_row(rig, "beam.damping_ratios", f"mode {k + 1}'s damping ratio", ze, "",
                       how, index=k)
        m.rows += [rf, rz]
        if adoptable(rf):
            factors[k] = fe.value
        if adoptable(rz):
            dampings[k] = ze.value
    m.adopted["beam.frequency_factors"] = factors
    m.adopted["beam.damping_ratios"] = dampings
    m._data = m._physics = None


def _wheel(m: MeasuredModel, plan: CommissionPlan, cols: Any, t: np.ndarray, dt_s: float,
           done: dict[str, Any]) -> None:
    rig = m.rig
    if "reaction_wheel" not in plan.bound:
        return
    rw = rig.section("reaction_wheel")
    wheel_phases = [done[n] for n in ("wheel+", "wheel-", "ring") if n in done
                    and "wheel_torque_n_m" in done[n].segment]
    if not wheel_phases:
        return
    cmd = cols.column("/wheel/torque_cmd_n_m")
    lag_s = float(rw["torque_lag_s"])
    torque = _col(cols, "/wheel/torque_n_m")
    key = "reaction_wheel.torque_lag_s"
    if torque is None or not np.isfinite(torque).any():
        m.rows.append(not_run(key, "the torque loop's lag", "no torque reading"))
    else:
        sel = (t >= wheel_phases[0].start_s - 0.1) & (t < wheel_phases[-1].end_s + 0.5)
        try:
            lag = est.first_order_lag(cmd[sel], torque[sel], dt_s,
                                      resolution=resolution(rig.binding, "reaction_wheel",
                                                            "torque"))
            row = model_row(rig, key, "the torque loop's lag", lag.lag_s, "s",
                            f"the torque reading against its command (gain {lag.gain:.4g}, "
                            f"{lag.dead_ticks} dead ticks)")
            m.rows.append(row)
            if adoptable(row):
                m.adopted[key] = lag.lag_s.value
                lag_s = lag.lag_s.value
        except est.EstimateError as exc:
            m.rows.append(not_run(key, "the torque loop's lag", str(exc)))
    speed = cols.column("/wheel/speed_rad_s")
    j_r = float(rw["rotor_inertia_kg_m2"])
    settle = max(SETTLE_LAGS * lag_s, SETTLE_MIN_S)
    # the speed reading's scale, from each pulse's own window (friction's share small):
    # a friction measured with a misread speed is misread by the same factor
    scales = []
    for name in ("wheel+", "wheel-"):
        ph = done.get(name)
        if ph is None:
            continue
        base = (t >= ph.start_s - 0.2) & (t < ph.start_s)
        after = (t >= ph.end_s + settle) & (t < ph.end_s + settle + 0.05)
        impulse = float(np.sum(cmd[(t >= ph.start_s - dt_s) & (t < ph.end_s + settle)])) * dt_s
        if base.any() and after.any() and impulse:
            scales.append((float(np.mean(speed[after])) - float(np.mean(speed[base])))
                          / (-impulse / j_r))
    m.speed_scale = float(np.mean(scales)) if scales else None
    windows = [(done[n].end_s + settle, done[n].quiet_end_s) for n in ("wheel+", "wheel-")
               if n in done]
    label_c, label_v = "the wheel's Coulomb friction", "the wheel's viscous friction"
    res = resolution(rig.binding, "reaction_wheel", "speed")
    try:
        fr = est.coast_down_friction(t, speed, windows, j_r, max(5 * res, 0.05), res)
    except est.EstimateError as exc:
        m.rows += [not_run("reaction_wheel.friction_coulomb_n_m", label_c, str(exc)),
                   not_run("reaction_wheel.friction_viscous_n_m_s", label_v, str(exc))]
        return
    lo, hi = fr.speed_range_rad_s
    how = (f"the coast-downs after the wheel's pulses ({fr.samples} samples, |speed| "
           f"{lo:.3g} to {hi:.3g} rad/s): J dw/dt = -(Coulomb sign(w) + viscous w)")
    coulomb, viscous = fr.coulomb_n_m, fr.viscous_n_m_s
    scale = m.speed_scale
    if scale is not None and scale != 0 and not (
            1 / MODEL_FACTOR_MAX < abs(scale) < MODEL_FACTOR_MAX):
        # the speed reading is a binding's factor off (its own check fails): the friction
        # it gives is that factor off too; taken back by it so the other checks are not
        # bent by the misreading
        coulomb = est.Estimate(coulomb.value / abs(scale), coulomb.sigma / abs(scale))
        viscous = est.Estimate(viscous.value / abs(scale), viscous.sigma / abs(scale))
        how += (f"; the speed reading is {scale:.4g} x the torque's integral (its own check "
                "fails): the friction is divided by that")
    rc = model_row(rig, "reaction_wheel.friction_coulomb_n_m", label_c, coulomb, "N m", how)
    rv = model_row(rig, "reaction_wheel.friction_viscous_n_m_s", label_v, viscous, "N m s",
                   how + f"; the friction at the top speed {hi:.3g} rad/s: "
                   f"{fr.torque_at(hi):.3g} N m")
    m.rows += [rc, rv]
    if adoptable(rc) and adoptable(rv):
        m.adopted["reaction_wheel.friction_coulomb_n_m"] = max(coulomb.value, 0.0)
        m.adopted["reaction_wheel.friction_viscous_n_m_s"] = max(viscous.value, 0.0)
        breakaway = rw.get("friction_breakaway_n_m")
        if breakaway is not None:
            m.adopted["reaction_wheel.friction_breakaway_n_m"] = max(coulomb.value, breakaway)


def _momentum(m: MeasuredModel, plan: CommissionPlan, cols: Any, t: np.ndarray, dt_s: float,
              done: dict[str, Any], measured_modes: list[est.Mode]) -> None:
    rig = m.rig
    if "hub_sensor" not in plan.bound:
        return
    hub_phases = [done[n] for n in ("wheel+", "wheel-", "valve+", "valve-", "ring")
                  if n in done]
    if not hub_phases:
        return
    wheel = "reaction_wheel" in plan.bound
    lag = float(m.adopted.get("reaction_wheel.torque_lag_s",
                              rig.section("reaction_wheel")["torque_lag_s"]))
    settle = max(SETTLE_LAGS * lag, SETTLE_MIN_S)
    first = plan.phases[0].start_s if plan.phases else hub_phases[0].start_s
    segments = [est.Segment(0.5, first, False)] if first > 0.6 else []
    segments += [est.Segment(p.end_s + settle, p.quiet_end_s, True) for p in hub_phases]
    valves = [p for p in hub_phases if p.name in ("valve+", "valve-")]
    # the beam in the hub rate: the ring-down's hub-free modes where it gave them, the
    # file's elsewhere (those the hub sensor's rate resolves)
    wn, zeta = rig.plant.hub_free_modal_damping()
    pick = est.match_modes([x.omega_rad_s.value for x in measured_modes], wn)
    modes = [(float(w), float(z)) if i is None else
             (measured_modes[i].omega_rad_s.value, measured_modes[i].damping_ratio.value)
             for w, z, i in zip(wn, zeta, pick, strict=True)]
    nyquist = math.pi / (dt_s * _every(rig, "hub_sensor"))
    modes = [x for x in modes if x[0] < nyquist / 4]
    rate = np.radians(cols.column("/attitude/rate_deg_s"))
    speed = cols.column("/wheel/speed_rad_s") if wheel else None
    j_r = float(rig.section("reaction_wheel")["rotor_inertia_kg_m2"])
    j_file = float(rig.plant.inertia_kg_m2)
    key = "hub.inertia_kg_m2"
    try:
        mom = est.momentum_exchange(t, rate, speed, j_r, segments,
                                    [p.start_s for p in valves], modes,
                                    resolution(rig.binding, "hub_sensor", "rate"))
    except est.EstimateError as exc:
        m.rows.append(not_run(key, "the hub's inertia", str(exc)))
        return
    impulses: list[est.Estimate] = [est.Estimate(p.value * j_file, p.sigma * j_file)
                                    for p in mom.rate_steps_rad_s]
    inertia_how = "the file's inertia"
    if mom.inertia_kg_m2 is None:
        m.rows.append(not_run(key, "the hub's inertia", "no wheel bound: the momentum "
                              "exchange needs its speed"))
    else:
        row = model_row(rig, key, "the hub's inertia (momentum exchange with the wheel)",
                        mom.inertia_kg_m2, "kg m^2",
                        f"minus the rotor's momentum change over the hub rate's, over "
                        f"{mom.samples} quiet samples (the beam's vibration fitted as free "
                        f"decays of {len(modes)} modes; residual {mom.residual_rms:.2g} rad/s)",
                        scale_like=True)
        m.rows.append(row)
        if adoptable(row):
            m.adopted[key] = mom.inertia_kg_m2.value
            assert mom.impulses_n_m_s is not None
            impulses = list(mom.impulses_n_m_s)
            inertia_how = f"the measured inertia {mom.inertia_kg_m2:.4g}"
    tv = rig.section("thruster_valves")
    e_v = _every(rig, "thruster_valves")
    state = cols.column("/thrusters/valve_state")
    for ph, imp in zip(valves, impulses, strict=True):
        sign = 1 if ph.name == "valve+" else -1
        suffix = "" if sign > 0 else "_negative"
        key_c = f"thruster_valves.couple{suffix}_n_m"
        open_d = tv.get(f"open_delay{suffix}_s")
        close_d = tv.get(f"close_delay{suffix}_s")
        open_d = tv["open_delay_s"] if open_d is None else open_d
        close_d = tv["close_delay_s"] if close_d is None else close_d
        on = (ph.end_s - ph.start_s) + close_d - open_d
        which = "positive" if sign > 0 else "negative"
        couple = est.Estimate(sign * imp.value / on, imp.sigma / on)
        row = model_row(rig, key_c, f"the {which} valve's couple", couple, "N m",
                        f"the hub's momentum change {imp.value:.4g} +- {imp.sigma:.2g} N m s "
                        f"({inertia_how}) over the on-time {on:.4g} s (commanded "
                        f"{ph.end_s - ph.start_s:g} s and the file's delays, opening "
                        f"{open_d:g} s, closing {close_d:g} s: a delay 1 ms off moves the "
                        f"couple by {1e-3 / on:.1%})", scale_like=True)
        m.rows.append(row)
        if adoptable(row):
            m.adopted[key_c] = couple.value
        # the delays, as far as the read-back's period bounds them (reported)
        period = e_v * dt_s
        for what, t_cmd, want in (("open", ph.start_s, sign), ("close", ph.end_s, 0)):
            key_d = f"thruster_valves.{what}_delay{suffix}_s"
            label_d = f"the {which} valve's {'opening' if what == 'open' else 'closing'} delay"
            # a command recorded at a tick acts from the next one (the loop's order)
            d = est.readback_delay(t, state, t_cmd + dt_s, want, period, ph.quiet_end_s)
            if d is None:
                m.rows.append(not_run(key_d, label_d, "the read-back never showed it"))
                continue
            half = d.sigma * math.sqrt(3)
            m.rows.append(Check(
                "thruster_valves", key_d.split(".", 1)[1], label_d, d.value,
                float(open_d if what == "open" else close_d), None, "s", None, "INFO",
                why=f"the read-back answers every {period:g} s: it {what}ed between "
                    f"{d.value - half:.3g} s and {d.value + half:.3g} s after the command "
                    "took effect (reported, not judged: the period bounds it no better than "
                    "the file knows it)", sigma=d.sigma, key=key_d))
