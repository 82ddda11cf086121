"""Cold-gas thruster valve pair driver (opposed valves making a torque couple)."""

from __future__ import annotations

from drivers.base import DeviceDriver


class ThrusterValvesDriver(DeviceDriver):
    name = "thruster_valves"
    telemetry_frame = "VALVE_TLM"
    command_frame = "VALVE_CMD"

    command_quantities = ("valve_pos", "valve_neg")

    def command_args(self, direction: int) -> tuple[int, int]:
        """direction +1 opens the positive-torque valve, -1 the negative, 0 closes both.
        Both valves are never opened together. In ``command_quantities`` order."""
        d = 0 if direction != direction else (1 if direction > 0 else -1 if direction < 0 else 0)
        return int(d > 0), int(d < 0)

    def command_values(self, direction: int) -> dict[str, float]:
        """The command quantities by name (see ``command_args``)."""
        return dict(zip(self.command_quantities, self.command_args(direction), strict=True))

    def encode(self, direction: int, counter: int) -> bytes:
        """The sgsrt VALVE_CMD payload."""
        return self.protocol[self.command_frame].encode(
            {**self.command_values(direction), "counter": counter & 0xFF})

    @property
    def firings(self) -> int:
        return int(self.values.get("firings", 0))

    @property
    def on_time_s(self) -> float:
        return self.values.get("on_time", 0.0)
