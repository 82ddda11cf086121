"""What flows through one tick: the rig's state (from telemetry) and the actuator command."""

from __future__ import annotations

from dataclasses import dataclass, field

_new = object.__new__


@dataclass
class RigState:
    """Decoded telemetry at one tick (SI units). ``stale`` names devices with old data."""

    tick: int = 0
    time_s: float = 0.0
    hub_angle_rad: float = 0.0
    hub_rate_rad_s: float = 0.0
    tip_accel_m_s2: float = 0.0
    accel_saturated: bool = False
    wheel_speed_rad_s: float = 0.0
    wheel_torque_n_m: float = 0.0
    wheel_enabled: bool = False
    wheel_fault: bool = False
    valve_state: int = 0
    valve_firings: int = 0
    valve_on_time_s: float = 0.0
    piezo_sensor_v: tuple[float, float] = (0.0, 0.0)
    rotor_angle_rad: float = 0.0
    rotor_speed_rad_s: float = 0.0
    rotor_sample_tick: int = 0  # tick of the last rotor telemetry (it answers every n-th SYNC)
    stale: tuple[str, ...] = field(default_factory=tuple)

    def copy(self) -> RigState:
        """A copy of this tick's state (every field is immutable: a shallow copy is whole).
        The loop gives the controller one each tick, so that what the controller does to
        its input can never reach the monitor or the recording, which read the original;
        a dict copy, about 0.3 us a tick (``copy.copy`` takes 2.5 us)."""
        out = _new(RigState)
        out.__dict__ = self.__dict__.copy()
        return out


@dataclass
class RigCommand:
    """Actuator commands for one tick (SI units). The drivers clamp to device limits."""

    wheel_torque_n_m: float = 0.0
    valve_direction: int = 0  # +1 positive couple, -1 negative, 0 closed
    piezo_v: tuple[float, float] = (0.0, 0.0)
    rotor_speed_rad_s: float = 0.0
    rotor_enable: bool = False


SAFE_COMMAND = RigCommand()
