"""What the harness exchanges with each device, whatever the protocol: the quantities.

A binding (sgsrt, any DBC, CANopen) maps these to frames and signals or to objects; the
drivers and RigState/RigCommand only ever see these names, in SI units (flags as 0/1,
counts as integers). The names are the sgsrt DBC's signal names, so the default binding is
the identity.
"""

from __future__ import annotations

DEVICES = ("hub_sensor", "accelerometer", "reaction_wheel", "thruster_valves",
           "piezo_amplifier", "disturbance_rotor")

# device -> telemetry quantity -> unit ("" for flags and counts)
TELEMETRY: dict[str, dict[str, str]] = {
    "hub_sensor": {"angle": "rad", "rate": "rad/s"},
    "accelerometer": {"accel": "m/s^2", "sample_counter": "", "saturated": "", "fault": ""},
    "reaction_wheel": {"speed": "rad/s", "torque": "N.m", "enabled": "", "fault": "",
                       "speed_limited": "", "torque_limited": "", "counter": "",
                       "status": ""},
    "thruster_valves": {"valve_pos_open": "", "valve_neg_open": "", "fault": "",
                        "firings": "", "on_time": "s", "counter": ""},
    "piezo_amplifier": {"sensor_ch1": "V", "sensor_ch2": "V", "overcurrent": "", "fault": "",
                        "counter": ""},
    "disturbance_rotor": {"angle": "rad", "speed": "rad/s", "enabled": "", "fault": "",
                          "counter": "", "status": ""},
}

# ``status`` is a drive's own state word as it sends it (a CiA 402 statusword, 0x6041):
# the fault monitor names the drive's state from it when the drive leaves operation enabled

# device -> command quantity -> unit
COMMANDS: dict[str, dict[str, str]] = {
    "reaction_wheel": {"torque_cmd": "N.m", "enable": ""},
    "thruster_valves": {"valve_pos": "", "valve_neg": ""},
    "piezo_amplifier": {"voltage_ch1": "V", "voltage_ch2": "V"},
    "disturbance_rotor": {"speed_cmd": "rad/s", "enable": ""},
}

# what a run needs bound, by device: without these the controllers and the monitor would
# read zeros as if they were measurements
REQUIRED_TELEMETRY: dict[str, tuple[str, ...]] = {
    "hub_sensor": ("angle", "rate"),
    "accelerometer": ("accel",),
    "reaction_wheel": ("speed", "torque"),
    "thruster_valves": ("valve_pos_open", "valve_neg_open"),
    "piezo_amplifier": ("sensor_ch1", "sensor_ch2"),
    "disturbance_rotor": ("speed",),  # its angle is recorded, not used to control
}
REQUIRED_COMMANDS: dict[str, tuple[str, ...]] = {
    "reaction_wheel": ("torque_cmd",),
    "thruster_valves": ("valve_pos", "valve_neg"),
    "piezo_amplifier": ("voltage_ch1", "voltage_ch2"),
    "disturbance_rotor": ("speed_cmd",),
}
