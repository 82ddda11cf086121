"""Square-wave valve bursts for a free decay (the thruster valves' counterpart of
``wheel_bursts``): the valve pair fires +couple / -couple at a chosen frequency for a whole
number of cycles (zero net impulse), each burst optionally followed by ``free_decay_s`` of
closed valves and repeated. The valves are on/off, so the level is the rig's couple; a
burst whose half period is shorter than the valves' minimum on-time cannot be made and is
refused, naming ``thruster_valves.min_on_time_s``. ``harness identify`` reads the same
free-decay windows as after ``wheel_bursts``.
"""

from __future__ import annotations

import math
from typing import Any

from harness.controllers.api import controller_factory
from harness.controllers.registry import WheelBursts, _bursts
from harness.state import RigCommand, RigState
from rig_models.rig_file import RigConfig
from rig_models.schema import Field


class ValveBursts(WheelBursts):
    """``WheelBursts`` commanding the valve direction (+1 / -1) instead of a wheel torque."""

    def __init__(self, start_s: float, bursts: list[tuple[float, int, float]]) -> None:
        super().__init__(1.0, start_s, bursts)

    def step(self, state: RigState) -> RigCommand:
        return RigCommand(valve_direction=int(round(self.torque(state.time_s))))


@controller_factory({
    "type": Field("str", required=True),
    "start_s": Field("number", "s", default=0.5, minimum=0.0),
    "bursts": Field("any", required=True),
})
def build_valve_bursts(c: dict[str, Any], rig: RigConfig, dt_s: float) -> ValveBursts:
    bursts = _bursts(c)
    min_on = rig.section("thruster_valves")["min_on_time_s"]
    for omega, _, _ in bursts:
        half = math.pi / omega
        if half < max(min_on, dt_s):
            raise ValueError(
                f"bursts: omega_rad_s {omega:g}: half period {half * 1e3:.2f} ms is shorter than "
                f"the valves' minimum on-time thruster_valves.min_on_time_s "
                f"{min_on * 1e3:g} ms (or one tick, {dt_s * 1e3:g} ms)")
    return ValveBursts(c["start_s"], bursts)

