"""The commissioning runs, from the rig file: what each moves, when, and how much.

1. ``rest``: sensors only (a dry run: no command frame, CiA 402 drives left disabled) for
   ``REST_S`` after the monitor's start-up; on a CANopen rig its set-up reads every node's
   identity, device type and scaling objects.
2. ``moving``: one open-loop script (``harness.controllers.commission_script``), each
   bound actuator in turn, with a quiet gap after each excitation:

   - wheel: a torque pulse of ``WHEEL_TORQUE_FRACTION`` of ``max_torque_n_m`` for
     ``WHEEL_PULSE_S``, then the same of the other sign (the wheel and hub back near rest);
     the wheel coasts ``WHEEL_GAP_S`` after each (its bearing friction, from the speed it
     loses);
   - valves: the positive valve for ``VALVE_PULSE_S``, then the negative one;
   - ring: ``RING_CYCLES`` cycles of a square wave at the model's first hub-free mode, of
     ``RING_TORQUE_FRACTION`` of ``max_torque_n_m`` on the wheel (the valves when no wheel
     is bound), then ``RING_S`` of ring-down: the beam's modes, frequency and damping, from
     the tip accelerometer;
   - piezo: a chirp of ``PIEZO_FRACTION`` of ``max_voltage_v`` on channel 1, then channel 2,
     from ``CHIRP_F0_FRACTION`` to ``CHIRP_F1_FRACTION`` of the model's first hub-free mode;
   - rotor: ``ROTOR_FRACTION`` of its ``max_speed_rad_s`` for ``ROTOR_S``.

Every amplitude is a fraction of the device's own limit, and the whole plan is checked
against the run's and the rig's limits before the first frame (``harness.core.limits``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

START_S = 1.0  # the monitor's start-up (0.5 s) and a quiet stretch before the first pulse
REST_S = 1.0
WHEEL_TORQUE_FRACTION = 0.25
WHEEL_PULSE_S = 0.5
WHEEL_GAP_S = 4.0  # the coast-down: 0.6 mN m of friction slows the pulse's 5 rad/s by 1.5
VALVE_PULSE_S = 0.2
VALVE_GAP_S = 1.3
RING_TORQUE_FRACTION = 0.5
RING_CYCLES = 2
RING_S = 15.0  # several periods of the first mode (about 2.2 s on the SGSRT): its damping
PIEZO_FRACTION = 0.25
CHIRP_S = 2.0
CHIRP_F0_FRACTION, CHIRP_F1_FRACTION = 0.5, 8.0
PIEZO_GAP_S = 0.5
ROTOR_FRACTION = 0.1
ROTOR_S = 2.5
END_GAP_S = 0.5
RATE_HZ = 500.0


@dataclass
class Phase:
    """One excitation of the script: what it drives and when (s)."""

    name: str  # wheel+, wheel-, valve+, valve-, ring, piezo1, piezo2, rotor
    start_s: float
    end_s: float  # the excitation's end
    quiet_end_s: float  # the end of the quiet gap after it
    segment: dict[str, Any]
    more: list[dict[str, Any]] = field(default_factory=list)  # its further segments

    @property
    def segments(self) -> list[dict[str, Any]]:
        return [self.segment, *self.more]


@dataclass
class CommissionPlan:
    rig: Any
    rig_ref: str
    bound: tuple[str, ...]
    phases: list[Phase] = field(default_factory=list)
    duration_s: float = 0.0

    def phase(self, name: str) -> Phase | None:
        return next((p for p in self.phases if p.name == name), None)

    @property
    def actuators(self) -> list[str]:
        return [a for a in ("reaction_wheel", "thruster_valves", "piezo_amplifier",
                            "disturbance_rotor") if a in self.bound]

    def rest_run(self, bus: str, clock: str) -> dict[str, Any]:
        return {"name": "commission-rest", "description": "commissioning: sensors at rest",
                "rig": self.rig_ref, "bus": bus, "clock": clock, "rate_hz": RATE_HZ,
                "duration_s": 0.5 + REST_S, "actuators": self.actuators,
                # nothing is armed or moved: the monitor's faults would stop the run at a
                # reading the rest checks are there to judge (an offset beyond the range)
                "monitor": {"enabled": False},
                "controller": {"type": "hold"}}

    def moving_run(self, bus: str, clock: str) -> dict[str, Any]:
        return {"name": "commission-moving",
                "description": "commissioning: every bound actuator excited in turn",
                "rig": self.rig_ref, "bus": bus, "clock": clock, "rate_hz": RATE_HZ,
                "duration_s": round(self.duration_s, 3), "actuators": self.actuators,
                # the monitor's physics windows are what the checks here do per pulse and
                # per quantity, with the likely cause: a miss is judged there, not stopped
                # at the first window (its other faults still stop the run)
                "monitor": {"plausibility": False},
                "controller": {"type": "commission_script",
                               "segments": [s for p in self.phases for s in p.segments]}}


def plan_commissioning(rig: Any, rig_ref: str) -> CommissionPlan:
    bound = rig.binding.bound
    plan = CommissionPlan(rig, rig_ref, bound)
    t = START_S

    def add(name: str, length: float, gap: float, segment: dict[str, Any]) -> None:
        nonlocal t
        seg = {"start_s": round(t, 6), "end_s": round(t + length, 6), **segment}
        plan.phases.append(Phase(name, t, t + length, t + length + gap, seg))
        t += length + gap

    if "reaction_wheel" in bound:
        torque = WHEEL_TORQUE_FRACTION * rig.section("reaction_wheel")["max_torque_n_m"]
        add("wheel+", WHEEL_PULSE_S, WHEEL_GAP_S, {"wheel_torque_n_m": torque})
        add("wheel-", WHEEL_PULSE_S, WHEEL_GAP_S, {"wheel_torque_n_m": -torque})
    if "thruster_valves" in bound:
        on = max(VALVE_PULSE_S, rig.section("thruster_valves")["min_on_time_s"])
        add("valve+", on, VALVE_GAP_S, {"valve": 1})
        add("valve-", on, VALVE_GAP_S, {"valve": -1})
    ring = ring_segments(rig, bound)
    if ring:
        start = t
        segs = [{"start_s": round(start + a, 6), "end_s": round(start + b, 6), **s}
                for a, b, s in ring]
        length = ring[-1][1]
        plan.phases.append(Phase("ring", start, start + length, start + length + RING_S,
                                 segs[0], segs[1:]))
        t += length + RING_S
    if "piezo_amplifier" in bound and rig.piezo_patches:
        f1 = float(rig.plant.hub_free_modes()[0][0]) / (2 * math.pi)
        amp = PIEZO_FRACTION * rig.section("piezo_amplifier")["max_voltage_v"]
        for ch in range(1, len(rig.piezo_patches) + 1):
            add(f"piezo{ch}", CHIRP_S, PIEZO_GAP_S if ch == len(rig.piezo_patches) else 0.0,
                {"piezo_ch": ch, "amplitude_v": amp, "f0_hz": round(CHIRP_F0_FRACTION * f1, 4),
                 "f1_hz": round(CHIRP_F1_FRACTION * f1, 4)})
    if "disturbance_rotor" in bound:
        speed = ROTOR_FRACTION * rig.section("disturbance_rotor")["max_speed_rad_s"]
        add("rotor", ROTOR_S, 0.0, {"rotor_speed_rad_s": speed})
    plan.duration_s = t + END_GAP_S
    return plan


def ring_segments(rig: Any, bound: tuple[str, ...]
                  ) -> list[tuple[float, float, dict[str, Any]]]:
    """The ring's excitation, (from, to, segment) relative to its start: ``RING_CYCLES``
    cycles of a square wave at the model's first hub-free mode, positive half first (its
    torques cancel over each cycle: the wheel and the hub end near where they began), on
    the wheel (``RING_TORQUE_FRACTION`` of its ``max_torque_n_m``), else the valves."""
    if "reaction_wheel" in bound:
        torque = RING_TORQUE_FRACTION * rig.section("reaction_wheel")["max_torque_n_m"]
        halves = ({"wheel_torque_n_m": torque}, {"wheel_torque_n_m": -torque})
    elif "thruster_valves" in bound:
        halves = ({"valve": 1}, {"valve": -1})
    else:
        return []
    half = math.pi / float(rig.plant.hub_free_modes()[0][0])
    return [(k * half, (k + 1) * half, halves[k % 2]) for k in range(2 * RING_CYCLES)]
