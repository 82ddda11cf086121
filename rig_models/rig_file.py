"""The rig file: a YAML description of the rig's physics and device limits.

`load_rig("sgsrt")` loads a built-in rig from `rig_models/rigs/`; any other argument is a path.
"""

from __future__ import annotations

import copy
import hashlib
import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, replace
from functools import cached_property
from pathlib import Path
from typing import Any

from drivers.binding import BindingError, RigBinding, absolutize, build_binding
from drivers.binding.quantities import DEVICES
from rig_models.beam import BeamModes, BeamSpec, beam_modes
from rig_models.devices import G0_M_S2
from rig_models.flexible_hub import HubBeamModel, build_hub_beam
from rig_models.piezo import PatchGains, PiezoPatch, patch_gains
from rig_models.schema import ConfigError, Field, validate
from rig_models.yaml_file import load_yaml

RIGS_DIR = Path(__file__).parent / "rigs"

POSITIVE = {"exclusive_minimum": 0.0}
TWO_PI = 2.0 * math.pi
FRACTION = {"minimum": -0.5, "maximum": 0.5}  # a scale error: reading = (1 + e) x true


def _at_most_modes(value: Any) -> str | None:
    return "expected at most 20 entries (one per kept mode)" if len(value) > 20 else None


RIG_SCHEMA: dict[str, Any] = {
    "name": Field("str", required=True),
    "hub": {
        "inertia_kg_m2": Field("number", "kg m^2", required=True, **POSITIVE),
        "radius_m": Field("number", "m", required=True, minimum=0.0),
        # a table out of level: torque on the hub -gravity_torque * sin(angle - azimuth)
        "gravity_torque_n_m": Field("number", "N m", default=0.0, minimum=0.0, maximum=10.0),
        "gravity_azimuth_rad": Field("number", "rad", default=0.0, minimum=-TWO_PI,
                                     maximum=TWO_PI),
    },
    "beam": {
        "length_m": Field("number", "m", required=True, **POSITIVE),
        "width_m": Field("number", "m", required=True, **POSITIVE),
        "thickness_m": Field("number", "m", required=True, **POSITIVE),
        "youngs_modulus_pa": Field("number", "Pa", required=True, **POSITIVE),
        "density_kg_m3": Field("number", "kg/m^3", required=True, **POSITIVE),
        "tip_mass_kg": Field("number", "kg", default=0.0, minimum=0.0),
        "n_elements": Field("int", default=40, minimum=2, maximum=400),
        "n_modes": Field("int", default=3, minimum=1, maximum=20),
        "damping_ratio": Field("number", default=0.05, minimum=0.0, maximum=0.99),
        # per kept constrained mode, in order (missing entries: 1 and damping_ratio): its
        # frequency times the factor (its modal stiffness times factor^2), its damping ratio
        "frequency_factors": Field("list[number]", "x the beam model's frequency",
                                   default=[], minimum=0.1, maximum=10.0, check=_at_most_modes),
        "damping_ratios": Field("list[number]", default=[], minimum=0.0, maximum=0.99,
                                check=_at_most_modes),
    },
    "reaction_wheel": {
        "max_torque_n_m": Field("number", "N m", required=True, **POSITIVE),
        "max_speed_rad_s": Field("number", "rad/s", required=True, **POSITIVE),
        "rotor_inertia_kg_m2": Field("number", "kg m^2", required=True, **POSITIVE),
        "torque_lag_s": Field("number", "s", default=0.01, minimum=0.0),
        # bearing friction between rotor and hub (internal: the hub takes its reaction);
        # breakaway: the static friction a wheel at rest must overcome (null: the Coulomb)
        "friction_coulomb_n_m": Field("number", "N m", default=0.0, minimum=0.0, maximum=1.0),
        "friction_viscous_n_m_s": Field("number", "N m s", default=0.0, minimum=0.0,
                                        maximum=1.0),
        "friction_breakaway_n_m": Field("number", "N m", default=None, minimum=0.0,
                                        maximum=1.0),
    },
    "accelerometer": {
        "range_g": Field("number", "g", default=2.0, **POSITIVE),
        "bandwidth_hz": Field("number", "Hz", default=400.0, **POSITIVE),
        "noise_rms_m_s2": Field("number", "m/s^2", default=0.0, minimum=0.0),
        "lsb_m_s2": Field("number", "m/s^2", default=0.001, minimum=0.0),
        # reading = (1 + scale_error) x (true + g0 sin(tilt) cos(hub angle - tilt azimuth))
        # + bias, latency_s old (whole ticks)
        "bias_m_s2": Field("number", "m/s^2", default=0.0, minimum=-100.0, maximum=100.0),
        "scale_error": Field("number", "fraction", default=0.0, **FRACTION),
        "tilt_rad": Field("number", "rad", default=0.0, minimum=-0.5, maximum=0.5),
        "tilt_azimuth_rad": Field("number", "rad", default=0.0, minimum=-TWO_PI,
                                  maximum=TWO_PI),
        "latency_s": Field("number", "s", default=0.0, minimum=0.0, maximum=0.5),
    },
    "hub_sensor": {
        "angle_noise_rms_rad": Field("number", "rad", default=0.0, minimum=0.0),
        "rate_noise_rms_rad_s": Field("number", "rad/s", default=0.0, minimum=0.0),
        "angle_lsb_rad": Field("number", "rad", default=1e-7, minimum=0.0),
        "rate_lsb_rad_s": Field("number", "rad/s", default=1e-7, minimum=0.0),
        # reading = (1 + scale_error) x true + bias (+ the rate bias's random walk),
        # latency_s old (whole ticks)
        "angle_bias_rad": Field("number", "rad", default=0.0, minimum=-math.pi,
                                maximum=math.pi),
        "rate_bias_rad_s": Field("number", "rad/s", default=0.0, minimum=-1.0, maximum=1.0),
        "angle_scale_error": Field("number", "fraction", default=0.0, **FRACTION),
        "rate_scale_error": Field("number", "fraction", default=0.0, **FRACTION),
        "rate_random_walk_rad_s_sqrt_s": Field("number", "rad/s per sqrt(s)", default=0.0,
                                               minimum=0.0, maximum=0.1),
        "latency_s": Field("number", "s", default=0.0, minimum=0.0, maximum=0.5),
    },
    "thruster_valves": {
        "couple_n_m": Field("number", "N m", default=0.1, **POSITIVE),
        "open_delay_s": Field("number", "s", default=0.004, minimum=0.0),
        "close_delay_s": Field("number", "s", default=0.004, minimum=0.0),
        "min_on_time_s": Field("number", "s", default=0.010, minimum=0.0),
        # the negative valve's own couple magnitude and delays (null: the positive's)
        "couple_negative_n_m": Field("number", "N m", default=None, **POSITIVE),
        "open_delay_negative_s": Field("number", "s", default=None, minimum=0.0),
        "close_delay_negative_s": Field("number", "s", default=None, minimum=0.0),
    },
    "piezo_amplifier": {
        "max_voltage_v": Field("number", "V", default=200.0, **POSITIVE, maximum=327.0),
        "max_current_a": Field("number", "A", default=0.1, **POSITIVE),
        "sensor_noise_rms_v": Field("number", "V", default=0.001, minimum=0.0),
        # the sensor patches' reading step (the sgsrt DBC's 1 mV); the stuck rule of the
        # monitor takes it with the noise (harness.core.plausibility)
        "sensor_lsb_v": Field("number", "V", default=0.001, minimum=0.0),
    },
    # one entry per amplifier channel (1, 2): a PZT actuator pair with a sensor patch
    "piezo_patches": Field("any", default=[]),
    "disturbance_rotor": {
        "mass_kg": Field("number", "kg", default=0.0, minimum=0.0),
        "eccentricity_m": Field("number", "m", default=0.0, minimum=0.0),
        "dish_radius_m": Field("number", "m", default=0.6, minimum=0.0),
        "max_speed_rad_s": Field("number", "rad/s", default=30.0, **POSITIVE, maximum=32.0),
        "speed_lag_s": Field("number", "s", default=0.2, minimum=0.0),
    },
    "noise_seed": Field("int", default=1, minimum=0),
    "bus": {
        "bitrate_bit_s": Field("int", "bit/s", default=1_000_000, minimum=10_000,
                               maximum=1_000_000),
        # each device answers every n-th SYNC (CANopen transmission type n)
        "sync_divider": {
            name: Field("int", default=default, minimum=1, maximum=240)
            for name, default in (
                ("hub_sensor", 1), ("accelerometer", 1), ("reaction_wheel", 1),
                ("thruster_valves", 5), ("piezo_amplifier", 1), ("disturbance_rotor", 5),
            )
        },
        # the harness's SYNC and heartbeat frames: sgsrt's (default), or a DBC's
        # {dbc, message, signal} / {dbc, message, counter, armed}, or canopen
        "sync": Field("any", default=None),
        "heartbeat": Field("any", default=None),
        # CANopen: the harness's own node id (its heartbeat's COB-ID 0x700 + id)
        "master_node_id": Field("int", default=127, minimum=1, maximum=127),
        # CANopen: how long each node waits for the harness's heartbeat before its error
        # behaviour makes it safe (its 0x1016 consumer time)
        "heartbeat_consumer_ms": Field("int", "ms", default=200, minimum=1, maximum=65535),
        # the fault-insertion unit: the standard id of the frame on which the virtual rig
        # takes a fault at run time (rig_models.faults.encode_fault_insertion); absent: the
        # rig has no such unit. No frame of the binding may have it (drivers.binding)
        "fault_insertion_id": Field("int", default=None, minimum=1, maximum=0x7FF),
    },
    # how each device speaks on the bus (drivers/binding): sgsrt (default), dbc, canopen or
    # none, checked by drivers.binding.build_binding (errors name the key)
    "devices": Field("any", default=None),
    "watchdog": {
        "heartbeat_timeout_s": Field("number", "s", default=0.25, **POSITIVE),
    },
    # how well this rig file knows its rig: bounds of the model's errors, from which
    # `harness commission` derives its limits (docs/commission.md). A ratio's fraction is at
    # most 0.5: a band 1 +- 1 holds a ratio of 0 (a quantity that never moves) and a lab
    # cannot mean that
    "tolerances": {
        "inertia_fraction": Field("number", "fraction", default=0.05, minimum=0.0,
                                  maximum=0.5),
        "torque_fraction": Field("number", "fraction", default=0.05, minimum=0.0, maximum=0.5),
        "speed_fraction": Field("number", "fraction", default=0.05, minimum=0.0, maximum=0.5),
        "couple_fraction": Field("number", "fraction", default=0.10, minimum=0.0, maximum=0.5),
        "modal_fraction": Field("number", "fraction", default=0.25, minimum=0.0, maximum=0.5),
        "noise_factor": Field("number", "x the noise spec", default=2.0, minimum=1.0),
        "accel_bias_m_s2": Field("number", "m/s^2", default=0.05, minimum=0.0),
        "rate_bias_rad_s": Field("number", "rad/s", default=1.0e-4, minimum=0.0),
        "piezo_bias_v": Field("number", "V", default=0.01, minimum=0.0),
        # the wheel's bearing friction the model leaves out (beyond its friction_* keys):
        # a torque below it may not turn a wheel at rest, a coasting wheel may slow by it
        "wheel_friction_n_m": Field("number", "N m", default=1.0e-3, minimum=0.0),
        # each beam mode's frequency: the beam model against the beam (paper 003, Table 1:
        # measured over calculated 2.5 % and 2.2 % off)
        "frequency_fraction": Field("number", "fraction", default=0.05, minimum=0.0,
                                    maximum=0.5),
        # each beam mode's damping ratio: paper 003's 0.05 is a modelling choice, not a
        # measurement; a bolted aluminium beam's structural damping is 1-2 %
        "damping_fraction": Field("number", "fraction", default=0.8, minimum=0.0,
                                  maximum=0.95),
        # a drive's torque lag and a valve's delays: the file's are typical figures for
        # such devices (10 ms, 4 ms), not this rig's measurement
        "timing_s": Field("number", "s", default=0.005, minimum=0.0),
    },
    # limits of a run's criteria that differ on this rig, by criterion name:
    # {final_error: {max_abs_deg: 0.2}}; applied by the harness's verdict layer
    "expect_overrides": Field("any", default=None),
    # how the rig really is (the virtual rig emulates it; the harness keeps the model
    # above): the physics sections' keys as an overlay, plus timing (AS_BUILT_SCHEMA,
    # checked by rig_from_dict; docs/as_built.md)
    "as_built": Field("any", default=None),
}

AS_BUILT_SECTIONS = ("hub", "beam", "reaction_wheel", "hub_sensor", "accelerometer",
                     "thruster_valves")
"""The physics sections an ``as_built:`` overlay may change (not the bus, the devices'
binding, the limits the harness clamps to elsewhere, nor the tolerances)."""


def _overlay(schema: Mapping[str, Any]) -> dict[str, Any]:
    """``schema`` with every leaf optional and absent by default (an overlay names only
    what differs)."""
    return {k: _overlay(v) if not isinstance(v, Field) else replace(v, required=False,
                                                                     default=None)
            for k, v in schema.items()}


AS_BUILT_SCHEMA: dict[str, Any] = {
    **{k: _overlay(RIG_SCHEMA[k]) for k in AS_BUILT_SECTIONS},
    # devices answering a SYNC late: emulated in real time (run_forever), not in lockstep
    "timing": {
        "answer_latency_s": Field("number", "s", default=None, minimum=0.0, maximum=0.1),
        "answer_jitter_s": Field("number", "s", default=None, minimum=0.0, maximum=0.1),
    },
}


@dataclass(frozen=True)
class RigConfig:
    """A validated rig file."""

    source: str
    data: dict[str, Any]
    base_dir: Path | None = None  # the rig file's folder: DBC/EDS paths are relative to it

    @cached_property
    def binding(self) -> RigBinding:
        """How each device speaks on the bus (``drivers.binding``)."""
        try:
            return build_binding(self.data, self.base_dir)
        except BindingError as exc:
            raise ConfigError(f"{self.source}: {exc}") from exc

    def section(self, name: str) -> dict[str, Any]:
        return self.data[name]

    @property
    def name(self) -> str:
        return self.data["name"]

    def as_built_rig(self) -> RigConfig:
        """The rig as it really is: this model with its ``as_built:`` overlay merged and the
        section removed (what the virtual rig emulates); this rig itself when it has none."""
        return self._as_built

    @cached_property
    def _as_built(self) -> RigConfig:
        overlay = self.data.get("as_built")
        physics = {k: v for k, v in (overlay or {}).items() if k != "timing"}
        if not physics:
            if not overlay:
                return self
            data = dict(self.data, as_built=None)
        else:
            data = _merge(copy.deepcopy(dict(self.data, as_built=None)), copy.deepcopy(physics))
            _check_physics(data, f"{self.source}: as_built")
        cfg = RigConfig(source=f"{self.source} (as built)", data=data, base_dir=self.base_dir)
        # the overlay changes no device's binding (nor the bus): the same binding, not
        # built again (an EDS parsed twice)
        cfg.__dict__["binding"] = self.binding
        return cfg

    @property
    def fault_insertion_key(self) -> tuple[int, bool] | None:
        """(id, extended) of the fault-insertion unit's frame; None: the rig has none."""
        return self.binding.fault_insertion

    @property
    def answer_timing(self) -> tuple[float, float]:
        """(latency, jitter) in s of the devices' answers to a SYNC, as built (0, 0 when the
        rig file says nothing): emulated by the virtual rig in real time only."""
        timing = (self.data.get("as_built") or {}).get("timing") or {}
        return (float(timing.get("answer_latency_s") or 0.0),
                float(timing.get("answer_jitter_s") or 0.0))

    @cached_property
    def beam_spec(self) -> BeamSpec:
        b = self.data["beam"]
        return BeamSpec(
            length_m=b["length_m"],
            width_m=b["width_m"],
            thickness_m=b["thickness_m"],
            youngs_modulus_pa=b["youngs_modulus_pa"],
            density_kg_m3=b["density_kg_m3"],
            hub_radius_m=self.data["hub"]["radius_m"],
            tip_mass_kg=b["tip_mass_kg"],
            n_elements=b["n_elements"],
        )

    @cached_property
    def beam_modes(self) -> BeamModes:
        n_modes = self.data["beam"]["n_modes"]
        if n_modes > self.data["beam"]["n_elements"]:
            raise ConfigError(f"{self.source}: beam.n_modes: must not exceed beam.n_elements")
        return beam_modes(self.beam_spec, n_modes)

    @cached_property
    def plant(self) -> HubBeamModel:
        b = self.data["beam"]
        n_modes = len(self.beam_modes.omega_rad_s)
        damping: float | list[float] = b["damping_ratio"]
        ratios = b.get("damping_ratios") or []
        if ratios:  # per mode, the rest at damping_ratio
            damping = [*ratios[:n_modes], *[b["damping_ratio"]] * (n_modes - len(ratios))]
        try:
            return build_hub_beam(
                inertia_kg_m2=self.data["hub"]["inertia_kg_m2"],
                modes=self.beam_modes,
                damping_ratio=damping,
                tip_radius_m=self.data["hub"]["radius_m"] + b["length_m"],
                frequency_factors=b.get("frequency_factors") or None,
            )
        except ValueError as exc:
            raise ConfigError(f"{self.source}: {exc}") from exc

    @cached_property
    def piezo_patches(self) -> list[PiezoPatch]:
        raw = self.data["piezo_patches"] or []
        if not isinstance(raw, list) or len(raw) > 2:
            raise ConfigError(f"{self.source}: piezo_patches: expected a list of at most 2 "
                              "patches (amplifier channels 1 and 2)")
        keys = {"start_m", "length_m", "width_m", "thickness_m", "youngs_modulus_pa",
                "d31_m_v", "permittivity_f_m"}
        out = []
        for i, p in enumerate(raw):
            where = f"{self.source}: piezo_patches[{i}]"
            if not isinstance(p, dict) or not set(p) <= keys or not {
                    "start_m", "length_m", "width_m", "thickness_m"} <= set(p):
                raise ConfigError(f"{where}: expected start_m, length_m, width_m, thickness_m "
                                  f"(m) and optionally {sorted(keys - {'start_m'})}")
            try:
                out.append(PiezoPatch(**{k: float(v) for k, v in p.items()}))
            except (TypeError, ValueError) as exc:
                raise ConfigError(f"{where}: {exc}") from exc
        return out

    @cached_property
    def piezo_gains(self) -> list[PatchGains]:
        try:
            return [patch_gains(self.beam_modes, self.beam_spec, p) for p in self.piezo_patches]
        except ValueError as exc:
            raise ConfigError(f"{self.source}: piezo_patches: {exc}") from exc

    @property
    def accel_range_m_s2(self) -> float:
        return self.data["accelerometer"]["range_g"] * G0_M_S2


def _exists(path: Path) -> bool:
    """``path.exists()``, False for a name the file system refuses (too long, a NUL)."""
    try:
        return path.exists()
    except (OSError, ValueError):
        return False


def rig_path(name_or_path: str | Path) -> Path:
    candidate = Path(name_or_path)
    if candidate.suffix in (".yaml", ".yml") or _exists(candidate):
        return candidate
    return RIGS_DIR / f"{name_or_path}.yaml"


def load_rig(name_or_path: str | Path = "sgsrt") -> RigConfig:
    """Load and validate a rig file (built-in name or path)."""
    path = rig_path(name_or_path)
    if not _exists(path):
        builtin = ", ".join(sorted(p.stem for p in RIGS_DIR.glob("*.yaml")))
        raise ConfigError(f"rig file {name_or_path}: not found (built-in rigs: {builtin})")
    raw = _read_rig_yaml(path, ())
    return rig_from_dict(raw, source=f"rig file {path.name}", base_dir=path.resolve().parent)


def _read_rig_yaml(path: Path, seen: tuple[Path, ...], what: str = "rig file") -> Any:
    """A rig file's data; ``extends: NAME`` takes another rig file's data as the base and
    overrides it key by key (a rig that differs only in its device binding names the
    physics once); ``as_built_from: NAME`` takes another rig file's ``as_built:`` section
    (this file's own ``as_built:`` overrides it key by key: one as-built rig, several
    bindings). ``what`` names the file in errors (a base: the file that extends it)."""
    raw = load_yaml(path, what)
    if not isinstance(raw, dict):
        return raw
    if "as_built_from" in raw:
        source = _read_base(path, raw.pop("as_built_from"), seen, "as_built_from")
        own = raw.get("as_built")
        if own is not None and not isinstance(own, dict):
            raise ConfigError(f"rig file {path.name}: as_built: expected a mapping of keys, "
                              f"got {_kind(own)}")
        base_built = source.get("as_built")
        if not isinstance(base_built, dict):
            raise ConfigError(f"rig file {path.name}: as_built_from: its rig file has no "
                              "as_built: section")
        raw["as_built"] = _merge(base_built, own or {})
    if "extends" not in raw:
        return raw
    return _merge(_read_base(path, raw.pop("extends"), seen, "extends"), raw)


def _read_base(path: Path, base_name: Any, seen: tuple[Path, ...], key: str
               ) -> dict[str, Any]:
    """The data of the rig file ``base_name`` that ``path`` names under ``key`` (extends,
    as_built_from): a built-in name, or a path (relative to ``path``'s folder)."""
    if not isinstance(base_name, str):
        raise ConfigError(f"rig file {path.name}: {key}: expected a rig name or path, got "
                          f"{base_name!r}")
    base = rig_path(base_name)
    if not base.is_absolute() and not _exists(base) and _exists(path.parent / base_name):
        base = path.parent / base_name
    if not _exists(base):
        raise ConfigError(f"rig file {path.name}: {key}: {base_name}: not found")
    if base.resolve() in seen or base.resolve() == path.resolve():
        raise ConfigError(f"rig file {path.name}: {key}: {base_name}: a circle of rig files "
                          "(extends, as_built_from)")
    base_data = _read_rig_yaml(base, seen + (path.resolve(),),
                               f"rig file {path.name}: {key}: rig file")
    if base_data is None:
        base_data = {}
    if not isinstance(base_data, dict):
        raise ConfigError(f"rig file {path.name}: {key}: {base_name}: its top level is "
                          f"{_kind(base_data)}, not a mapping of keys (a rig file)")
    return base_data


def _kind(value: Any) -> str:
    return "a list" if isinstance(value, list) else f"a {type(value).__name__} ({value!r:.40})"


def _merge(base: dict[str, Any], over: dict[str, Any],
           path: tuple[str, ...] = ()) -> dict[str, Any]:
    """``over`` on ``base`` key by key; a device under ``devices:`` that names its
    ``binding`` replaces the base's device whole (another binding is another device: the
    base's node id or EDS would not belong to a DBC device)."""
    out = dict(base)
    for k, v in over.items():
        if path == ("devices",) and isinstance(v, dict) and "binding" in v:
            out[k] = v
        elif isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = _merge(out[k], v, (*path, str(k)))
        else:
            out[k] = v
    return out


def rig_from_dict(raw: Any, source: str = "rig", base_dir: Path | None = None) -> RigConfig:
    """A validated rig; its device binding is built here too, so a bad binding is refused
    before anything opens a bus."""
    data = validate(raw, RIG_SCHEMA, source)
    data["as_built"] = _as_built_overlay(data["as_built"], source)
    _check_physics(data, source)
    cfg = RigConfig(source=source, data=absolutize(data, base_dir), base_dir=base_dir)
    cfg.binding  # noqa: B018 (built to be checked)
    _check_fault_insertion_id(cfg)
    if cfg.data["as_built"] is not None:
        cfg.as_built_rig()  # the model with the overlay: checked as a whole too
    return cfg


def _check_fault_insertion_id(cfg: RigConfig) -> None:
    """What the binding cannot see: the fault-insertion frame's id is not the id of the
    virtual rig's own ``unknown_ids`` fault frames."""
    from rig_models.faults import UNKNOWN_ID

    key = cfg.fault_insertion_key
    if key is not None and key[0] == UNKNOWN_ID:
        raise ConfigError(f"{cfg.source}: bus.fault_insertion_id: 0x{UNKNOWN_ID:03X} is the id "
                          "of the virtual rig's unknown_ids fault frames")


def _pruned(data: dict[str, Any]) -> dict[str, Any]:
    """A validated overlay without its absent keys (None) and empty sections."""
    out: dict[str, Any] = {}
    for k, v in data.items():
        if isinstance(v, dict):
            v = _pruned(v)
            if v:
                out[k] = v
        elif v is not None:
            out[k] = v
    return out


def _as_built_overlay(raw: Any, source: str) -> dict[str, Any] | None:
    """The ``as_built:`` section checked against ``AS_BUILT_SCHEMA`` (errors name
    ``as_built.hub.inertia_kg_m2`` etc.), only the keys it gives; None when it gives none."""
    if raw is None:
        return None
    return _pruned(validate(raw, AS_BUILT_SCHEMA, source, "as_built")) or None


def _check_physics(data: Mapping[str, Any], source: str) -> None:
    """What one key's bounds cannot say: per-mode lists no longer than the kept modes,
    a breakaway friction no lower than the Coulomb friction."""
    beam = data["beam"]
    for key in ("frequency_factors", "damping_ratios"):
        values = beam.get(key) or []
        if len(values) > beam["n_modes"]:
            raise ConfigError(f"{source}: beam.{key}: {len(values)} entries for "
                              f"beam.n_modes = {beam['n_modes']} kept modes")
    rw = data["reaction_wheel"]
    breakaway, coulomb = rw.get("friction_breakaway_n_m"), rw.get("friction_coulomb_n_m") or 0.0
    if breakaway is not None and breakaway < coulomb:
        raise ConfigError(f"{source}: reaction_wheel.friction_breakaway_n_m: expected >= "
                          f"friction_coulomb_n_m = {coulomb:g} N m (static friction is no "
                          f"lower than sliding), got {breakaway!r}")


# ------------------------------------------------------------------------ identity
def _file_ref(value: str) -> dict[str, Any]:
    """A DBC/EDS path as the identity sees it: its file name and its content's SHA-256
    (None when it cannot be read), not the folder it lay in."""
    path = Path(value)
    try:
        digest: str | None = hashlib.sha256(path.read_bytes()).hexdigest()
    except (OSError, ValueError):
        digest = None
    return {"file": path.name, "sha256": digest}


def _without_folders(obj: Any) -> Any:
    if isinstance(obj, Mapping):
        return {str(k): _file_ref(v) if k in ("dbc", "eds") and isinstance(v, str) and v
                else _without_folders(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_without_folders(v) for v in obj]
    return obj


def rig_sha256(data: Mapping[str, Any]) -> str:
    """SHA-256 of a resolved rig (its ``extends:`` bases merged, defaults filled, overrides
    applied) as canonical JSON, with each DBC/EDS file it names as its file name and content
    hash: the same rig hashes the same wherever its files lie, and an edited DBC or EDS is
    another rig."""
    text = json.dumps(_without_folders(data), sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()


def binding_summary(data: Mapping[str, Any]) -> dict[str, dict[str, Any]]:
    """How each device speaks on the bus, from a rig's data: ``{"binding": "sgsrt"}``,
    ``{"binding": "dbc", "dbc": FILE}``, ``{"binding": "canopen", "node_id": N, "eds":
    FILE}`` or ``{"binding": "none"}`` (file names without their folder)."""
    devices = data.get("devices") if isinstance(data.get("devices"), Mapping) else {}
    out: dict[str, dict[str, Any]] = {}
    for device in DEVICES:
        cfg = devices.get(device)
        if cfg is None or isinstance(cfg, str):
            out[device] = {"binding": cfg or "sgsrt"}
            continue
        if not isinstance(cfg, Mapping):
            out[device] = {"binding": str(cfg)}
            continue
        kind = str(cfg.get("binding", "sgsrt"))
        entry: dict[str, Any] = {"binding": kind}
        if kind == "dbc":
            entry["dbc"] = Path(str(cfg.get("dbc", ""))).name
        elif kind == "canopen":
            entry["node_id"] = cfg.get("node_id")
            entry["eds"] = Path(str(cfg.get("eds", ""))).name
        out[device] = entry
    return out


def rig_identity(data: Mapping[str, Any], bus: str | None = None) -> dict[str, Any]:
    """Which rig said it: the rig's name, its hash (``rig_sha256``), the bus the run used
    and each device's binding. One function for every output that names the rig
    (summary.json, verdict.json, a suite's results and reports, JUnit properties, ``harness
    logs``, the probe, the results database)."""
    name = data.get("name")
    return {"rig": name if isinstance(name, str) else None, "rig_sha256": rig_sha256(data),
            "bus": bus,
            "binding": binding_summary(data)}


def _device_text(entry: Mapping[str, Any]) -> str:
    kind = str(entry.get("binding", "?"))
    if kind == "dbc":
        return f"dbc {entry.get('dbc')}"
    if kind == "canopen":
        return f"canopen node {entry.get('node_id')} {entry.get('eds')}"
    return kind


def binding_text(binding: Mapping[str, Any] | None) -> str:
    """A binding summary in one line: devices grouped by how they speak (``sgsrt: every
    device``; ``canopen node 2 sgsrt_wheel_drive.eds: reaction_wheel; ...``)."""
    if not isinstance(binding, Mapping) or not binding:
        return "-"
    groups: dict[str, list[str]] = {}
    for device, entry in binding.items():
        text = _device_text(entry) if isinstance(entry, Mapping) else str(entry)
        groups.setdefault(text, []).append(str(device))
    if len(groups) == 1:
        return f"{next(iter(groups))}: every device"
    return "; ".join(f"{text}: {', '.join(devices)}" for text, devices in groups.items())


def identity_text(ident: Mapping[str, Any] | None) -> str:
    """``rig sgsrt-canopen (sha256 0123456789ab), bus virtual:sgsrt-canopen, binding ...``:
    a rig identity in one line, for headers and logs."""
    if not isinstance(ident, Mapping) or not ident.get("rig"):
        return "rig unknown"
    sha = str(ident.get("rig_sha256") or "")[:12] or "-"
    bus = f", bus {ident['bus']}" if ident.get("bus") else ""
    return (f"rig {ident['rig']} (sha256 {sha}){bus}, binding "
            f"{binding_text(ident.get('binding'))}")
