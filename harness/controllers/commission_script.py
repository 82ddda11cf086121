"""The commissioning script: a short, bounded, open-loop excitation of every bound device,
segment by segment (``harness commission``, ``harness.commissioning.plan``).

Each segment drives one actuator over ``[start_s, end_s)``: a wheel torque (N m), a valve
direction (+1 / -1), a linear chirp on one piezo channel (amplitude, from ``f0_hz`` to
``f1_hz``, its ends tapered over ``TAPER_S`` so the drive starts and ends at 0 V), or a rotor
speed (rad/s, enabled). Outside every segment nothing is commanded.
"""

from __future__ import annotations

import math
from typing import Any

from harness.controllers.api import controller_factory
from harness.state import RigCommand
from rig_models.schema import Field

TAPER_S = 0.1
KINDS = ("wheel_torque_n_m", "valve", "piezo_ch", "rotor_speed_rad_s")


class CommissionScript:
    def __init__(self, segments: list[dict[str, Any]]) -> None:
        self.segments = sorted(segments, key=lambda s: s["start_s"])
        self.end_s = max((s["end_s"] for s in self.segments), default=0.0)

    def reset(self) -> None:
        pass

    def step(self, state: Any) -> RigCommand:
        t = state.time_s
        cmd = RigCommand()
        for s in self.segments:
            if not s["start_s"] <= t < s["end_s"]:
                continue
            if "wheel_torque_n_m" in s:
                cmd.wheel_torque_n_m = s["wheel_torque_n_m"]
            elif "valve" in s:
                cmd.valve_direction = s["valve"]
            elif "piezo_ch" in s:
                v = chirp(t - s["start_s"], s["end_s"] - s["start_s"], s["amplitude_v"],
                          s["f0_hz"], s["f1_hz"])
                cmd.piezo_v = (v, 0.0) if s["piezo_ch"] == 1 else (0.0, v)
            elif "rotor_speed_rad_s" in s:
                cmd.rotor_speed_rad_s, cmd.rotor_enable = s["rotor_speed_rad_s"], True
        return cmd


def chirp(t: float, duration_s: float, amplitude: float, f0: float, f1: float) -> float:
    """A linear chirp from f0 to f1 over the duration, ends tapered (raised cosine)."""
    if not 0.0 <= t < duration_s:
        return 0.0
    phase = 2 * math.pi * (f0 * t + 0.5 * (f1 - f0) / duration_s * t * t)
    edge = min(t, duration_s - t)
    taper = 1.0 if edge >= TAPER_S else 0.5 - 0.5 * math.cos(math.pi * edge / TAPER_S)
    return amplitude * taper * math.sin(phase)


@controller_factory({"segments": Field("any", required=True)})
def build_commission_script(c: dict[str, Any], rig: Any, dt_s: float) -> CommissionScript:
    segs = c["segments"]
    if not isinstance(segs, list):
        raise ValueError("segments: expected a list")
    out = []
    for i, s in enumerate(segs):
        if not isinstance(s, dict) or not {"start_s", "end_s"} <= set(s) or sum(
                k in s for k in KINDS) != 1:
            raise ValueError(f"segments[{i}]: expected start_s, end_s and one of "
                             f"{', '.join(KINDS)}")
        if not float(s["end_s"]) > float(s["start_s"]) >= 0:
            raise ValueError(f"segments[{i}]: expected 0 <= start_s < end_s")
        if "valve" in s and s["valve"] not in (-1, 1):
            raise ValueError(f"segments[{i}].valve: expected +1 or -1")
        if "piezo_ch" in s and (s["piezo_ch"] not in (1, 2) or not {
                "amplitude_v", "f0_hz", "f1_hz"} <= set(s)):
            raise ValueError(f"segments[{i}]: a piezo chirp takes piezo_ch 1 or 2, "
                             "amplitude_v, f0_hz, f1_hz")
        out.append(dict(s))
    return CommissionScript(out)

