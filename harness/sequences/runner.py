"""A sequence run in the tick: the run's controller wrapped by its steps.

``SequenceRunner`` is what the loop calls as the controller: each tick it steps the run's
own controller with the tick's state, then evaluates the current step (its verifies, its
``when:`` conditions, how it ends) on the same state, and returns the command: the
controller's, a step's open-loop command, or the safe command once the monitor has found a
fault. A step that ends starts the next in the same tick, so an action follows its
condition in the tick the condition first holds (its command goes out in that tick; an
injected fault acts from the rig's next tick). Nothing here waits, reads the bus or
allocates beyond a step's start and end.

The loop tells it of a monitor fault (``on_fault``): from then on the harness holds the rig
safe, actions that would move it are suppressed, the current step goes on deciding for at
most ``after_fault_s``, the steps not reached are SKIPPED and ``finally:`` runs. ``finished``
tells the loop the sequence is over (the run ends).

Imports: ``harness.state``, ``harness.sequences``, ``rig_models``.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

from harness.sequences.conditions import FALSE, PENDING, TRUE, Condition, compile_condition
from harness.sequences.spec import Actions, SequenceSpec, Step
from harness.state import RigCommand, RigState
from rig_models.faults import FaultSpec

PASS, FAIL, TIMEOUT, SKIPPED, ERROR = "PASS", "FAIL", "TIMEOUT", "SKIPPED", "ERROR"
_NO_REFERENCE = (math.nan, math.nan, math.nan)

MAX_ACTIONS_KEPT = 20
"""A step's actions listed in its result (a ``when: ... every: true`` may fire all run
long): the first this many, then a count, so a result's size does not grow with the run."""

MAX_INJECTIONS = 100
"""Faults a run's sequence may inject: every fault stays in the rig's list (its telemetry
checks each, every tick), so a ``when:`` that injects every time it holds is cut off here,
each later injection suppressed and counted."""


@dataclass
class StepResult:
    """One step's outcome: what decided it, when, and the condition's value then."""

    name: str
    index: int
    final: bool
    outcome: str = SKIPPED
    started_s: float | None = None
    ended_s: float | None = None
    reason: str = ""
    condition: str = ""  # the condition that decided it
    value: str = ""  # its value at the decision
    measures: dict[str, float] = field(default_factory=dict)
    actions: list[str] = field(default_factory=list)
    actions_not_listed: int = 0  # past MAX_ACTIONS_KEPT
    verified: list[str] = field(default_factory=list)  # a passed step's verifies, as held

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "index": self.index, "finally": self.final,
                "outcome": self.outcome, "started_s": self.started_s,
                "ended_s": self.ended_s, "reason": self.reason,
                "condition": self.condition, "value": self.value,
                "measures": self.measures,
                "actions": self.actions + ([f"... and {self.actions_not_listed} more"]
                                           if self.actions_not_listed else []),
                "verified": self.verified}


class _LiveStep:
    """A step's compiled conditions and its running measures."""

    def __init__(self, step: Step, quantities: dict[str, Any]) -> None:
        self.step = step
        c = compile_condition
        self.wait = c(step.wait_until, quantities, step.where) if step.wait_until else None
        self.until = c(step.until, quantities, step.where) if step.until else None
        self.verify = [c(v, quantities, step.where) for v in step.verify]
        self.when = [(w, c(w.condition, quantities, w.where)) for w in step.when]
        self.fired = [False] * len(self.when)
        # what the tick calls, bound once
        self.verify_updates = tuple((v.update, v) for v in self.verify)
        self.when_updates = tuple((j, w, cond.update) for j, (w, cond) in enumerate(self.when))
        self.wait_update = self.wait.update if self.wait is not None else None
        self.slew = False
        self.target_rad = math.nan  # the step's slew target (its settle band is about it)
        self.out_of_band_s = 0.0  # the last time the error was outside the settle band

    def reset(self, t_s: float) -> None:
        for cond in self.conditions():
            cond.reset(t_s)
        self.fired = [False] * len(self.when)

    def conditions(self) -> list[Condition]:
        out = [x for x in (self.wait, self.until) if x is not None]
        return out + self.verify + [c for _, c in self.when]


class SequenceRunner:
    """The controller the loop calls for a run with a ``sequence:`` (see the module)."""

    def __init__(self, spec: SequenceSpec, controller: Any, quantities: dict[str, Any],
                 settle_band_rad: float, dt_s: float,
                 step_controllers: dict[int, Any] | None = None) -> None:
        self.spec = spec
        self.controller = controller
        # a step's own controller (by the step's index), run while the step runs, on the
        # step's time (its t = 0 the step's start)
        self.step_controllers = dict(step_controllers or {})
        self.quantities = quantities
        self.settle_band_rad = settle_band_rad
        self.dt_s = dt_s
        self._inner_step = controller.step
        self._reference = getattr(controller, "reference", None)
        self._retarget = getattr(controller, "retarget", None)
        self.live = [_LiveStep(s, quantities) for s in spec.all_steps]
        self.results = [StepResult(s.name, s.index, s.final) for s in spec.all_steps]
        # set by the session before the loop: how a fault reaches the rig, where events go
        self.insert_fault: Callable[[FaultSpec], None] | None = None
        self.clear_faults: Callable[[], None] | None = None
        self.log_event: Callable[[float, str, str, str], None] | None = None
        self._start()

    def _start(self) -> None:
        # the context the conditions read
        self.state = RigState()
        self.sent = RigCommand()
        self.t_s = 0.0
        self.step_t0_s = 0.0
        self.step_index = 0
        self.safe = False
        self.detected = False
        self.events: dict[str, float] = {}
        self.current = 0
        self.started = False
        self._live_now: _LiveStep | None = None  # the step under way
        self._active: Any = None  # the step's own controller, while it runs
        self._active_t0 = 0.0
        self.override: RigCommand | None = None
        self.aborted = False
        self.finished = False
        self.safe_until_s = math.inf
        self.injected: list[dict[str, Any]] = []  # the first MAX_ACTIONS_KEPT
        self.injections = 0
        self.injections_suppressed = 0
        self.ended_by = ""

    def __deepcopy__(self, memo: dict[int, Any]) -> SequenceRunner:
        """A fresh runner (the limit plan's): conditions compiled again, never shared."""
        return SequenceRunner(self.spec, copy.deepcopy(self.controller, memo),
                              self.quantities, self.settle_band_rad, self.dt_s,
                              copy.deepcopy(self.step_controllers, memo))

    # what the session reads off the controller (reference, design_report, ...) is the
    # run's own controller's
    def __getattr__(self, name: str) -> Any:
        if name.startswith("__") or name == "controller":
            raise AttributeError(name)
        return getattr(self.controller, name)

    @property
    def reference_rad(self) -> float:
        """The controller's reference angle now (NaN without one): read only when a
        condition asks for it."""
        return self.reference(self.t_s)[0]

    def reference(self, t_s: float) -> tuple[float, float, float]:
        """The reference of the controller in charge at ``t_s`` (a step's own, on the
        step's time, else the run's); NaN without one. The loop records it."""
        active = self._active
        if active is not None:
            ref = getattr(active, "reference", None)
            return ref(t_s - self._active_t0) if ref is not None else _NO_REFERENCE
        return self._reference(t_s) if self._reference is not None else _NO_REFERENCE

    def event_time(self, name: str) -> float | None:
        return self.events.get(name)

    def reset(self) -> None:
        reset = getattr(self.controller, "reset", None)
        if callable(reset):
            reset()

    # ------------------------------------------------------------------ the tick
    def step(self, state: RigState) -> RigCommand:
        active = self._active
        if active is None:
            cmd = self._inner_step(state)
        else:  # the step's own controller, on the step's time
            shifted = state.copy()
            shifted.time_s = state.time_s - self._active_t0
            cmd = active.step(shifted)
        self.state = state
        t = self.t_s = state.time_s
        if not self.finished:
            live = self._live_now  # most ticks: the step under way goes on
            if live is None or self.safe or self._decide(live, t):
                self._advance(t)
        if self.safe:
            cmd = RigCommand()
        elif self.override is not None:
            cmd = self.override
        self.sent = cmd
        return cmd

    def _advance(self, t: float) -> None:
        steps = self.spec.all_steps
        for _ in range(len(steps) + 1):  # each step that ends starts the next this tick
            if self.current >= len(steps):
                self._finish(t, self.ended_by or "completed")
                return
            if self.safe and t >= self.safe_until_s:
                self._stop_after_fault(t)
                continue
            live = self.live[self.current]
            if not self.started:
                self._begin(live, t)
            if not self._decide(live, t):
                return
            self._live_now = None

    def _begin(self, live: _LiveStep, t: float) -> None:
        step = live.step
        res = self.results[self.current]
        self.started = True
        self._live_now = live
        self.step_t0_s = t
        self.step_index = self.current
        res.started_s = t
        live.reset(t)
        own = self.step_controllers.get(step.index)
        if own is not None:
            reset = getattr(own, "reset", None)
            if callable(reset):
                reset()
            self._active, self._active_t0 = own, t
        self._log(t, f"step {step.name}: started", "INFO")
        live.slew = step.actions.slew_rad is not None or step.actions.hold
        live.target_rad = (self.state.hub_angle_rad if step.actions.hold
                           else step.actions.slew_rad if live.slew else math.nan)
        live.out_of_band_s = t
        self._do(step.actions, t, res)

    def _decide(self, live: _LiveStep, t: float) -> bool:
        """Evaluate the current step; True when it ended (the next may start this tick)."""
        step = live.step
        if live.slew and not abs(live.target_rad - self.state.hub_angle_rad) \
                <= self.settle_band_rad:
            live.out_of_band_s = t
        for update, cond in live.verify_updates:
            if update(self) == FALSE:
                return self._end(live, t, FAIL, "verify failed", cond)
        for j, w, update in live.when_updates:
            if update(self) == TRUE and (w.every or not live.fired[j]):
                live.fired[j] = True
                self._log(t, f"step {step.name}: when {w.condition}: {w.actions.describe()}",
                          "INFO")
                self._do(w.actions, t, self.results[self.current])
        elapsed = t - self.step_t0_s
        if live.wait_update is not None:
            if live.wait_update(self) == TRUE:
                return self._end(live, t, PASS, "wait_until held", live.wait)
            if elapsed >= step.timeout_s - 1e-9:  # type: ignore[operator]
                outcome = ERROR if step.on_timeout == "error" else TIMEOUT
                return self._end(live, t, outcome,
                                 f"wait_until did not hold within {step.timeout_s:g} s",
                                 live.wait)
            return False
        if live.until is not None and live.until.update(self) == TRUE:
            return self._end(live, t, PASS, "until held", live.until)
        if step.for_s is not None:
            if elapsed >= step.for_s - 1e-9:
                return self._end(live, t, PASS, f"ran its {step.for_s:g} s", None)
            return False
        if live.until is not None:
            return False
        return self._end(live, t, PASS, "its actions done", None)

    def _end(self, live: _LiveStep, t: float, outcome: str, reason: str,
             cond: Condition | None) -> bool:
        step, res = live.step, self.results[self.current]
        pending = [c for c in live.verify if c.update(self) == PENDING] \
            if outcome == PASS else []
        res.outcome, res.ended_s, res.reason = outcome, t, reason
        if cond is not None:
            res.condition = cond.text
            res.value = cond.describe(self)
        if pending:
            res.reason += "; undecided at the end: " + "; ".join(c.text for c in pending)
        if outcome == PASS:  # what each verify held to, at the step's end
            res.verified = [f"{c.text}: {c.describe(self)}" for c in live.verify]
        if live.slew:
            err = live.target_rad - self.state.hub_angle_rad
            res.measures["final_error_deg"] = math.degrees(err)
            if abs(err) <= self.settle_band_rad:
                res.measures["settle_time_s"] = live.out_of_band_s - res.started_s \
                    if res.started_s is not None else math.nan
        level = "INFO" if outcome == PASS else "ERROR"
        self._log(t, f"step {step.name}: {outcome}: {reason}"
                     + (f" ({res.condition}: {res.value})" if res.condition else ""), level)
        self.started = False
        self._live_now = None
        self._active = None  # the run's controller again
        self.current += 1
        if outcome != PASS and not step.final and step.on_fail == "abort" \
                or outcome == ERROR:
            self._skip_to_finally(t, f"step {step.name} {outcome}")
        return True

    def _skip_to_finally(self, t: float, why: str) -> None:
        main = len(self.spec.steps)
        for i in range(self.current, main):
            self.results[i].reason = f"not reached: {why}"
        if self.current < main:
            self.current = main
        self.ended_by = self.ended_by or why

    def _stop_after_fault(self, t: float) -> None:
        """``after_fault_s`` after the monitor's fault: the step under way fails undecided;
        from the main steps, ``finally:`` gets as long again; from ``finally:``, the
        sequence ends."""
        steps, main = self.spec.all_steps, len(self.spec.steps)
        in_final = self.current >= main
        if self.started:
            res = self.results[self.current]
            res.outcome, res.ended_s = FAIL, t
            res.reason = f"not decided {self.spec.after_fault_s:g} s after the monitor's fault"
            self.started = False
            self._live_now = None
            self._active = None
            self._log(t, f"step {res.name}: FAIL: {res.reason}", "ERROR")
            self.current += 1
        if not in_final:
            self._skip_to_finally(t, "the monitor's fault")
            self.safe_until_s = t + self.spec.after_fault_s
        else:
            for i in range(self.current, len(steps)):
                self.results[i].reason = "not reached: the monitor's fault"
            self.current = len(steps)

    def _finish(self, t: float, how: str) -> None:
        self.finished = True
        self.ended_by = how
        self._log(t, f"sequence ended: {how}", "INFO")

    @staticmethod
    def _note(res: StepResult, text: str) -> None:
        if len(res.actions) < MAX_ACTIONS_KEPT:
            res.actions.append(text)
        else:
            res.actions_not_listed += 1

    def _do(self, a: Actions, t: float, res: StepResult) -> None:
        if a.mark:
            self.events[a.mark] = t
        if self.safe and a.moves:
            self._note(res, f"{a.describe()} at {t:.3f} s: suppressed, the rig is held safe "
                            "after a fault")
            return
        if a.inject is not None and self.injections >= MAX_INJECTIONS:
            self._note(res, f"{a.describe()} at {t:.3f} s: suppressed, {MAX_INJECTIONS} "
                            "faults injected already")
            self.injections_suppressed += 1
            a = replace(a, inject=None)
        if a.describe():
            self._note(res, f"{a.describe()} at {t:.3f} s")
        if a.slew_rad is not None or a.hold:
            target = self.state.hub_angle_rad if a.hold else a.slew_rad
            if self._retarget is None:  # refused before the run (build_sequence)
                raise RuntimeError("the run's controller cannot retarget")
            self._retarget(target, t)
        if a.command is not None:
            self.override = a.command
        if a.release:
            self.override = None
        if a.clear_faults and self.clear_faults is not None:
            self.clear_faults()
        if a.inject is not None:
            fault = replace(a.inject, at_s=t)
            if self.insert_fault is not None:
                self.insert_fault(fault)
            self.events["fault"] = t
            self.injections += 1
            if len(self.injected) < MAX_ACTIONS_KEPT:
                self.injected.append({**vars(fault), "step": res.name})

    def _log(self, t: float, text: str, level: str) -> None:
        if self.log_event is not None:
            self.log_event(t, "/events/sequence", text, level)

    # ------------------------------------------------------------------ from the loop
    def on_fault(self, t_s: float, event: Any) -> bool:
        """The monitor found a fault at ``t_s``: hold the rig safe and go on deciding
        (True: the loop keeps ticking with safe commands until ``finished``)."""
        if self.finished:
            return False
        self.detected = True
        self.safe = True
        self.events.setdefault("detected", t_s)
        self.safe_until_s = t_s + self.spec.after_fault_s
        self.ended_by = self.ended_by or f"the monitor's fault at t = {t_s:.3f} s"
        self._log(t_s, f"fault {event}: the rig is held safe; the sequence decides for at "
                       f"most {self.spec.after_fault_s:g} s more", "WARN")
        return True

    def summary(self) -> dict[str, Any]:
        """summary.json's ``sequence``."""
        return {"steps": [r.to_dict() for r in self.results],
                "ended_by": self.ended_by or ("completed" if self.finished
                                              else "the run's duration_s"),
                "finished": self.finished, "injected": self.injected,
                "injections": self.injections,
                "injections_suppressed": self.injections_suppressed,
                "events": dict(self.events)}

    def close(self, t_s: float) -> None:
        """The run ended (its duration, an interruption): the step under way is a
        TIMEOUT, the rest not reached."""
        if self.finished:
            return
        steps = self.spec.all_steps
        for i in range(self.current, len(steps)):
            res = self.results[i]
            if i == self.current and self.started:
                res.outcome, res.ended_s = TIMEOUT, t_s
                res.reason = "the run ended before the step did (the run's duration_s)"
            else:
                res.reason = res.reason or "not reached: the run ended"
        self.ended_by = self.ended_by or "the run's duration_s"
