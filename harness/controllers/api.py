"""The controller API: what a run-file controller type is made of, built-in or a plugin.

A controller type is a *factory* ``factory(section, rig, dt_s) -> controller`` with its
run-file schema declared beside it (``@controller_factory(SCHEMA)``), registered by name in
the entry point group ``sgsrt_harness.controllers`` (``name = "module:factory"``). The
controller it returns has ``reset()`` and ``step(state) -> RigCommand``, called once a tick
(SI units; no I/O, no blocking, no allocation-heavy work in the tick). docs/controllers.md
is the full contract with a template.

This module is the stable surface a plugin imports: ``Controller``, ``ControllerFactory``,
``controller_factory``, ``Field``, ``RigCommand``, ``RigState``, ``RigConfig``, and the
building blocks of the built-in slews: ``CycloidalSlew`` (a rest-to-rest profile from any
angle), ``PDWheelController`` (PD + feed-forward on the wheel, tracking one) and
``Retargetable``, what a controller has for a test sequence's ``slew:`` and ``hold:``
(``retarget(angle_rad, t_s)``). It imports ``harness.state``, ``rig_models`` and those two
modules of ``harness.controllers``.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any, Protocol, TypeVar

from harness.controllers.pd_wheel import PDWheelController
from harness.controllers.slew_profile import CycloidalSlew
from harness.state import SAFE_COMMAND, RigCommand, RigState
from rig_models.rig_file import RigConfig
from rig_models.schema import Field, Schema

__all__ = ["SAFE_COMMAND", "TYPE_FIELD", "Controller", "ControllerFactory", "CycloidalSlew",
           "Field", "PDWheelController", "Retargetable", "RigCommand", "RigConfig",
           "RigState", "Schema", "controller_factory"]


class Controller(Protocol):
    """What the loop calls: ``reset()`` once before the first tick, ``step(state)`` every
    tick with that tick's telemetry (SI units), returning the tick's actuator commands."""

    def reset(self) -> None: ...

    def step(self, state: RigState) -> RigCommand: ...


class Retargetable(Protocol):
    """A controller a test sequence can send elsewhere: ``retarget(angle_rad, t_s)`` makes
    its reference slew from where it is at ``t_s`` to ``angle_rad`` (a ``slew:`` step; a
    ``hold:`` retargets to the hub's angle). Called between two ticks, never inside
    ``step``; it must not block."""

    def retarget(self, angle_rad: float, t_s: float) -> None: ...


ControllerFactory = Callable[[dict[str, Any], RigConfig, float], Controller]
"""``factory(section, rig, dt_s)``: the validated ``controller:`` section (defaults filled
in, numbers as float), the rig file, the loop period in seconds. A ``ValueError`` it raises
is the run's configuration error (exit 2, nothing sent)."""

TYPE_FIELD = Field("str", required=True)
"""The ``type:`` key every controller section has (added to a schema that omits it)."""

F = TypeVar("F", bound=Callable[..., Any])


def controller_factory(schema: Mapping[str, Any]) -> Callable[[F], F]:
    """Declare a factory's run-file schema beside it: the registry reads ``factory.schema``
    and checks a run's ``controller:`` section against it (unknown key, wrong type, out of
    range: a one-line error naming the key) before anything is sent.

        @controller_factory({"angle_deg": Field("number", "deg", required=True)})
        def build(section, rig, dt_s): ...
    """
    full = dict(schema) if "type" in schema else {"type": TYPE_FIELD, **schema}

    def declare(factory: F) -> F:
        factory.schema = full  # type: ignore[attr-defined]
        return factory

    return declare
