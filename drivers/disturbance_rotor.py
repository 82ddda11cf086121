"""Disturbance rotor (eccentric mass) driver."""

from __future__ import annotations

from dataclasses import dataclass

from drivers.base import DeviceDriver


@dataclass
class DisturbanceRotorDriver(DeviceDriver):
    max_speed_rad_s: float = 30.0
    name = "disturbance_rotor"
    telemetry_frame = "ROTOR_TLM"
    command_frame = "ROTOR_CMD"

    command_quantities = ("speed_cmd", "enable")

    def command_args(self, speed_rad_s: float, enable: bool) -> tuple[float, int]:
        """The command quantities in ``command_quantities`` order (positional encoders)."""
        lim = self.max_speed_rad_s
        s = 0.0 if speed_rad_s != speed_rad_s else max(-lim, min(lim, speed_rad_s))
        return (s if enable else 0.0), int(enable)

    def command_values(self, speed_rad_s: float, enable: bool) -> dict[str, float]:
        return dict(zip(self.command_quantities, self.command_args(speed_rad_s, enable),
                        strict=True))

    def encode(self, speed_rad_s: float, enable: bool, counter: int) -> bytes:
        """The sgsrt ROTOR_CMD payload."""
        return self.protocol[self.command_frame].encode(
            {**self.command_values(speed_rad_s, enable), "counter": counter & 0xFF})

    @property
    def angle_rad(self) -> float:
        return self.values.get("angle", 0.0)

    @property
    def speed_rad_s(self) -> float:
        return self.values.get("speed", 0.0)
