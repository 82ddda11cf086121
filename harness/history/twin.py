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

COMMANDS = ("/wheel/torque_cmd_n_m", "/thrusters/valve_cmd", "/piezo/cmd_ch1_v",
            "/piezo/cmd_ch2_v", "/rotor/speed_rad_s")
SENSORS = ("/attitude/angle_deg", "/attitude/rate_deg_s", "/tip/accel_m_s2",
           "/wheel/speed_rad_s", "/wheel/torque_n_m", "/piezo/sensor_ch1_v",
           "/piezo/sensor_ch2_v")


WAIT_TICKS = 20_000
"""How far the channels read may run ahead of one not yet seen before it is taken as
absent (bounds the memory of a recording that lacks a channel)."""


class TwinError(Exception):
    """The run cannot be replayed through the twin (no recording, no config, bad rig)."""


def _noise_of(rig: dict[str, Any]) -> dict[str, float]:
    acc, hub = rig["accelerometer"], rig["hub_sensor"]
    return {"/tip/accel_m_s2": acc["noise_rms_m_s2"],
            "/attitude/angle_deg": math.degrees(hub["angle_noise_rms_rad"]),
            "/attitude/rate_deg_s": math.degrees(hub["rate_noise_rms_rad_s"]),
            "/piezo/sensor_ch1_v": rig["piezo_amplifier"]["sensor_noise_rms_v"],
            "/piezo/sensor_ch2_v": rig["piezo_amplifier"]["sensor_noise_rms_v"]}


MAX_RATIO = 3.0
"""The default alarm threshold: a channel whose residual's rms is more than this many times
its noise rms (``harness twin --max-ratio``). A rig that matches its model sits at about 1;
3 leaves room for a noise spec that is a little off, not for a changed rig or a quantity
bound to the wrong object."""


def _canopen(rig: dict[str, Any], device: str) -> dict[str, Any] | None:
    d = (rig.get("devices") or {}).get(device)
    return d if isinstance(d, dict) and d.get("binding") == "canopen" else None


def _scale(spec: Any) -> tuple[float, float] | None:
    if not isinstance(spec, dict):
        return None
    scale, offset = spec.get("scale"), spec.get("offset", 0.0)
    if isinstance(scale, int | float) and not isinstance(scale, bool) and scale > 0 \
            and isinstance(offset, int | float) and math.isfinite(scale):
        return float(scale), float(offset)
    return None


def command_steps(rig: dict[str, Any]) -> tuple[tuple[float, float] | None, ...]:
    """(step, offset) of each command a CANopen device takes as an integer of its object
    (wheel torque, valves, piezo ch1, ch2; None: taken as it is): the drive quantises what the
    harness sends, so the twin must too (unquantised, a virtual CANopen rig that is exactly
    its model left the hub angle's residual at 1.9 x its noise)."""
    wheel, piezo = _canopen(rig, "reaction_wheel"), _canopen(rig, "piezo_amplifier")

    def cmd(d: dict[str, Any] | None, key: str) -> tuple[float, float] | None:
        return _scale((d.get("commands") or {}).get(key)) if d else None

    return (cmd(wheel, "torque_cmd"), None, cmd(piezo, "voltage_ch1"),
            cmd(piezo, "voltage_ch2"))


def telemetry_steps(rig: dict[str, Any]) -> dict[str, float]:
    """channel -> the quantisation step a CANopen device reports it in (the rig file's device
    data): the noise floor of a channel the rig file gives no noise for."""
    out = {}
    wheel = _canopen(rig, "reaction_wheel")
    if wheel:
        tlm = wheel.get("telemetry") or {}
        for key, channel in (("speed", "/wheel/speed_rad_s"), ("torque", "/wheel/torque_n_m")):
            sc = _scale(tlm.get(key))
            if sc:
                out[channel] = sc[0]
    return out


def _quantise(v: float, step: tuple[float, float] | None) -> float:
    if step is None or not math.isfinite(v):
        return v
    scale, offset = step
    return round((v - offset) / scale) * scale + offset


class TwinModel:
    """The noise-free twin of a rig file, advanced one tick at a time."""

    def __init__(self, rig_data: dict[str, Any], dt_s: float) -> None:
        from rig_models.rig_file import rig_from_dict
        from rig_models.virtual_rig import VirtualRig

        self.steps = command_steps(rig_data)
        quiet = copy.deepcopy(rig_data)
        quiet["accelerometer"]["noise_rms_m_s2"] = 0.0
        quiet["hub_sensor"]["angle_noise_rms_rad"] = 0.0
        quiet["hub_sensor"]["rate_noise_rms_rad_s"] = 0.0
        quiet["hub_sensor"]["rate_random_walk_rad_s_sqrt_s"] = 0.0  # a drawn drift: noise
        quiet["piezo_amplifier"]["sensor_noise_rms_v"] = 0.0
        quiet["devices"] = None  # the physics only: no device speaks on a bus here
        # the model the rig file states (its friction, biases, lags included), never the
        # as_built: overlay a virtual rig emulates: the twin measures the rig against it
        quiet["as_built"] = None
        if isinstance(quiet.get("bus"), dict):  # nor the harness: a DBC's SYNC would need them
            quiet["bus"] = dict(quiet["bus"], sync=None, heartbeat=None)
        self.rig = VirtualRig(rig_from_dict(quiet, source="twin rig"), bus=None,  # type: ignore[arg-type]
                              dt_s=dt_s)
        self.rig.armed, self.rig.safe = True, True  # no heartbeat: the watchdog stays out
        self.k = 0

    def tick(self, torque_n_m: float, valve: float, ch1_v: float, ch2_v: float
             ) -> tuple[float, ...]:
        """The sensors at this tick (in ``SENSORS`` order), then the harness's command
        sent after them, held over the next step."""
        rig = self.rig
        if self.k:
            rig.step()
        self.k += 1
        y = rig.plant.c @ rig.x + rig.plant.d @ rig.u
        angle, rate = rig.hub_sensor.sample(y[0], y[1])
        modal = rig.x[1:1 + rig.n_modes]
        gains = rig.piezo_gains
        out = (math.degrees(angle), math.degrees(rate), rig.accel.sample(y[2]),
               rig.wheel.speed_rad_s, rig.wheel.torque_n_m,
               float(gains[0].sensor @ modal) if gains else 0.0,
               float(gains[1].sensor @ modal) if len(gains) > 1 else 0.0)
        q = self.steps  # as the devices take them (a drive's integer of its object)
        rig.wheel.command(_quantise(torque_n_m, q[0]), True)
        rig.valves.command(int(round(valve)))
        rig.piezo.command(_quantise(ch1_v, q[2]), _quantise(ch2_v, q[3]))
        return out


def simulate(rig_data: dict[str, Any], dt_s: float, n: int,
             commands: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The noise-free twin's sensor channels over ``n`` ticks, driven by ``commands``
    (arrays of ``n`` samples by channel name; missing ones are 0)."""
    twin = TwinModel(rig_data, dt_s)
    zeros = np.zeros(n)
    cmd = [commands.get(name, zeros) for name in COMMANDS[:4]]
    rows = [twin.tick(*(float(c[k]) for c in cmd)) for k in range(n)]
    arr = np.array(rows, dtype=float).reshape(n, len(SENSORS))
    return {name: arr[:, i] for i, name in enumerate(SENSORS)}


class _Pending:
    """A channel's samples read but not yet compared, by tick (bounded by the recording's
    interleaving: the loop writes every channel's block for the same rows together)."""

    def __init__(self) -> None:
        self.ticks: list[np.ndarray] = []
        self.vals: list[np.ndarray] = []
        self.last = -1

    def add(self, ticks: np.ndarray, vals: np.ndarray) -> None:
        self.ticks.append(ticks)
        self.vals.append(vals)
        if ticks.size:
            self.last = max(self.last, int(ticks.max()))

    def take(self, k0: int, k1: int) -> np.ndarray:
        """Values of ticks k0..k1 (NaN where none), dropping them and anything older."""
        out = np.full(k1 - k0 + 1, np.nan)
        if not self.ticks:
            return out
        t, v = np.concatenate(self.ticks), np.concatenate(self.vals)
        sel = (t >= k0) & (t <= k1)
        out[t[sel] - k0] = v[sel]
        keep = t > k1
        self.ticks, self.vals = ([t[keep]], [v[keep]]) if keep.any() else ([], [])
        return out


class _Residual:
    """A channel's residual statistics, streaming."""

    def __init__(self) -> None:
        self.n = 0
        self.sumsq = 0.0
        self.rec_sumsq = 0.0
        self.worst = 0.0
        self.worst_t = 0.0
        self.step = math.inf  # the smallest change between two recorded samples

    def add(self, rec: np.ndarray, twin: np.ndarray, t: np.ndarray) -> None:
        ok = np.isfinite(rec)
        if not ok.any():
            return
        d = np.abs(np.diff(rec[ok]))
        d = d[d > 0]
        if d.size:
            self.step = min(self.step, float(d.min()))
        r = rec[ok] - twin[ok]
        self.n += int(ok.sum())
        self.sumsq += float(np.sum(r ** 2))
        self.rec_sumsq += float(np.sum(rec[ok] ** 2))
        i = int(np.argmax(np.abs(r)))
        if abs(r[i]) >= abs(self.worst):
            self.worst, self.worst_t = float(r[i]), float(t[ok][i])


def twin_residual(run_dir: Path, rig: str | None = None, max_ratio: float = MAX_RATIO
                  ) -> dict[str, Any]:
    """The twin's residual of a recorded run (see the module docstring). ``rig``: the rig
    file the twin is built from (default: the run's own, from its config.yaml). One
    streaming pass over run.rrd: memory does not grow with the run's length. Every channel
    is judged against ``max_ratio`` (its residual's rms over its noise rms): ``beyond``
    lists those past it, worst first; the channels are listed worst first."""
    from harness.testing.evaluate import MissingData
    from harness.testing.judge import ChannelSource

    run_dir = Path(run_dir)
    rrd = run_dir / "run.rrd"
    if not rrd.is_file():
        raise TwinError(f"{run_dir}: no run.rrd (not a run directory)")
    from harness.record.run_folder import RunFolderError, load_run_folder

    try:  # checked as every reader of a run folder checks it: rate, duration, sections
        folder = load_run_folder(run_dir)
    except RunFolderError as exc:
        raise TwinError(str(exc)) from exc
    cfg = folder.config
    from rig_models.rig_file import load_rig, rig_from_dict
    from rig_models.schema import ConfigError

    rate = folder.rate_hz
    dt_s = folder.dt_s
    try:
        rig_cfg = load_rig(rig) if rig is not None else rig_from_dict(
            cfg.get("rig"), source=f"{run_dir / 'config.yaml'} rig")
        model = TwinModel(rig_cfg.data, dt_s)
    except ConfigError as exc:
        raise TwinError(str(exc)) from exc
    pending = {name: _Pending() for name in (*COMMANDS, *SENSORS)}
    stats = {name: _Residual() for name in SENSORS}
    held = [0.0, 0.0, 0.0, 0.0]  # a tick without a recorded command keeps the last one
    rotor_turned = False
    seen: set[str] = set()
    k_next = 0

    def advance(k_end: int) -> None:
        nonlocal k_next, rotor_turned
        if k_end < k_next:
            return
        cmds = [pending[name].take(k_next, k_end) for name in COMMANDS[:4]]
        rotor = pending["/rotor/speed_rad_s"].take(k_next, k_end)
        rotor_turned = rotor_turned or bool(np.nanmax(np.abs(rotor), initial=0.0) > 0)
        rows = []
        for j in range(k_end - k_next + 1):
            for i, c in enumerate(cmds):
                if np.isfinite(c[j]):
                    held[i] = float(c[j])
            rows.append(model.tick(*held))
        twin = np.array(rows, dtype=float).reshape(-1, len(SENSORS))
        t = np.arange(k_next, k_end + 1) * dt_s
        for i, name in enumerate(SENSORS):
            stats[name].add(pending[name].take(k_next, k_end), twin[:, i], t)
        k_next = k_end + 1

    try:
        for entity, t, v in ChannelSource(rrd).blocks([*COMMANDS, *SENSORS]):
            seen.add(entity)
            ticks = np.rint(np.clip(t / dt_s, -1.0, folder.max_ticks + 1.0)).astype(np.int64)
            if ticks.size:  # bounded before the twin sizes anything on it
                folder.check_ticks(f"{rrd}: {entity}", int(ticks.max()))
            pending[entity].add(ticks, v)
            # the loop writes every channel for the same rows: compare up to the tick all
            # have, once all were seen (a channel missing from the recording: once the
            # others have run WAIT_TICKS ahead, it is taken as absent)
            if len(seen) == len(pending) or \
                    max(pending[e].last for e in seen) - k_next > WAIT_TICKS:
                advance(min(pending[e].last for e in seen))
    except (MissingData, RunFolderError) as exc:
        raise TwinError(str(exc)) from exc
    if "/tip/accel_m_s2" not in seen:
        raise TwinError(f"{rrd}: no /tip/accel_m_s2 channel")
    advance(max(pending[e].last for e in seen))
    notes = []
    if rotor_turned:
        notes.append("the disturbance rotor turned (its command is not recorded): the twin "
                     "runs without it, so its vibration is in the residual")
    noise = _noise_of(rig_cfg.data)
    device_steps = telemetry_steps(rig_cfg.data)
    rows = []
    for name in SENSORS:
        st = stats[name]
        if st.n == 0 or (name.startswith("/piezo/sensor")
                         and not rig_cfg.data.get("piezo_patches")):
            continue
        rms = math.sqrt(st.sumsq / st.n)
        nz, source = noise.get(name), "rig file noise"
        if not nz:
            # no noise in the rig file: the quantisation the device reports the channel in
            # (its device data), else the smallest step the recording shows, as uniform
            # quantisation noise (step / sqrt(12))
            step, source = device_steps.get(name), "device data's resolution"
            if step is None and math.isfinite(st.step):
                step, source = st.step, "recorded resolution"
            nz = step / math.sqrt(12.0) if step else None
        rows.append({"channel": name, "samples": st.n, "rms": rms, "worst": st.worst,
                     "worst_time_s": st.worst_t,
                     "recorded_rms": math.sqrt(st.rec_sumsq / st.n),
                     "noise_rms": nz, "noise_from": source if nz else None,
                     "rms_over_noise": rms / nz if nz else None})
    rows.sort(key=lambda r: -math.inf if r["rms_over_noise"] is None else -r["rms_over_noise"])
    beyond = [r["channel"] for r in rows
              if r["rms_over_noise"] is not None and r["rms_over_noise"] > max_ratio]
    wn, zeta = rig_cfg.plant.hub_free_modal_damping()
    modes = [{"mode": i + 1, "omega_rad_s": float(w), "damping_ratio": float(z)}
             for i, (w, z) in enumerate(zip(wn, zeta, strict=True))]
    worst = max((r for r in rows if r["rms_over_noise"] is not None),
                key=lambda r: r["rms_over_noise"], default=None)
    return {"run_dir": str(run_dir), "rig": rig_cfg.source, "rate_hz": rate, "ticks": k_next,
            "channels": rows, "worst_channel": None if worst is None else worst["channel"],
            "max_ratio": max_ratio, "beyond": beyond,
            "model_modes": modes, "identified_modes": _identified(run_dir, cfg, modes),
            "notes": notes}


def _identified(run_dir: Path, cfg: dict[str, Any], model: list[dict[str, Any]]
                ) -> list[dict[str, Any]]:
    """The run's identified modes (its identify.json, else an identification over its
    free-decay windows if it has any) beside the twin's model modes."""
    from harness.record.run_folder import RunFolderError, identified_modes

    try:
        found = identified_modes(run_dir)
    except RunFolderError as exc:
        raise TwinError(str(exc)) from exc
    ident = None if found is None else {"modes": found}
    if ident is None:
        # the identification (scipy, Rerun's reader) only when the run has no identify.json
        from harness.core.identify import analysis_windows, identify_record, load_windows

        if analysis_windows(cfg) is None:
            return []
        try:
            rec = load_windows(run_dir)  # the windows' samples only
            ident = identify_record(rec)
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
