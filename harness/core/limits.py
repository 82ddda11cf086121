"""Nothing moves beyond a limit: a run's planned motion checked before its first frame.

Every command that moves the rig (``harness run``, ``test``, ``calibrate``, ``study`` on the
rig, ``commission``) runs through ``harness.core.session.execute_run``, which calls
``check_run`` before it opens the bus; ``harness calibrate`` and ``harness commission``
call it for every run they plan before the first one starts. A run whose plan passes a
limit is refused (exit 2, nothing sent, no run folder) with a sentence naming the limit.

The plan is the run's own controller (a second one, built as the run builds it) stepped
tick by tick in closed loop against the rig's rigid-body motion: the hub and everything
on it turning as one body of the rig model's inertia under the wheel's torque (its speed
changing by -torque / rotor inertia), the valves' couple and nothing else (no beam, no
noise, no disturbance, no lag). That is the motion the run asks for; the beam's vibration
and the sensors' noise come on top of it and are the monitor's to judge while the run
goes. Checked against:

- the run's ``limits`` (the monitor's): hub angle ``max_angle_deg``, hub rate
  ``max_rate_deg_s``, wheel speed ``max_wheel_speed_rad_s`` (or the rig's, the smaller);
- the rig file's device limits (what the drivers clamp to): wheel torque
  ``reaction_wheel.max_torque_n_m``, wheel speed ``reaction_wheel.max_speed_rad_s``, piezo
  voltage ``piezo_amplifier.max_voltage_v``, rotor speed ``disturbance_rotor.max_speed_rad_s``,
  and the valves through the motion their couple ``thruster_valves.couple_n_m`` makes.

A command beyond a device's limit that the drivers would clamp is still refused: the run
would not do what its file says. A closed-loop controller saturating at its limit (a PD
slew's torque at ``max_torque_n_m``) is within it.

May import: ``harness.state``, ``rig_models``. Never the bus or the recording.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

from harness.state import RigCommand, RigState

REL_TOL = 1e-9  # a planned value at its limit (a saturated command) is within it

PLAN_HORIZON_S = 600.0
"""The plan steps the run's first this many seconds (the whole run when shorter): a run of
days would otherwise be stepped for hours before its first frame. Every built-in run and
the motion a slew or an excitation asks for lie within it; beyond it the monitor alone
holds the run to its ``limits`` (it stops the run at the first tick past one)."""

PLAN_STOP_EVERY = 256
"""Ticks between two looks at the command's stop request (Ctrl-C, SIGTERM) while planning,
and at the wall clock for progress."""

PLAN_PROGRESS_AFTER_S = 1.0
"""A plan that takes longer than this on the wall clock says how far it is, about once a
second."""


class PlanInterrupted(KeyboardInterrupt):
    """Ctrl-C or SIGTERM while the plan was checked: nothing was sent."""


class BeyondLimit(ValueError):
    """A run's plan passes a limit; the message is a sentence naming it."""


@dataclass
class PlannedMotion:
    """The largest value of each quantity over the plan and when it occurs (s), and when it
    first passed its limit (``limits``: quantity -> limit, in SI)."""

    duration_s: float = 0.0
    limits: dict[str, float] = field(default_factory=dict)
    peaks: dict[str, tuple[float, float]] = field(default_factory=dict)
    first_beyond: dict[str, float] = field(default_factory=dict)
    stopped: str = ""  # why the plan ended early (a controller that raised: the run's error)

    def note(self, name: str, value: float, t_s: float) -> None:
        v = abs(value)
        if v != v:  # NaN: a command that says nothing is judged as the worst
            v = math.inf
        old = self.peaks.get(name)
        if old is None or v > old[0]:
            self.peaks[name] = (v, t_s)
            lim = self.limits.get(name)
            if (lim is not None and name not in self.first_beyond
                    and not v <= lim * (1.0 + REL_TOL)):
                self.first_beyond[name] = t_s

    def peak(self, name: str) -> tuple[float, float]:
        return self.peaks.get(name, (0.0, 0.0))


@dataclass(frozen=True)
class Limit:
    quantity: str
    what: str
    value: float  # SI
    unit: str  # the unit it is written in
    per_si: float  # that unit per SI unit
    where: str


def limits_of(rig: Any, limits: dict[str, Any]) -> dict[str, Limit]:
    """Every limit a plan is checked against, by quantity, with where it lives."""
    wheel = rig.section("reaction_wheel")
    speed_lim, speed_key = float(wheel["max_speed_rad_s"]), \
        "the rig file's reaction_wheel.max_speed_rad_s"
    run_speed = float(limits.get("max_wheel_speed_rad_s") or 0.0)
    if 0.0 < run_speed < speed_lim:
        speed_lim, speed_key = run_speed, "the run's limits.max_wheel_speed_rad_s"
    deg = math.degrees(1.0)
    out = [
        Limit("hub_angle", "the hub angle", math.radians(float(limits["max_angle_deg"])),
              "deg", deg, "the run's limits.max_angle_deg"),
        Limit("hub_rate", "the hub rate", math.radians(float(limits["max_rate_deg_s"])),
              "deg/s", deg, "the run's limits.max_rate_deg_s"),
        Limit("wheel_speed", "the wheel speed", speed_lim, "rad/s", 1.0, speed_key),
        Limit("wheel_torque", "the wheel torque command", float(wheel["max_torque_n_m"]),
              "N m", 1.0, "the rig file's reaction_wheel.max_torque_n_m"),
        Limit("piezo_v", "the piezo voltage command",
              float(rig.section("piezo_amplifier")["max_voltage_v"]), "V", 1.0,
              "the rig file's piezo_amplifier.max_voltage_v"),
        Limit("rotor_speed", "the rotor speed command",
              float(rig.section("disturbance_rotor")["max_speed_rad_s"]), "rad/s", 1.0,
              "the rig file's disturbance_rotor.max_speed_rad_s"),
    ]
    return {lim.quantity: lim for lim in out}


def plan_motion(controller: Any, rig: Any, dt_s: float, n_ticks: int,
                actuators: tuple[str, ...], limits: dict[str, float] | None = None,
                should_stop: Any = None, progress: Any = None) -> PlannedMotion:
    """Step ``controller`` (a fresh one: it is left stepped) for ``n_ticks`` ticks of
    ``dt_s`` against the rig's rigid-body motion; the peaks of hub angle, hub rate, wheel
    speed and of every command the run would send to ``actuators``. A controller that
    raises ends the plan there (``stopped``): the run meets the error itself, on its own
    exit path (recorded, the rig left safe, judged ERROR). ``should_stop``: the command's
    stop request; a KeyboardInterrupt while it asks for none is the controller's own, and
    a stop it asks for ends the plan with ``PlanInterrupted`` (nothing sent). ``progress``
    (fraction done, ticks, n_ticks) is called about once a second once the plan has taken
    ``PLAN_PROGRESS_AFTER_S``. The caller bounds ``n_ticks`` (``PLAN_HORIZON_S``)."""
    inertia = float(rig.plant.inertia_kg_m2)
    wheel = rig.section("reaction_wheel")
    rotor_inertia = float(wheel["rotor_inertia_kg_m2"])
    couple = float(rig.section("thruster_valves")["couple_n_m"])
    use = set(actuators)
    angle = rate = wheel_speed = 0.0
    wheel_torque = 0.0
    valve = 0
    motion = PlannedMotion(duration_s=(n_ticks - 1) * dt_s, limits=dict(limits or {}))
    note = motion.note
    state = RigState()
    step = controller.step
    wall0 = time.perf_counter()
    next_report = wall0 + PLAN_PROGRESS_AFTER_S
    for tick in range(n_ticks):
        t = tick * dt_s
        if tick % PLAN_STOP_EVERY == 0 and tick:
            if should_stop is not None and should_stop() is not None:
                raise PlanInterrupted(f"{should_stop()} while the limit plan was checked at "
                                      f"t = {t:.1f} s of {n_ticks * dt_s:.1f} s")
            now = time.perf_counter()
            if progress is not None and now >= next_report:
                progress(tick / n_ticks, tick, n_ticks)
                next_report = now + 1.0
        state.tick, state.time_s = tick, t
        state.hub_angle_rad, state.hub_rate_rad_s = angle, rate
        state.wheel_speed_rad_s, state.wheel_torque_n_m = wheel_speed, wheel_torque
        state.wheel_enabled = True
        state.valve_state = valve
        try:
            cmd = step(state)
        except KeyboardInterrupt as exc:
            if should_stop is None or should_stop() is not None:
                raise  # Ctrl-C before the run began: nothing sent
            motion.stopped = f"the controller raised at t = {t:.3f} s ({exc!r})"
            break
        except BaseException as exc:  # noqa: BLE001 - the run meets it itself, judged ERROR
            # SystemExit too: a plugin's exit in its plan must not end the command as done
            motion.stopped = f"the controller raised at t = {t:.3f} s ({exc!r})"
            break
        if not isinstance(cmd, RigCommand):  # the run meets it too (ControllerError)
            motion.stopped = f"the controller returned {type(cmd).__name__} at t = {t:.3f} s"
            break
        try:
            wheel_torque = cmd.wheel_torque_n_m if "reaction_wheel" in use else 0.0
            valve = (cmd.valve_direction > 0) - (cmd.valve_direction < 0) \
                if "thruster_valves" in use else 0
            if "reaction_wheel" in use:
                note("wheel_torque", wheel_torque, t)
            if "piezo_amplifier" in use:
                note("piezo_v", max(abs(cmd.piezo_v[0]), abs(cmd.piezo_v[1])), t)
            if "disturbance_rotor" in use and cmd.rotor_enable:
                note("rotor_speed", cmd.rotor_speed_rad_s, t)
            if wheel_torque != wheel_torque:
                wheel_torque = 0.0
            # semi-implicit Euler over the tick, the command held (zero-order hold)
            rate += (wheel_torque + valve * couple) / inertia * dt_s
        except (TypeError, ValueError) as exc:  # a value of the wrong type: the run meets it
            motion.stopped = f"the controller's command at t = {t:.3f} s: {exc}"
            break
        angle += rate * dt_s
        wheel_speed -= wheel_torque / rotor_inertia * dt_s
        note("hub_angle", angle, t + dt_s)
        note("hub_rate", rate, t + dt_s)
        note("wheel_speed", wheel_speed, t + dt_s)
    return motion


def limit_rows(motion: PlannedMotion, rig: Any, limits: dict[str, Any]) -> list[dict[str, Any]]:
    """Every checked quantity the plan has: its planned peak, the limit, where the limit
    lives, in the limit's unit; ``at_s`` when it first passed the limit, else its peak's."""
    rows = []
    for q, lim in limits_of(rig, limits).items():
        if q not in motion.peaks:
            continue
        v, at = motion.peak(q)
        rows.append({"quantity": q, "what": lim.what, "planned": v * lim.per_si,
                     "limit": lim.value * lim.per_si, "unit": lim.unit, "where": lim.where,
                     "at_s": motion.first_beyond.get(q, at)})
    return rows


def beyond(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The rows past their limit, the first passed first."""
    return sorted((r for r in rows if not r["planned"] <= r["limit"] * (1.0 + REL_TOL)),
                  key=lambda r: r["at_s"])


def refusal(source: str, row: dict[str, Any], others: int = 0) -> str:
    """The sentence that refuses a plan, naming the limit."""
    more = f" ({others} more limit{'s' if others > 1 else ''} passed too)" if others else ""
    return (f"{source}: refused before anything was sent: the plan takes {row['what']} to "
            f"{row['planned']:.4g} {row['unit']}, beyond {row['where']} of {row['limit']:g} "
            f"{row['unit']} from t = {row['at_s']:.2f} s{more}; lower the run's angle, "
            "torque or amplitude, or raise the limit if the rig allows it")


def check_run(run: Any, controller: Any | None = None,
              should_stop: Any = None, progress: Any = None) -> list[dict[str, Any]]:
    """Refuse ``run`` (a RunConfig) whose plan passes a limit (BeyondLimit, a sentence);
    the checked rows otherwise. ``controller``: a fresh controller of the run to step (one
    is built as the run builds it when not given; never pass the one the run will use)."""
    if controller is None:
        from harness.core.runs import build_controller

        controller = build_controller(run)
    lims = {q: lim.value for q, lim in limits_of(run.rig, run.data["limits"]).items()}
    n_ticks = min(run.n_ticks, int(round(PLAN_HORIZON_S / run.dt_s)) + 1)
    motion = plan_motion(controller, run.rig, run.dt_s, n_ticks, run.actuators, lims,
                         should_stop, progress)
    rows = limit_rows(motion, run.rig, run.data["limits"])
    bad = beyond(rows)
    if bad:
        raise BeyondLimit(refusal(run.source, bad[0], len(bad) - 1))
    return rows
