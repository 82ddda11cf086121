"""Reaction wheel driver (torque mode)."""

from __future__ import annotations

from dataclasses import dataclass

from drivers.base import DeviceDriver


@dataclass
class ReactionWheelDriver(DeviceDriver):
    max_torque_n_m: float = 0.065
    name = "reaction_wheel"
    telemetry_frame = "WHEEL_TLM"
    sequence = ("counter", 256)
    command_frame = "WHEEL_CMD"

    def clamp(self, torque_n_m: float) -> float:
        """The torque that will actually be commanded (device limit from the rig file)."""
        limit = self.max_torque_n_m
        if torque_n_m != torque_n_m:  # NaN from a broken controller: command nothing
            return 0.0
        return -limit if torque_n_m < -limit else limit if torque_n_m > limit else torque_n_m

    command_quantities = ("torque_cmd", "enable")

    def command_args(self, torque_n_m: float, enable: bool) -> tuple[float, int]:
        """The command quantities in ``command_quantities`` order (positional encoders)."""
        return (self.clamp(torque_n_m) if enable else 0.0), int(enable)

    def command_values(self, torque_n_m: float, enable: bool) -> dict[str, float]:
        """The command quantities (``drivers.binding.quantities``)."""
        return dict(zip(self.command_quantities, self.command_args(torque_n_m, enable),
                        strict=True))

    def encode(self, torque_n_m: float, enable: bool, counter: int) -> bytes:
        """The sgsrt WHEEL_CMD payload."""
        return self.protocol[self.command_frame].encode(
            {**self.command_values(torque_n_m, enable), "counter": counter & 0xFF})

    @property
    def speed_rad_s(self) -> float:
        return self.values.get("speed", 0.0)

    @property
    def torque_n_m(self) -> float:
        return self.values.get("torque", 0.0)

    @property
    def fault(self) -> bool:
        return bool(self.values.get("fault", 0))
