"""What a sequence's conditions can read: the tick's state, the command sent, the controller's
reference, the step's and the run's time, and the harness's own flags.

Each name is a base (``hub.angle``) with an SI dimension; a condition writes it with a unit
(``hub.angle_deg``, ``hub.angle_rad``) and the condition language converts. A quantity reads
the sequence's context (``SequenceContext`` in ``harness.sequences.runner``): its ``state``
(``harness.state.RigState``), ``sent`` (the last ``RigCommand``), ``reference_rad``, ``t_s``,
``step_t0_s``, ``safe`` and ``detected``. Devices the rig file does not have are left out, so
a condition naming one is refused before the run.
"""

from __future__ import annotations

import math
from typing import Any

from harness.sequences.conditions import Quantity

# base name -> (dimension, read, what it is, the rig device it needs or "")
_TABLE: list[tuple[str, str, Any, str, str]] = [
    ("hub.angle", "angle", lambda c: c.state.hub_angle_rad,
     "the hub's angle (hub sensor)", "hub_sensor"),
    ("hub.rate", "angular_rate", lambda c: c.state.hub_rate_rad_s,
     "the hub's rate (hub sensor)", "hub_sensor"),
    ("attitude.reference", "angle", lambda c: c.reference_rad,
     "the controller's reference angle (NaN without one)", ""),
    ("attitude.error", "angle", lambda c: c.reference_rad - c.state.hub_angle_rad,
     "reference minus hub angle, as recorded in /attitude/error_deg", "hub_sensor"),
    ("tip.accel", "acceleration", lambda c: c.state.tip_accel_m_s2,
     "the tip accelerometer", "accelerometer"),
    ("tip.saturated", "flag", lambda c: float(c.state.accel_saturated),
     "the accelerometer reports saturation", "accelerometer"),
    ("wheel.speed", "angular_rate", lambda c: c.state.wheel_speed_rad_s,
     "the reaction wheel's speed (its telemetry)", "reaction_wheel"),
    ("wheel.torque", "torque", lambda c: c.state.wheel_torque_n_m,
     "the reaction wheel's torque (its telemetry)", "reaction_wheel"),
    ("wheel.torque_cmd", "torque", lambda c: c.sent.wheel_torque_n_m,
     "the wheel torque the harness sent last tick", "reaction_wheel"),
    ("wheel.enabled", "flag", lambda c: float(c.state.wheel_enabled),
     "the wheel reports itself enabled", "reaction_wheel"),
    ("wheel.fault", "flag", lambda c: float(c.state.wheel_fault),
     "the wheel reports a fault", "reaction_wheel"),
    ("valves.state", "count", lambda c: float(c.state.valve_state),
     "the valves' reported state: +1 positive couple, -1 negative, 0 closed",
     "thruster_valves"),
    ("valves.cmd", "count", lambda c: float(c.sent.valve_direction),
     "the valve direction the harness sent last tick", "thruster_valves"),
    ("valves.firings", "count", lambda c: float(c.state.valve_firings),
     "the valves' firing count", "thruster_valves"),
    ("valves.on_time", "time", lambda c: c.state.valve_on_time_s,
     "the valves' accumulated open time", "thruster_valves"),
    ("piezo.sensor1", "voltage", lambda c: c.state.piezo_sensor_v[0],
     "piezo sensor patch 1", "piezo_amplifier"),
    ("piezo.sensor2", "voltage", lambda c: c.state.piezo_sensor_v[1],
     "piezo sensor patch 2", "piezo_amplifier"),
    ("piezo.cmd1", "voltage", lambda c: c.sent.piezo_v[0],
     "the piezo channel 1 voltage the harness sent last tick", "piezo_amplifier"),
    ("piezo.cmd2", "voltage", lambda c: c.sent.piezo_v[1],
     "the piezo channel 2 voltage the harness sent last tick", "piezo_amplifier"),
    ("rotor.angle", "angle", lambda c: c.state.rotor_angle_rad,
     "the disturbance rotor's angle", "disturbance_rotor"),
    ("rotor.speed", "angular_rate", lambda c: c.state.rotor_speed_rad_s,
     "the disturbance rotor's speed", "disturbance_rotor"),
    ("stale.count", "count", lambda c: float(len(c.state.stale)),
     "devices whose telemetry is old this tick", ""),
    ("step.time", "time", lambda c: c.t_s - c.step_t0_s,
     "time since the step started", ""),
    ("step.index", "count", lambda c: float(c.step_index),
     "the step's index in the sequence (0 first)", ""),
    ("run.time", "time", lambda c: c.t_s, "time since the run started", ""),
    ("rig.safe", "flag", lambda c: float(c.safe),
     "the harness holds the rig safe: every command safe (wheel 0 N m, valves closed, "
     "piezo 0 V, rotor off) and the heartbeat disarmed, after the monitor found a fault", ""),
    ("fault.detected", "flag", lambda c: float(c.detected),
     "the fault monitor has stopped the run's motion for a fault", ""),
]


# what the harness sent: always this tick's, whatever the device's telemetry
_SENT = frozenset({"wheel.torque_cmd", "valves.cmd", "piezo.cmd1", "piezo.cmd2"})
NAN = math.nan


def _fresh(read: Any, device: str) -> Any:
    """``read``, NaN while ``device``'s telemetry is old (``RigState.stale``: a silent or
    late device): a condition never holds on a value the device no longer confirms (NaN
    holds no comparison but ``!=``), so a wait goes on waiting and a verify fails."""
    def fresh(c: Any) -> float:
        return NAN if device in c.state.stale else read(c)
    return fresh


def quantities_for(devices: set[str] | frozenset[str] | None = None) -> dict[str, Quantity]:
    """The names a sequence may read on a rig with ``devices`` (None: every device); a
    device's telemetry reads NaN while it is stale."""
    return {name: Quantity(dim, read if not device or name in _SENT else _fresh(read, device),
                           doc)
            for name, dim, read, doc, device in _TABLE
            if not device or devices is None or device in devices}


def quantity_rows() -> list[tuple[str, str, str, str]]:
    """(base name, dimension, what it is, device) for the reference in docs/sequences.md."""
    return [(name, dim, doc, device) for name, dim, _, doc, device in _TABLE]
