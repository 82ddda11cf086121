"""How each plotted series is drawn: a short legend name (``measured angle``, ``torque
commanded``, ``WHEEL_CMD torque_cmd``) instead of its entity path, one colour per quantity
(the same in every plot and file: commands and references warm, measurements cool, the
two piezo channels never swapped), and how the viewer thins it when zoomed out. Logged once
as a static ``SeriesLines(names=, colors=, aggregation_policy=, interpolation_mode=)`` on the
entity (Rerun 0.41); the layouts set the same aggregation as each plot's default. The entity
paths themselves are unchanged: the plot titles carry the quantity and its unit.

Aggregation: when a pixel column covers many samples the viewer by default draws their
average, which halves a one-tick peak (a 44 ms loop-work spike read 22 ms) and draws a valve
that is only ever -1, 0 or +1 at -0.5. Continuous signals get ``MinMax`` (the pixel shows
the samples' whole span, so every peak stays); discrete ones (valves, flags, counts) get
``Off`` (every sample drawn) and a step line, since they hold their value between samples.
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
    "/timing/sync_jitter_ms": "SYNC jitter",
    "/timing/answer_latency_ms": "last answer",
    "/timing/command_margin_ms": "command margin",
    "/bus/late_or_missing": "late or missing",
}
UNIT_SUFFIXES = ("_deg_s", "_rad_s", "_m_s2", "_n_m", "_deg", "_rad", "_ms", "_hz", "_v",
                 "_s", "_m")


# Okabe-Ito colours (distinct for colour-blind readers too), by quantity
BLUE, ORANGE, SKY, GREEN = (0, 114, 178), (230, 159, 0), (86, 180, 233), (0, 158, 115)
VERMILLION, PURPLE, YELLOW, GREY = (213, 94, 0), (204, 121, 167), (240, 228, 66), (150, 150, 150)
SERIES_COLOURS: dict[str, tuple[int, int, int]] = {
    "/attitude/angle_deg": BLUE,
    "/attitude/reference_deg": ORANGE,
    "/attitude/error_deg": PURPLE,
    "/attitude/rate_deg_s": SKY,
    "/wheel/torque_cmd_n_m": ORANGE,
    "/wheel/torque_n_m": BLUE,
    "/wheel/speed_rad_s": SKY,
    "/tip/accel_m_s2": GREEN,
    "/thrusters/valve_cmd": ORANGE,
    "/thrusters/valve_state": BLUE,
    "/thrusters/firings": ORANGE,
    "/thrusters/on_time_s": BLUE,
    "/piezo/cmd_ch1_v": ORANGE,
    "/piezo/cmd_ch2_v": PURPLE,
    "/piezo/sensor_ch1_v": BLUE,
    "/piezo/sensor_ch2_v": GREEN,
    "/rotor/angle_rad": BLUE,
    "/rotor/speed_rad_s": SKY,
    "/timing/lateness_ms": YELLOW,
    "/timing/work_ms": VERMILLION,
    "/timing/frames_rx": SKY,
    "/timing/sync_jitter_ms": PURPLE,
    "/timing/answer_latency_ms": BLUE,
    "/timing/command_margin_ms": GREEN,
    "/bus/late_or_missing": VERMILLION,
}
# the decoded bus's signals: the colour of the loop's channel they carry
BUS_TWINS: dict[str, str] = {
    "/bus/hub_sensor/tlm/angle_rad": "/attitude/angle_deg",
    "/bus/hub_sensor/tlm/rate_rad_s": "/attitude/rate_deg_s",
    "/bus/accelerometer/tlm/accel_m_s2": "/tip/accel_m_s2",
    "/bus/reaction_wheel/cmd/torque_cmd_n_m": "/wheel/torque_cmd_n_m",
    "/bus/reaction_wheel/tlm/torque_n_m": "/wheel/torque_n_m",
    "/bus/reaction_wheel/tlm/speed_rad_s": "/wheel/speed_rad_s",
    "/bus/piezo_amplifier/cmd/voltage_ch1_v": "/piezo/cmd_ch1_v",
    "/bus/piezo_amplifier/cmd/voltage_ch2_v": "/piezo/cmd_ch2_v",
    "/bus/piezo_amplifier/tlm/sensor_ch1_v": "/piezo/sensor_ch1_v",
    "/bus/piezo_amplifier/tlm/sensor_ch2_v": "/piezo/sensor_ch2_v",
}
DEVICE_COLOURS: dict[str, tuple[int, int, int]] = {
    "hub_sensor": BLUE, "accelerometer": GREEN, "reaction_wheel": ORANGE,
    "thruster_valves": VERMILLION, "piezo_amplifier": PURPLE, "disturbance_rotor": SKY}

# signals that only take a few values and hold them: valves, flags, counts
DISCRETE = {"/thrusters/valve_cmd", "/thrusters/valve_state", "/thrusters/firings",
            "/timing/frames_rx", "/bus/late_or_missing"}
DISCRETE_PREFIXES = ("/bus/thruster_valves/", "/bus/harness/", "/bus/disturbance_rotor/cmd/")
MIN_MAX = "MinMax"
OFF = "Off"


def is_discrete(entity: str) -> bool:
    return entity in DISCRETE or entity.startswith(DISCRETE_PREFIXES)


def aggregation(entity: str) -> str:
    """The viewer's aggregation of a series when zoomed out (see the module docstring)."""
    return OFF if is_discrete(entity) else MIN_MAX


def series_colour(entity: str) -> tuple[int, int, int] | None:
    """The quantity's colour (None: the viewer's own)."""
    entity = BUS_TWINS.get(entity, entity)
    if entity in SERIES_COLOURS:
        return SERIES_COLOURS[entity]
    parts = entity.strip("/").split("/")
    if len(parts) == 3 and parts[0] == "bus" and parts[2] == "rx_after_sync_ms":
        return DEVICE_COLOURS.get(parts[1])
    return None


def series_style(entity: str, name: str | None = None) -> rr.SeriesLines:
    """The static ``SeriesLines`` of a plotted series: name, colour, aggregation."""
    colour = series_colour(entity)
    discrete = is_discrete(entity)
    return rr.SeriesLines(names=name or series_name(entity),
                          colors=None if colour is None else [colour],
                          aggregation_policy=aggregation(entity),
                          interpolation_mode="StepAfter" if discrete else None)


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
    """A static ``SeriesLines`` on each entity (``series_style``): named ``names[entity]``
    or ``series_name(entity)``."""
    for entity in entities:
        rec.log(entity, series_style(entity, (names or {}).get(entity)), static=True)


def log_multi_series_names(rec: rr.RecordingStream, entity: str, names: Sequence[str]) -> None:
    """Names of an entity that holds several series (one scalar column each)."""
    rec.log(entity, rr.SeriesLines(names=list(names)), static=True)
