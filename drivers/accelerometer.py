"""Tip accelerometer driver."""

from __future__ import annotations

from drivers.base import DeviceDriver


class AccelerometerDriver(DeviceDriver):
    name = "accelerometer"
    telemetry_frame = "ACCEL_TLM"
    sequence = ("sample_counter", 65536)

    @property
    def accel_m_s2(self) -> float:
        return self.values.get("accel", 0.0)

    @property
    def saturated(self) -> bool:
        return bool(self.values.get("saturated", 0))
