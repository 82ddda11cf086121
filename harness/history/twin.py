"""The twin's residual: a recorded run's own commands through the virtual rig's physics,
against the run's recorded sensors.

The commands are the recorded command channels (``/wheel/torque_cmd_n_m``,
``/thrusters/valve_cmd``, ``/piezo/cmd_ch1_v``, ``/piezo/cmd_ch2_v``); they drive the device
models and the discretised plant of the rig file (``rig_models``) directly, tick by tick, as
the virtual rig does on its SYNCs: the command sent after sample k acts over the step from
k to k + 1 (zero-order hold), then the devices sample. The bus is bypassed on purpose: the
twin checks the physics, not the protocol (``harness replay`` checks the frames). The
twin's sensors are noise-free (the rig file's noise set to 0; bandwidth, range and
quantisation kept), so on a rig that matches its model the residual is the sensors' noise.
The disturbance rotor's speed command is not recorded: a run that spins it is compared
without it (said in the notes).

Per sensor channel: the residual's rms, its worst sample and that sample's time, the rms
of the recorded signal, and the residual's rms over the channel's noise in the rig file
(1: the model explains everything but the noise).
"""

from __future__ import annotations

import copy
import math
from pathlib import Path
from typing import Any

import numpy as np
import yaml

COMMANDS = ("/wheel/torque_cmd_n_m", "/thrusters/valve_cmd", "/piezo/cmd_ch1_v",
            "/piezo/cmd_ch2_v", "/rotor/speed_rad_s")
SENSORS = ("/attitude/angle_deg", "/attitude/rate_deg_s", "/tip/accel_m_s2",
           "/wheel/speed_rad_s", "/wheel/torque_n_m", "/piezo/sensor_ch1_v",
           "/piezo/sensor_ch2_v")


class TwinError(Exception):
    """The run cannot be replayed through the twin (no recording, no config, bad rig)."""


def _noise_of(rig: dict[str, Any]) -> dict[str, float]:
    acc, hub = rig["accelerometer"], rig["hub_sensor"]
    return {"/tip/accel_m_s2": acc["noise_rms_m_s2"],
            "/attitude/angle_deg": math.degrees(hub["angle_noise_rms_rad"]),
            "/attitude/rate_deg_s": math.degrees(hub["rate_noise_rms_rad_s"]),
            "/piezo/sensor_ch1_v": rig["piezo_amplifier"]["sensor_noise_rms_v"],
            "/piezo/sensor_ch2_v": rig["piezo_amplifier"]["sensor_noise_rms_v"]}


def simulate(rig_data: dict[str, Any], dt_s: float, n: int,
             commands: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The noise-free twin's sensor channels over ``n`` ticks, driven by ``commands``
    (arrays of ``n`` samples by channel name; missing ones are 0)."""
    from rig_models.rig_file import rig_from_dict
    from rig_models.virtual_rig import VirtualRig

    quiet = copy.deepcopy(rig_data)
    quiet["accelerometer"]["noise_rms_m_s2"] = 0.0
    quiet["hub_sensor"]["angle_noise_rms_rad"] = 0.0
    quiet["hub_sensor"]["rate_noise_rms_rad_s"] = 0.0
    quiet["piezo_amplifier"]["sensor_noise_rms_v"] = 0.0
    quiet["devices"] = None  # the physics only: no device speaks on a bus here
    rig = VirtualRig(rig_from_dict(quiet, source="twin rig"), bus=None, dt_s=dt_s)  # type: ignore[arg-type]
    rig.armed, rig.safe = True, True  # no heartbeat here: the watchdog stays out of it
    zeros = np.zeros(n)
    torque = commands.get("/wheel/torque_cmd_n_m", zeros)
    valve = commands.get("/thrusters/valve_cmd", zeros)
    p1 = commands.get("/piezo/cmd_ch1_v", zeros)
    p2 = commands.get("/piezo/cmd_ch2_v", zeros)
    out = {name: np.empty(n) for name in SENSORS}
    plant, nm = rig.plant, rig.n_modes
    gains = rig.piezo_gains
    for k in range(n):
        if k:
            rig.step()
        y = plant.c @ rig.x + plant.d @ rig.u
        angle, rate = rig.hub_sensor.sample(y[0], y[1])
        out["/attitude/angle_deg"][k] = math.degrees(angle)
        out["/attitude/rate_deg_s"][k] = math.degrees(rate)
        out["/tip/accel_m_s2"][k] = rig.accel.sample(y[2])
        out["/wheel/speed_rad_s"][k] = rig.wheel.speed_rad_s
        out["/wheel/torque_n_m"][k] = rig.wheel.torque_n_m
        modal = rig.x[1:1 + nm]
        out["/piezo/sensor_ch1_v"][k] = float(gains[0].sensor @ modal) if gains else 0.0
        out["/piezo/sensor_ch2_v"][k] = float(gains[1].sensor @ modal) if len(gains) > 1 \
            else 0.0
        # the harness's command after sample k, held over the next step
        rig.wheel.command(float(torque[k]), True)
        rig.valves.command(int(round(float(valve[k]))))
        rig.piezo.command(float(p1[k]), float(p2[k]))
    return out


def _on_ticks(t: np.ndarray, v: np.ndarray, dt_s: float, n: int) -> np.ndarray:
    """A recorded channel on the tick grid (a channel's row k holds tick k's value)."""
    out = np.full(n, np.nan)
    idx = np.rint(t / dt_s).astype(np.int64)
    ok = (idx >= 0) & (idx < n)
    out[idx[ok]] = v[ok]
    return out


def twin_residual(run_dir: Path, rig: str | None = None) -> dict[str, Any]:
    """The twin's residual of a recorded run (see the module docstring). ``rig``: the rig
    file the twin is built from (default: the run's own, from its config.yaml)."""
    from harness.testing.judge import read_channels

    run_dir = Path(run_dir)
    rrd = run_dir / "run.rrd"
    if not rrd.is_file():
        raise TwinError(f"{run_dir}: no run.rrd (not a run directory)")
    try:
        cfg = yaml.safe_load((run_dir / "config.yaml").read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise TwinError(f"{run_dir}: config.yaml unreadable ({exc})") from exc
    if not isinstance(cfg, dict) or not isinstance(cfg.get("run"), dict):
        raise TwinError(f"{run_dir}: config.yaml has no run section")
    from rig_models.rig_file import load_rig, rig_from_dict
    from rig_models.schema import ConfigError

    try:
        rig_cfg = load_rig(rig) if rig is not None else rig_from_dict(
            cfg.get("rig"), source=f"{run_dir / 'config.yaml'} rig")
    except ConfigError as exc:
        raise TwinError(str(exc)) from exc
    try:
        rate = float(cfg["run"]["rate_hz"])
    except (KeyError, TypeError, ValueError) as exc:
        raise TwinError(f"{run_dir}: config.yaml run.rate_hz missing") from exc
    dt_s = 1.0 / rate
    try:
        channels = read_channels(rrd, set(COMMANDS) | set(SENSORS))
    except Exception as exc:  # noqa: BLE001 - an unreadable recording is bad input
        raise TwinError(f"{rrd}: unreadable ({type(exc).__name__}: {exc})") from exc
    if "/tip/accel_m_s2" not in channels:
        raise TwinError(f"{rrd}: no /tip/accel_m_s2 channel")
    t_end = max(float(t[-1]) for t, _ in channels.values() if len(t))
    n = int(round(t_end / dt_s)) + 1
    cmds = {}
    notes = []
    for name in COMMANDS[:4]:
        if name in channels:
            c = _on_ticks(*channels[name], dt_s, n)
            # a tick without a recorded command keeps the last one (zero-order hold)
            c = _hold(c)
            cmds[name] = c
    rotor = channels.get("/rotor/speed_rad_s")
    if rotor is not None and np.nanmax(np.abs(rotor[1])) > 0:
        notes.append("the disturbance rotor turned (its command is not recorded): the twin "
                     "runs without it, so its vibration is in the residual")
    twin = simulate(rig_cfg.data, dt_s, n, cmds)
    noise = _noise_of(rig_cfg.data)
    rows = []
    for name in SENSORS:
        if name not in channels or (name.startswith("/piezo/sensor")
                                    and not rig_cfg.data.get("piezo_patches")):
            continue
        rec = _on_ticks(*channels[name], dt_s, n)
        ok = np.isfinite(rec)
        if not ok.any():
            continue
        r = rec[ok] - twin[name][ok]
        t = np.arange(n)[ok] * dt_s
        i = int(np.argmax(np.abs(r)))
        rms = float(np.sqrt(np.mean(r ** 2)))
        nz = noise.get(name)
        rows.append({"channel": name, "samples": int(ok.sum()), "rms": rms,
                     "worst": float(r[i]), "worst_time_s": float(t[i]),
                     "recorded_rms": float(np.sqrt(np.mean(rec[ok] ** 2))),
                     "noise_rms": nz, "rms_over_noise": rms / nz if nz else None})
    wn, zeta = rig_cfg.plant.hub_free_modal_damping()
    model = [{"mode": i + 1, "omega_rad_s": float(w), "damping_ratio": float(z)}
             for i, (w, z) in enumerate(zip(wn, zeta, strict=True))]
    worst = max((r for r in rows if r["rms_over_noise"] is not None),
                key=lambda r: r["rms_over_noise"], default=None)
    return {"run_dir": str(run_dir), "rig": rig_cfg.source, "rate_hz": rate, "ticks": n,
            "channels": rows, "worst_channel": None if worst is None else worst["channel"],
            "model_modes": model, "identified_modes": _identified(run_dir, cfg, model),
            "notes": notes}


def _hold(c: np.ndarray) -> np.ndarray:
    ok = np.isfinite(c)
    if not ok.any():
        return np.zeros_like(c)
    idx = np.where(ok, np.arange(c.size), 0)
    np.maximum.accumulate(idx, out=idx)
    out = c[idx]
    out[: int(np.argmax(ok))] = 0.0
    return out


def _identified(run_dir: Path, cfg: dict[str, Any], model: list[dict[str, Any]]
                ) -> list[dict[str, Any]]:
    """The run's identified modes (its identify.json, else an identification over its
    free-decay windows if it has any) beside the twin's model modes."""
    import json

    ident = None
    path = run_dir / "identify.json"
    if path.is_file():
        try:
            ident = json.loads(path.read_text())
        except ValueError:
            ident = None
    if ident is None:
        from harness.commands.identify import analysis_windows, identify_record, load_record

        if analysis_windows(cfg) is None:
            return []
        try:
            t, a, cfg2, _ = load_record(run_dir)
            ident = identify_record(t, a, cfg2, None, analysis_windows(cfg2) or [])
        except Exception:  # noqa: BLE001 - no modes to show beside the residual
            return []
    out = []
    for m in ident.get("modes") or []:
        w = float(m["omega_rad_s"])
        near = min(model, key=lambda mm: abs(math.log(w / mm["omega_rad_s"])))
        out.append({"omega_rad_s": w, "sigma_omega_rad_s": m.get("sigma_omega_rad_s"),
                    "damping_ratio": m.get("damping_ratio"), "model_mode": near["mode"],
                    "model_omega_rad_s": near["omega_rad_s"],
                    "change_percent": 100 * (w / near["omega_rad_s"] - 1),
                    "change_sigmas": (w - near["omega_rad_s"]) / m["sigma_omega_rad_s"]
                    if m.get("sigma_omega_rad_s") else None})
    return out
