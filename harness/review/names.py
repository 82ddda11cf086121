"""Short names for the plots' legends: each plotted series gets a readable name (``measured
angle``, ``torque commanded``, ``WHEEL_CMD torque_cmd``) instead of its entity path, logged
once as a static ``SeriesLines(names=...)`` on the entity (Rerun 0.41). The entity paths
themselves are unchanged: the plot titles carry the quantity and its unit, the legend says
which series is which.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence

import rerun as rr

# the loop's channels (harness.core.loop.CHANNELS) and the bus pass's count
SERIES_NAMES: dict[str, str] = {
    "/attitude/angle_deg": "measured angle",
    "/attitude/reference_deg": "reference angle",
    "/attitude/error_deg": "error",
    "/attitude/rate_deg_s": "hub rate",
    "/wheel/torque_cmd_n_m": "torque commanded",
    "/wheel/torque_n_m": "torque measured",
    "/wheel/speed_rad_s": "wheel speed",
    "/tip/accel_m_s2": "tip acceleration",
    "/thrusters/valve_cmd": "valve command",
    "/thrusters/valve_state": "valve state",
    "/thrusters/firings": "firings",
    "/thrusters/on_time_s": "on-time",
    "/piezo/cmd_ch1_v": "ch1 command",
    "/piezo/cmd_ch2_v": "ch2 command",
    "/piezo/sensor_ch1_v": "ch1 sensor",
    "/piezo/sensor_ch2_v": "ch2 sensor",
    "/rotor/angle_rad": "rotor angle",
    "/rotor/speed_rad_s": "rotor speed",
    "/timing/lateness_ms": "lateness",
    "/timing/work_ms": "work",
    "/timing/frames_rx": "frames read",
    "/bus/late_or_missing": "late or missing",
}
UNIT_SUFFIXES = ("_deg_s", "_rad_s", "_m_s2", "_n_m", "_deg", "_rad", "_ms", "_hz", "_v",
                 "_s", "_m")


def strip_unit(name: str) -> str:
    """``torque_cmd_n_m`` -> ``torque_cmd`` (the unit is in the plot's title)."""
    for suffix in UNIT_SUFFIXES:
        if name.endswith(suffix) and len(name) > len(suffix):
            return name[: -len(suffix)]
    return name


def series_name(entity: str) -> str:
    """The legend's name of an entity: ``SERIES_NAMES``, else its last part without the
    unit and with spaces (``/bus/hub_sensor/rx_after_sync_ms`` -> ``hub sensor``)."""
    if entity in SERIES_NAMES:
        return SERIES_NAMES[entity]
    parts = entity.strip("/").split("/")
    if len(parts) >= 3 and parts[0] == "bus" and parts[-1] == "rx_after_sync_ms":
        return parts[1].replace("_", " ")
    return strip_unit(parts[-1]).replace("_", " ")


def log_series_names(rec: rr.RecordingStream, entities: Iterable[str],
                     names: Mapping[str, str] | None = None) -> None:
    """A static ``SeriesLines(names=...)`` on each entity: ``names[entity]`` or
    ``series_name(entity)``."""
    for entity in entities:
        name = (names or {}).get(entity) or series_name(entity)
        rec.log(entity, rr.SeriesLines(names=name), static=True)


def log_multi_series_names(rec: rr.RecordingStream, entity: str, names: Sequence[str]) -> None:
    """Names of an entity that holds several series (one scalar column each)."""
    rec.log(entity, rr.SeriesLines(names=list(names)), static=True)
