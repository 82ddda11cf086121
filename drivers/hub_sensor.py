"""Hub angle/rate sensor driver."""

from __future__ import annotations

from drivers.base import DeviceDriver


class HubSensorDriver(DeviceDriver):
    name = "hub_sensor"
    telemetry_frame = "HUB_TLM"

    @property
    def angle_rad(self) -> float:
        return self.values.get("angle", 0.0)

    @property
    def rate_rad_s(self) -> float:
        return self.values.get("rate", 0.0)
