"""The recorded commissioning runs read against the physics (``checks`` writes the rows).

At rest: each sensor's offset (against the file's bias, 0 unless it gives one) and noise.
Moving, per excitation (``plan.Phase``): the measured change of each quantity from its
level just before the excitation against what the physics predicts from the commands
actually sent, through the *measured* model (``model.MeasuredModel``: the rig file's model
with its friction, lag, inertia, couples and beam as commissioning measured them, each
that is not a binding's factor; ``harness.history.twin`` runs it):

- wheel speed: -(the torque's integral) / rotor inertia, through the model's wheel (its
  lag, friction and limits), per pulse sign, over the pulse and its settling (the coast
  after it is the friction's, measured); the wheel's torque reading against its command;
- hub rate: the torque's integral over the hub's inertia plus the beam's response; the
  momentum balance: the hub rate against minus the wheel's measured momentum change over
  the hub's inertia (plus the model's beam response); the hub angle's change against the
  integral of the rate less its bias at rest;
- valves: each valve's impulse (the hub rate's change times the inertia) against couple x
  on-time through the model, and its read-back;
- piezo: each patch sensor against the model's response to its own channel's chirp;
- accelerometer: the tip's response to the wheel, the valves and the ring against the
  model's (its modes, first one first);
- rotor: its speed against its command, its angle's derivative against its speed.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from harness.commissioning.checks import (
    INTEGRATION_FRACTION,
    READBACK_MIN_FRACTION,
    Check,
    fraction_check,
    mean_check,
    noise_check,
    ratio_check,
    resolution,
)
from harness.commissioning.plan import CommissionPlan
from rig_models.devices import G0_M_S2

BASE_S = 0.2  # the level before an excitation: the mean over this long before it
SETTLE_S = 0.5  # the rest run's first samples (the monitor's start-up) are not judged


def _tol(rig: Any) -> dict[str, float]:
    return dict(rig.data["tolerances"])


def _every(rig: Any, device: str) -> int:
    return int(rig.data["bus"]["sync_divider"][device])


def rest_checks(plan: CommissionPlan, cols: Any, dt_s: float) -> list[Check]:
    rig, b = plan.rig, plan.rig.binding
    tol = _tol(rig)
    t = cols.time_s[: cols.rows]
    win = t >= SETTLE_S
    out: list[Check] = []
    hub, acc, pz = rig.section("hub_sensor"), rig.section("accelerometer"), \
        rig.section("piezo_amplifier")
    f = tol["noise_factor"]
    if "hub_sensor" in plan.bound:
        ang = np.radians(cols.column("/attitude/angle_deg")[win])
        rate = np.radians(cols.column("/attitude/rate_deg_s")[win])
        e = _every(rig, "hub_sensor")
        res_a = resolution(b, "hub_sensor", "angle")
        res_r = resolution(b, "hub_sensor", "rate")
        out.append(noise_check("hub_sensor", "angle", ang, "rad", hub["angle_noise_rms_rad"],
                               hub["angle_lsb_rad"], f, e, res_a))
        out.append(mean_check("hub_sensor", "rate", rate, "rad/s", hub["rate_noise_rms_rad_s"],
                              max(res_r, hub["rate_lsb_rad_s"]), tol["rate_bias_rad_s"], e,
                              expected=float(hub.get("rate_bias_rad_s") or 0.0)))
        out.append(noise_check("hub_sensor", "rate", rate, "rad/s",
                               hub["rate_noise_rms_rad_s"], hub["rate_lsb_rad_s"], f, e,
                               res_r))
    if "accelerometer" in plan.bound:
        a = cols.column("/tip/accel_m_s2")[win]
        e = _every(rig, "accelerometer")
        res = resolution(b, "accelerometer", "accel")
        angle = np.radians(cols.column("/attitude/angle_deg")[win]) \
            if "hub_sensor" in plan.bound else np.zeros(1)
        out.append(mean_check("accelerometer", "accel", a, "m/s^2", acc["noise_rms_m_s2"],
                              max(res, acc["lsb_m_s2"]), tol["accel_bias_m_s2"], e,
                              expected=accel_at_rest(acc, float(np.mean(angle)))))
        out.append(noise_check("accelerometer", "accel", a, "m/s^2", acc["noise_rms_m_s2"],
                               acc["lsb_m_s2"], f, e, res))
    if "piezo_amplifier" in plan.bound:
        e = _every(rig, "piezo_amplifier")
        for ch in (1, 2):
            v = cols.column(f"/piezo/sensor_ch{ch}_v")[win]
            res = resolution(b, "piezo_amplifier", f"sensor_ch{ch}")
            out.append(mean_check("piezo_amplifier", f"sensor_ch{ch}", v, "V",
                                  pz["sensor_noise_rms_v"], res, tol["piezo_bias_v"], e))
            out.append(noise_check("piezo_amplifier", f"sensor_ch{ch}", v, "V",
                                   pz["sensor_noise_rms_v"], res, f, e, res))
    if "reaction_wheel" in plan.bound:
        v = cols.column("/wheel/speed_rad_s")[win]
        res = resolution(b, "reaction_wheel", "speed")
        out.append(mean_check("reaction_wheel", "speed", v, "rad/s", 0.0, res, 0.0,
                              _every(rig, "reaction_wheel")))
    if "disturbance_rotor" in plan.bound:
        v = cols.column("/rotor/speed_rad_s")[win]
        res = resolution(b, "disturbance_rotor", "speed")
        out.append(mean_check("disturbance_rotor", "speed", v, "rad/s", 0.0, res, 0.0,
                              _every(rig, "disturbance_rotor")))
    return out


def accel_at_rest(acc: dict[str, Any], hub_angle_rad: float) -> float:
    """The rig file's model of the accelerometer's reading at rest: its bias and the
    gravity its tilted axis picks up at this hub angle, times its scale error (0 when the
    file gives none of them)."""
    g = G0_M_S2 * math.sin(float(acc.get("tilt_rad") or 0.0)) * math.cos(
        hub_angle_rad - float(acc.get("tilt_azimuth_rad") or 0.0))
    return (1.0 + float(acc.get("scale_error") or 0.0)) * g + float(acc.get("bias_m_s2") or 0.0)


def _twin(model: Any, cols: Any, dt_s: float) -> dict[str, np.ndarray]:
    from harness.history.twin import COMMANDS, simulate

    n = cols.rows
    commands = {c: cols.column(c) for c in COMMANDS[:4]}
    return simulate(model.data, dt_s, n, commands)


def _delta(x: np.ndarray, t: np.ndarray, t0: float, t1: float) -> tuple[np.ndarray, np.ndarray]:
    """x over [t0, t1] minus its mean over [t0 - BASE_S, t0)."""
    base = (t >= t0 - BASE_S) & (t < t0)
    sel = (t >= t0) & (t <= t1)
    level = float(np.mean(x[base])) if base.any() else float(x[sel][0])
    return x[sel] - level, sel


def moving_checks(plan: CommissionPlan, cols: Any, dt_s: float, model: Any) -> list[Check]:
    """The moving run's checks against the physics of ``model`` (a ``MeasuredModel``: the
    rig file's model with what commissioning measured of it)."""
    rig, b = plan.rig, plan.rig.binding
    tol = _tol(rig)
    t = cols.time_s[: cols.rows]
    twin = _twin(model, cols, dt_s)
    physics = model.physics
    out: list[Check] = []
    t_end = float(t[-1]) if t.size else 0.0
    done = [p for p in plan.phases if p.quiet_end_s <= t_end + 1e-9]
    for p in plan.phases:
        if p not in done:
            out.append(Check(p.name, "-", "excitation not judged", None, None, None, "", None,
                             "NOT RUN", why=f"the run stopped at t = {t_end:.3f} s, before "
                             f"its end at {p.quiet_end_s:.3f} s"))
    plan = CommissionPlan(plan.rig, plan.rig_ref, plan.bound, done, plan.duration_s)
    hub = rig.section("hub_sensor")
    inertia = float(physics.plant.inertia_kg_m2)
    rotor_j = float(rig.section("reaction_wheel")["rotor_inertia_kg_m2"])
    settle = max(10 * float(physics.section("reaction_wheel")["torque_lag_s"]), 0.1)
    rate = np.radians(cols.column("/attitude/rate_deg_s"))
    rate_twin = np.radians(twin["/attitude/rate_deg_s"])
    ang = np.radians(cols.column("/attitude/angle_deg"))
    # a sensor's noise in the ratios: the rig file's noise and resolution (its lsb: the
    # reading as bound; a binding far coarser than it is the rig file's inconsistency)
    rate_sigma = math.sqrt(hub["rate_noise_rms_rad_s"] ** 2 + hub["rate_lsb_rad_s"] ** 2 / 12)
    e_hub = _every(rig, "hub_sensor")
    hub_bound = "hub_sensor" in plan.bound

    for sign in ("+", "-"):
        ph = plan.phase(f"wheel{sign}")
        if ph is None:
            continue
        t0, t1 = ph.start_s, ph.quiet_end_s
        w = cols.column("/wheel/speed_rad_s")
        # the pulse and its settling only: the coast after it is the friction's (measured)
        dw, sel_w = _delta(w, t, t0, min(ph.end_s + settle, t1))
        dw_twin, _ = _delta(twin["/wheel/speed_rad_s"], t, t0, min(ph.end_s + settle, t1))
        res_w = resolution(b, "reaction_wheel", "speed")
        e_w = _every(rig, "reaction_wheel")
        out.append(ratio_check(
            "reaction_wheel", "speed", f"speed change vs -torque integral / rotor inertia "
            f"(pulse {sign})", dw, dw_twin, res_w / math.sqrt(12),
            tol["torque_fraction"] + tol["inertia_fraction"], e_w,
            why=f"expected {float(dw_twin[-1]):.4g} rad/s at the end, measured "
                f"{float(dw[-1]):.4g}, the model's friction "
                f"{physics.section('reaction_wheel')['friction_coulomb_n_m']:.3g} N m; a miss "
                "is the speed's conversion or the torque command's", t=t[sel_w]))
        sel = (t >= t0) & (t <= t1)
        tq = cols.column("/wheel/torque_n_m")
        on = (t >= ph.start_s) & (t < ph.end_s + 0.1)
        res_t = resolution(b, "reaction_wheel", "torque")
        out.append(ratio_check(
            "reaction_wheel", "torque", f"torque reading vs the model's torque (pulse {sign})",
            tq[on], twin["/wheel/torque_n_m"][on], res_t / math.sqrt(12),
            tol["torque_fraction"], e_w, t=t[on]))
        if hub_bound:
            dr, _ = _delta(rate, t, t0, t1)
            dr_twin, _ = _delta(rate_twin, t, t0, t1)
            out.append(ratio_check(
                "hub_sensor", "rate", f"hub rate change vs torque integral / hub inertia, "
                f"with the beam (pulse {sign})", dr, dr_twin, rate_sigma,
                tol["inertia_fraction"] + tol["torque_fraction"], e_hub, t=t[sel]))
            # momentum balance: the rigid part from the measured wheel speed, the beam's
            # part from the model
            dw_all, _ = _delta(w, t, t0, t1)
            dw_all_twin, _ = _delta(twin["/wheel/speed_rad_s"], t, t0, t1)
            beam_part = dr_twin + rotor_j / inertia * dw_all_twin
            pred = -rotor_j / inertia * dw_all + beam_part
            out.append(ratio_check(
                "hub_sensor", "rate", f"momentum balance: hub rate change vs -(wheel momentum "
                f"change) / hub inertia (pulse {sign})", dr, pred, rate_sigma,
                2 * tol["inertia_fraction"], e_hub,
                why="a miss with the two checks above passing is the wheel's speed; with the "
                    "hub rate's own check failing, the rate", t=t[sel]))

    for sign in ("+", "-"):
        ph = plan.phase(f"valve{sign}")
        if ph is None or not hub_bound:
            continue
        t0, t1 = ph.start_s, ph.quiet_end_s
        dr, sel = _delta(rate, t, t0, t1)
        dr_twin, _ = _delta(rate_twin, t, t0, t1)
        tv = physics.section("thruster_valves")
        couple = tv["couple_n_m"] if sign == "+" or tv.get("couple_negative_n_m") is None \
            else tv["couple_negative_n_m"]
        out.append(ratio_check(
            "thruster_valves", f"valve_{'pos' if sign == '+' else 'neg'}",
            f"impulse (hub rate change x inertia) vs couple x on-time ({couple:g} N m x "
            f"{ph.end_s - ph.start_s:g} s)", dr, dr_twin, rate_sigma,
            tol["couple_fraction"] + tol["inertia_fraction"], e_hub,
            why=f"measured impulse {float(np.mean(dr[-50:])) * inertia:.4g} N m s, expected "
                f"{float(np.mean(dr_twin[-50:])) * inertia:.4g}", t=t[sel]))
        vs = cols.column("/thrusters/valve_state")
        delay = rig.section("thruster_valves")["open_delay_s"]
        e_v = _every(rig, "thruster_valves")
        on = (t >= ph.start_s + delay + 2 * e_v * dt_s) & (t < ph.end_s)
        want = 1 if sign == "+" else -1
        frac = float(np.mean(vs[on] == want)) if on.any() else 0.0
        out.append(fraction_check(
            "thruster_valves", f"valve_{'pos' if sign == '+' else 'neg'}_open",
            f"read-back while commanded open (valve {sign})", frac, READBACK_MIN_FRACTION,
            f"fraction of the on-time after the opening delay ({delay:g} s) and two "
            "telemetry periods with this valve read open and the other closed",
            "the read-back is bound to the other valve's bit or a wrong object, or the "
            "command to the wrong valve"))

    hub_moves = [p for p in plan.phases if p.name[:5] in ("wheel", "valve") or p.name == "ring"]
    if hub_bound and hub_moves:
        t0 = min(p.start_s for p in hub_moves)
        t1 = max(p.quiet_end_s for p in hub_moves)
        sel = (t >= t0 - BASE_S) & (t <= t1)
        # the rate's bias at rest (measured) is no motion of the angle's
        ts, a_s, r_s = t[sel], ang[sel], rate[sel] - model.rate_bias_rad_s
        integral = np.concatenate(([0.0], np.cumsum(0.5 * (r_s[1:] + r_s[:-1]) * np.diff(ts))))
        res_a = hub["angle_lsb_rad"]
        out.append(ratio_check(
            "hub_sensor", "angle", "angle change vs the rate's integral", a_s - a_s[0],
            integral, math.sqrt(hub["angle_noise_rms_rad"] ** 2 + res_a ** 2 / 12),
            INTEGRATION_FRACTION, e_hub,
            why="a miss with the rate's checks passing is the angle's conversion; the rate "
                f"less its bias at rest {model.rate_bias_rad_s:.3g} rad/s", t=ts))

    if "accelerometer" in plan.bound:
        moving = hub_moves
        if moving:
            t0, t1 = moving[0].start_s, moving[-1].quiet_end_s
            acc = rig.section("accelerometer")
            a = cols.column("/tip/accel_m_s2")
            da, sel = _delta(a, t, t0, t1)
            da_twin, _ = _delta(twin["/tip/accel_m_s2"], t, t0, t1)
            f1 = float(physics.plant.hub_free_modes()[0][0]) / (2 * math.pi)
            res = acc["lsb_m_s2"]
            corr = float(np.corrcoef(da, da_twin)[0, 1]) if da.size > 2 and np.std(da) > 0 \
                else 0.0
            out.append(ratio_check(
                "accelerometer", "accel", f"tip acceleration vs the model's ring-down "
                f"(first mode {f1:.3g} Hz)", da, da_twin,
                math.sqrt(acc["noise_rms_m_s2"] ** 2 + res ** 2 / 12), tol["modal_fraction"],
                _every(rig, "accelerometer"), why=f"correlation with the model {corr:.3f}",
                t=t[sel]))

    for ch in (1, 2):
        ph = plan.phase(f"piezo{ch}")
        if ph is None:
            continue
        pz = rig.section("piezo_amplifier")
        v = cols.column(f"/piezo/sensor_ch{ch}_v")
        dv, sel = _delta(v, t, ph.start_s, ph.end_s)
        dv_twin, _ = _delta(twin[f"/piezo/sensor_ch{ch}_v"], t, ph.start_s, ph.end_s)
        res = resolution(b, "piezo_amplifier", f"sensor_ch{ch}")
        out.append(ratio_check(
            "piezo_amplifier", f"sensor_ch{ch}", f"patch sensor vs the model's response to "
            f"its drive's chirp (channel {ch})", dv, dv_twin,
            math.sqrt(pz["sensor_noise_rms_v"] ** 2 + res ** 2 / 12), tol["modal_fraction"],
            _every(rig, "piezo_amplifier"),
            why="a miss is the sensor's conversion or the drive's (voltage_ch"
                f"{ch})", t=t[sel]))

    ph = plan.phase("rotor")
    if ph is not None:
        e_r = _every(rig, "disturbance_rotor")
        cmd = float(ph.segment["rotor_speed_rad_s"])
        lag = float(rig.section("disturbance_rotor")["speed_lag_s"])
        late = (t >= max(ph.start_s + 5 * lag, ph.end_s - 1.0)) & (t < ph.end_s)
        sp = cols.column("/rotor/speed_rad_s")
        res = resolution(b, "disturbance_rotor", "speed")
        out.append(ratio_check(
            "disturbance_rotor", "speed", f"speed vs its command ({cmd:g} rad/s, after "
            f"5 lags of {lag:g} s)", sp[late], np.full(int(late.sum()), cmd),
            res / math.sqrt(12), tol["speed_fraction"], e_r))
        ra = np.unwrap(cols.column("/rotor/angle_rad")[late][::e_r])
        ts = t[late][::e_r]
        if ra.size > 3:
            slope = np.gradient(ra, ts)
            res_a = resolution(b, "disturbance_rotor", "angle")
            sig = (res_a / math.sqrt(12)) * math.sqrt(2) / (e_r * dt_s)
            out.append(ratio_check(
                "disturbance_rotor", "angle", "angle's derivative vs the speed reading",
                slope, sp[late][::e_r], sig, INTEGRATION_FRACTION, 1))
    return out
