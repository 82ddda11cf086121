"""A run file's ``sequence:``: named steps, parsed and checked before anything is sent.

Every problem is a ``ConfigError`` naming the step and the key (``sequence.steps[1] (slew
back).wait_until``): an unknown channel, a unit that does not match, a condition that can
never be decided (a ``for`` longer than its step's timeout, ``after`` an event no step
makes), a ``wait_until`` without a timeout, a fault the rig cannot take at run time, a
``${variable}`` the run does not define. Conditions are compiled here once
(``harness.sequences.conditions``); the runner compiles them again for each run so that
no two runs share a condition's state.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from harness.sequences.conditions import ConditionError, Quantity, compile_condition
from harness.state import RigCommand
from rig_models.faults import FaultSpec, make_fault
from rig_models.schema import ConfigError, short_repr

STEP_KEYS = ("name", "controller", "slew", "hold", "command", "inject", "clear_faults", "mark",
             "wait_until", "timeout_s", "on_timeout", "verify", "when", "for_s", "until",
             "on_fail")
ACTION_KEYS = ("slew", "hold", "command", "inject", "clear_faults", "mark")
COMMAND_KEYS = ("wheel_torque_n_m", "valve_direction", "piezo_ch1_v", "piezo_ch2_v")
EVENTS_BUILTIN = ("fault", "detected")
"""``fault``: the latest fault the sequence injected; ``detected``: the fault monitor's
first fault. A ``mark: NAME`` action makes the event ``NAME``."""

DEFAULT_AFTER_FAULT_S = 2.0
"""After the monitor finds a fault the rig is held safe and the sequence goes on deciding
(``rig.safe within 0.5 s after fault``) for at most this long; then the run ends."""

_VAR = re.compile(r"\$\{([A-Za-z_][A-Za-z0-9_]*)\}")


@dataclass(frozen=True)
class Actions:
    """What a step does when it starts (or a ``when:`` when its condition holds)."""

    slew_rad: float | None = None  # retarget the controller's slew
    hold: bool = False  # retarget to the hub's angle now
    command: RigCommand | None = None  # open loop: this command instead of the controller's
    release: bool = False  # ``command: controller``: the controller's commands again
    inject: FaultSpec | None = None  # at_s is set when it is injected
    clear_faults: bool = False
    mark: str = ""

    @property
    def moves(self) -> bool:
        """Does it change what the actuators do (suppressed while the rig is held safe)?"""
        return (self.slew_rad is not None or self.hold or self.command is not None
                or self.release or self.inject is not None)

    def describe(self) -> str:
        parts = []
        if self.slew_rad is not None:
            parts.append(f"slew to {math.degrees(self.slew_rad):g} deg")
        if self.hold:
            parts.append("hold")
        if self.command is not None:
            parts.append("open-loop command")
        if self.release:
            parts.append("controller resumes")
        if self.inject is not None:
            parts.append(f"inject {self.inject.kind}"
                         + (f" on {self.inject.device}" if self.inject.device else ""))
        if self.clear_faults:
            parts.append("clear faults")
        if self.mark:
            parts.append(f"mark {self.mark}")
        return ", ".join(parts)


@dataclass(frozen=True)
class When:
    condition: str
    actions: Actions
    every: bool = False  # every time it becomes true (default: at most once)
    where: str = ""


@dataclass(frozen=True)
class Step:
    name: str
    index: int
    where: str
    actions: Actions = Actions()
    wait_until: str | None = None
    timeout_s: float | None = None
    on_timeout: str = "fail"  # "fail" | "error"
    verify: tuple[str, ...] = ()
    when: tuple[When, ...] = ()
    for_s: float | None = None
    until: str | None = None
    on_fail: str = "abort"  # "abort" | "continue"
    final: bool = False  # a step of ``finally:``
    # the step's own controller section (``{type: ..., ...}``), run while the step runs on
    # the step's time (checked and built by the caller: the registry is not this package's)
    controller: dict[str, Any] | None = None


@dataclass(frozen=True)
class SequenceSpec:
    steps: tuple[Step, ...]
    final: tuple[Step, ...] = ()
    after_fault_s: float = DEFAULT_AFTER_FAULT_S
    source: str = "run"
    marks: frozenset[str] = field(default_factory=frozenset)

    @property
    def all_steps(self) -> tuple[Step, ...]:
        return self.steps + self.final

    @property
    def injects(self) -> bool:
        return any(a.inject is not None for s in self.all_steps
                   for a in (s.actions, *(w.actions for w in s.when)))


def _err(where: str, message: str) -> ConfigError:
    return ConfigError(f"{where}: {message}")


def substitute(value: Any, variables: Mapping[str, Any], where: str) -> Any:
    """``${name}`` replaced by the run's ``variables`` throughout ``value``: a string that
    is only ``${name}`` becomes the variable's value (a number stays a number)."""
    if isinstance(value, dict):
        return {k: substitute(v, variables, f"{where}.{k}") for k, v in value.items()}
    if isinstance(value, list):
        return [substitute(v, variables, f"{where}[{i}]") for i, v in enumerate(value)]
    if not isinstance(value, str) or "${" not in value:
        return value

    def lookup(name: str) -> Any:
        if name not in variables:
            known = ", ".join(sorted(variables)) or "none"
            raise _err(where, f"${{{name}}}: no such variable in the run's variables "
                              f"(defined: {known})")
        return variables[name]

    whole = _VAR.fullmatch(value.strip())
    if whole:
        return lookup(whole.group(1))
    return _VAR.sub(lambda m: _text(lookup(m.group(1))), value)


def _text(v: Any) -> str:
    return repr(v) if isinstance(v, float) else str(v)


def _number(raw: Any, where: str, minimum: float | None = None,
            exclusive: bool = False) -> float:
    if isinstance(raw, bool) or not isinstance(raw, int | float) or not math.isfinite(raw):
        raise _err(where, f"expected a number, got {short_repr(raw)}")
    if minimum is not None and (raw <= minimum if exclusive else raw < minimum):
        raise _err(where, f"expected a number {'>' if exclusive else '>='} {minimum:g}, "
                          f"got {raw!r}")
    return float(raw)


def _condition_text(raw: Any, where: str) -> str:
    if isinstance(raw, bool):  # YAML's `true`: a condition that always holds
        return "true" if raw else "false"
    if not isinstance(raw, str) or not raw.strip():
        raise _err(where, f"expected a condition (e.g. 'abs(hub.angle_deg - 10) < 0.05 for "
                          f"2 s'), got {short_repr(raw)}")
    return raw.strip()


def _command(raw: Any, where: str, actuators: tuple[str, ...]) -> tuple[RigCommand | None, bool]:
    if raw == "safe":
        return RigCommand(), False
    if raw == "controller":
        return None, True
    if not isinstance(raw, dict):
        raise _err(where, "expected safe, controller, or a mapping of "
                          f"{', '.join(COMMAND_KEYS)}; got {short_repr(raw)}")
    unknown = sorted(set(raw) - set(COMMAND_KEYS))
    if unknown:
        raise _err(f"{where}.{unknown[0]}", f"unknown key (expected {', '.join(COMMAND_KEYS)})")
    need = {"wheel_torque_n_m": "reaction_wheel", "valve_direction": "thruster_valves",
            "piezo_ch1_v": "piezo_amplifier", "piezo_ch2_v": "piezo_amplifier"}
    for key in raw:
        if need[key] not in actuators:
            raise _err(f"{where}.{key}", f"the run does not command {need[key]} (its "
                                         f"actuators: {', '.join(actuators)})")
    valve = raw.get("valve_direction", 0)
    if valve not in (-1, 0, 1) or isinstance(valve, bool):
        raise _err(f"{where}.valve_direction", f"expected -1, 0 or 1, got {valve!r}")
    return RigCommand(
        wheel_torque_n_m=_number(raw.get("wheel_torque_n_m", 0.0), f"{where}.wheel_torque_n_m"),
        valve_direction=int(valve),
        piezo_v=(_number(raw.get("piezo_ch1_v", 0.0), f"{where}.piezo_ch1_v"),
                 _number(raw.get("piezo_ch2_v", 0.0), f"{where}.piezo_ch2_v"))), False


def _actions(raw: Mapping[str, Any], where: str, actuators: tuple[str, ...]) -> Actions:
    slew_rad = None
    if "slew" in raw:
        s = raw["slew"]
        if not isinstance(s, dict) or set(s) != {"angle_deg"}:
            raise _err(f"{where}.slew", f"expected {{angle_deg: NUMBER}}, got {short_repr(s)}")
        slew_rad = math.radians(_number(s["angle_deg"], f"{where}.slew.angle_deg"))
    hold = raw.get("hold", False)
    if not isinstance(hold, bool):
        raise _err(f"{where}.hold", f"expected true or false, got {short_repr(hold)}")
    if hold and slew_rad is not None:
        raise _err(f"{where}.hold", "a step slews or holds, not both")
    command, release = (None, False)
    if "command" in raw:
        command, release = _command(raw["command"], f"{where}.command", actuators)
    inject = None
    if "inject" in raw:
        f = raw["inject"]
        if isinstance(f, dict) and "at_s" in f:
            raise _err(f"{where}.inject.at_s", "a sequence injects when the step starts or "
                                               "its when: holds; no at_s")
        inject = make_fault({**f, "at_s": 0.0} if isinstance(f, dict) else f,
                            f"{where}.inject")
    clear = raw.get("clear_faults", False)
    if not isinstance(clear, bool):
        raise _err(f"{where}.clear_faults", f"expected true or false, got {short_repr(clear)}")
    mark = raw.get("mark", "")
    if not isinstance(mark, str) or (mark and not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", mark)):
        raise _err(f"{where}.mark", f"expected a name (letters, digits, _), got {short_repr(mark)}")
    if mark in EVENTS_BUILTIN:
        raise _err(f"{where}.mark", f"{mark!r} is a built-in event ({', '.join(EVENTS_BUILTIN)})")
    return Actions(slew_rad, hold, command, release, inject, clear, mark)


def parse_sequence(raw: Any, variables: Mapping[str, Any] | None, source: str,
                   actuators: tuple[str, ...], quantities: Mapping[str, Quantity],
                   can_inject: Callable[[FaultSpec, str], None] | None = None
                   ) -> SequenceSpec:
    """The checked sequence. ``can_inject(fault, where)`` raises ``ConfigError`` for a fault
    the rig cannot take at run time (None: no rig can)."""
    where0 = f"{source}: sequence"
    if variables is not None and not isinstance(variables, dict):
        raise _err(f"{source}: variables", f"expected a mapping NAME: value, got "
                                           f"{short_repr(variables)}")
    raw = substitute(raw, variables or {}, where0)
    if isinstance(raw, list):
        raw = {"steps": raw}
    if not isinstance(raw, dict):
        raise _err(where0, f"expected {{steps: [...], finally: [...]}}, got {short_repr(raw)}")
    unknown = sorted(set(raw) - {"steps", "finally", "after_fault_s"})
    if unknown:
        raise _err(f"{where0}.{unknown[0]}", "unknown key (expected steps, finally, "
                                             "after_fault_s)")
    after = _number(raw.get("after_fault_s", DEFAULT_AFTER_FAULT_S), f"{where0}.after_fault_s",
                    0.0, exclusive=True)
    steps_raw, final_raw = raw.get("steps"), raw.get("finally") or []
    if not isinstance(steps_raw, list) or not steps_raw:
        raise _err(f"{where0}.steps", "expected a list of at least one step")
    if not isinstance(final_raw, list):
        raise _err(f"{where0}.finally", "expected a list of steps")
    steps: list[Step] = []
    names: set[str] = set()
    for part, items in (("steps", steps_raw), ("finally", final_raw)):
        for i, s in enumerate(items):
            where = f"{where0}.{part}[{i}]"
            step = _step(s, len(steps), where, actuators, part == "finally")
            if step.name in names:
                raise _err(f"{where}.name", f"{step.name!r} names two steps")
            names.add(step.name)
            steps.append(step)
    marks = frozenset(a.mark for s in steps for a in (s.actions, *(w.actions for w in s.when))
                      if a.mark)
    spec = SequenceSpec(tuple(s for s in steps if not s.final),
                        tuple(s for s in steps if s.final), after, source, marks)
    _check(spec, quantities, can_inject)
    return spec


def _step(raw: Any, index: int, where: str, actuators: tuple[str, ...], final: bool) -> Step:
    if not isinstance(raw, dict):
        raise _err(where, f"expected a step {{name, ...}}, got {short_repr(raw)}")
    unknown = sorted(set(raw) - set(STEP_KEYS))
    if unknown:
        raise _err(f"{where}.{unknown[0]}", f"unknown key (a step has {', '.join(STEP_KEYS)})")
    name = raw.get("name")
    if not isinstance(name, str) or not name.strip():
        raise _err(f"{where}.name", f"expected the step's name, got {short_repr(name)}")
    where = f"{where} ({name})"
    actions = _actions(raw, where, actuators)
    controller = raw.get("controller")
    if controller is not None:
        if not isinstance(controller, dict) or not isinstance(controller.get("type"), str):
            raise _err(f"{where}.controller", "expected a controller section {type: NAME, "
                                              f"...}}, got {short_repr(controller)}")
        if actions.slew_rad is not None or actions.hold:
            raise _err(f"{where}.controller", "a step runs its own controller or slews / "
                                              "holds the run's, not both")
    wait = _condition_text(raw["wait_until"], f"{where}.wait_until") \
        if "wait_until" in raw else None
    until = _condition_text(raw["until"], f"{where}.until") if "until" in raw else None
    timeout = _number(raw["timeout_s"], f"{where}.timeout_s", 0.0, exclusive=True) \
        if "timeout_s" in raw else None
    for_s = _number(raw["for_s"], f"{where}.for_s", 0.0, exclusive=True) \
        if "for_s" in raw else None
    if wait is not None and timeout is None:
        raise _err(f"{where}.timeout_s", "a wait_until needs a timeout_s (how long to wait "
                                         "before the step fails)")
    if timeout is not None and wait is None:
        raise _err(f"{where}.timeout_s", "a timeout_s belongs to a wait_until")
    if wait is not None and (for_s is not None or until is not None):
        raise _err(f"{where}.wait_until", "a step ends by wait_until (with timeout_s), or by "
                                          "for_s and/or until, not both")
    if until is not None and for_s is None:
        raise _err(f"{where}.for_s", "an until needs a for_s (the step's longest time)")
    on_timeout = raw.get("on_timeout", "fail")
    if on_timeout not in ("fail", "error"):
        raise _err(f"{where}.on_timeout", f"expected fail or error, got {short_repr(on_timeout)}")
    on_fail = raw.get("on_fail", "abort")
    if on_fail not in ("abort", "continue"):
        raise _err(f"{where}.on_fail", f"expected abort or continue, got {short_repr(on_fail)}")
    verify_raw = raw.get("verify", [])
    verify_list = verify_raw if isinstance(verify_raw, list) else [verify_raw]
    verify = tuple(_condition_text(v, f"{where}.verify[{i}]")
                   for i, v in enumerate(verify_list))
    when_raw = raw.get("when", [])
    if isinstance(when_raw, dict):
        when_raw = [when_raw]
    if not isinstance(when_raw, list):
        raise _err(f"{where}.when", "expected a list of {if: CONDITION, do: {...}}")
    whens = []
    for j, w in enumerate(when_raw):
        wwhere = f"{where}.when[{j}]"
        if not isinstance(w, dict) or "if" not in w or "do" not in w:
            raise _err(wwhere, f"expected {{if: CONDITION, do: {{...}}, every: false}}, got "
                               f"{short_repr(w)}")
        extra = sorted(set(w) - {"if", "do", "every"})
        if extra:
            raise _err(f"{wwhere}.{extra[0]}", "unknown key (expected if, do, every)")
        do = w["do"]
        if not isinstance(do, dict) or not do or set(do) - set(ACTION_KEYS):
            bad = sorted(set(do) - set(ACTION_KEYS)) if isinstance(do, dict) else []
            raise _err(f"{wwhere}.do{'.' + bad[0] if bad else ''}",
                       f"expected actions from {', '.join(ACTION_KEYS)}")
        every = w.get("every", False)
        if not isinstance(every, bool):
            raise _err(f"{wwhere}.every", f"expected true or false, got {short_repr(every)}")
        whens.append(When(_condition_text(w["if"], f"{wwhere}.if"),
                          _actions(do, f"{wwhere}.do", actuators), every, wwhere))
    return Step(name.strip(), index, where, actions, wait, timeout, on_timeout, verify,
                tuple(whens), for_s, until, on_fail, final, controller)


def _conditions(step: Step) -> list[tuple[str, str]]:
    out = []
    if step.wait_until is not None:
        out.append((f"{step.where}.wait_until", step.wait_until))
    if step.until is not None:
        out.append((f"{step.where}.until", step.until))
    out += [(f"{step.where}.verify[{i}]", v) for i, v in enumerate(step.verify)]
    out += [(f"{w.where}.if", w.condition) for w in step.when]
    return out


def _check(spec: SequenceSpec, quantities: Mapping[str, Quantity],
           can_inject: Callable[[FaultSpec, str], None] | None) -> None:
    events = set(EVENTS_BUILTIN) | spec.marks
    for step in spec.all_steps:
        for where, text in _conditions(step):
            try:
                cond = compile_condition(text, quantities, where)
            except ConditionError as exc:
                raise ConfigError(str(exc)) from None
            for ev in sorted(cond.events):
                if ev not in events:
                    raise _err(where, f"after {ev}: no such event (events: "
                                      f"{', '.join(sorted(events))}; a mark: NAME action "
                                      "makes one)")
                if ev == "fault" and not spec.injects:
                    raise _err(where, "after fault: no step injects a fault, so this can "
                                      "never be decided")
            if where.endswith(".wait_until") and step.timeout_s is not None \
                    and cond.min_time_s > step.timeout_s + 1e-12:
                raise _err(where, f"needs at least {cond.min_time_s:g} s to hold but the "
                                  f"step's timeout_s is {step.timeout_s:g} s: it can never "
                                  "hold in time")
            if where.endswith(".until") and step.for_s is not None \
                    and cond.min_time_s > step.for_s + 1e-12:
                raise _err(where, f"needs at least {cond.min_time_s:g} s to hold but the "
                                  f"step's for_s is {step.for_s:g} s")
        for a, where in [(step.actions, step.where)] + [(w.actions, f"{w.where}.do")
                                                       for w in step.when]:
            if a.inject is not None:
                if can_inject is None:
                    raise _err(f"{where}.inject", "this rig cannot take a fault at run time")
                can_inject(a.inject, f"{where}.inject")
