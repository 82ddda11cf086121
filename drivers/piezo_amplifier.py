"""Piezo amplifier driver: actuator voltage per channel out, patch sensor voltages in."""

from __future__ import annotations

from dataclasses import dataclass

from drivers.base import DeviceDriver


@dataclass
class PiezoAmplifierDriver(DeviceDriver):
    max_voltage_v: float = 200.0
    name = "piezo_amplifier"
    telemetry_frame = "PIEZO_TLM"
    command_frame = "PIEZO_CMD"

    def clamp(self, volts: float) -> float:
        if volts != volts:
            return 0.0
        lim = self.max_voltage_v
        return -lim if volts < -lim else lim if volts > lim else volts

    command_quantities = ("voltage_ch1", "voltage_ch2")

    def command_args(self, ch1_v: float, ch2_v: float) -> tuple[float, float]:
        """The command quantities in ``command_quantities`` order (positional encoders)."""
        return self.clamp(ch1_v), self.clamp(ch2_v)

    def command_values(self, ch1_v: float, ch2_v: float) -> dict[str, float]:
        return dict(zip(self.command_quantities, self.command_args(ch1_v, ch2_v), strict=True))

    def encode(self, ch1_v: float, ch2_v: float, counter: int) -> bytes:
        """The sgsrt PIEZO_CMD payload."""
        return self.protocol[self.command_frame].encode(
            {**self.command_values(ch1_v, ch2_v), "counter": counter & 0xFF})
