"""A controller cannot blind the harness or pass for done: it gets a copy of the tick's
state (what it writes never reaches the monitor or the recording), and whatever its step()
raises, SystemExit and a KeyboardInterrupt no signal asked for included, or a return that is
not a RigCommand, ends the run ERROR naming it, the rig left safe, with a verdict."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml

from harness.controllers import registry
from harness.core.loop import ControllerError
from harness.core.runs import run_from_dict
from harness.core.session import execute_run
from harness.record.reader import RecordedColumns
from harness.state import RigCommand, RigState
from rig_models.schema import Field
from tests.in_process import harness_in_process


class Blinder:
    """Full wheel torque, and every tick writes a quiet rig into the state it was given. It
    moves nothing in the limit plan (the plan steps a copy of it: ``original`` is False
    there), so the run starts and the monitor has to see the overspeed itself."""

    def __init__(self) -> None:
        self.seen: list[RigState] = []
        self.original = True

    def __deepcopy__(self, memo: dict) -> Blinder:
        twin = Blinder()
        twin.original = False
        return twin

    def step(self, state: RigState) -> RigCommand:
        self.seen.append(state)
        state.wheel_speed_rad_s = 0.0
        state.hub_angle_rad = 0.0
        state.hub_rate_rad_s = 0.0
        return RigCommand(wheel_torque_n_m=0.065 if self.original else 0.0)


class Raiser:
    def __init__(self, what: str, at_tick: int) -> None:
        self.what, self.at_tick = what, at_tick

    def step(self, state: RigState) -> object:
        if state.tick < self.at_tick:
            return RigCommand(wheel_torque_n_m=0.01)
        if self.what == "exit":
            raise SystemExit(0)
        if self.what == "interrupt":
            raise KeyboardInterrupt
        if self.what == "none":
            return None
        if self.what == "string":
            return RigCommand(wheel_torque_n_m="0.01")  # type: ignore[arg-type]
        raise ValueError("a bug in the plugin")


@pytest.fixture
def lab(monkeypatch):
    reg = registry.ControllerRegistry()
    schema = {"type": Field("str", required=True), "what": Field("str", default=""),
              "at_tick": Field("int", default=0)}
    made: list[object] = []

    def build_blinder(c, rig, dt_s):
        made.append(Blinder())
        return made[-1]

    reg.add(registry.ControllerType("lab_blinder", schema, build_blinder, "lab-ctrl",
                                    "lab_ctrl:blinder"))
    reg.add(registry.ControllerType("lab_raiser", schema,
                                    lambda c, rig, dt_s: Raiser(c["what"], c["at_tick"]),
                                    "lab-ctrl", "lab_ctrl:raiser"))
    monkeypatch.setattr(registry, "REGISTRY", reg)
    return made


def test_a_controller_writing_into_its_state_blinds_neither_the_monitor_nor_the_recording(
        lab, tmp_path):
    # full torque spins the wheel to its 628 rad/s limit in about 15.5 s; the controller
    # tells its state the wheel is still
    run = run_from_dict({"name": "blind", "duration_s": 20.0, "actuators": ["reaction_wheel"],
                         "limits": {"max_angle_deg": 1.0e5, "max_rate_deg_s": 1.0e4},
                         "controller": {"type": "lab_blinder"}})
    result = execute_run(run, out_dir=tmp_path, show_progress=False)
    s = result.summary
    assert s["stopped_by"] == "fault", s["error"]
    assert s["faults"][0]["device"] == "reaction_wheel"
    assert s["faults"][0]["kind"] == "speed limit"
    cols = RecordedColumns(result.run_dir / "run.rrd")
    speed = cols.column("/wheel/speed_rad_s")
    angle = cols.column("/attitude/angle_deg")
    assert np.max(np.abs(speed)) > 600.0  # what the wheel did, not what the controller wrote
    assert np.max(np.abs(angle)) > 10.0
    # and each tick's state the controller kept is its own (a later tick did not rewrite it)
    seen = lab[-1].seen
    assert len({id(x) for x in seen}) == len(seen)
    assert [x.tick for x in seen[:3]] == [0, 1, 2]


@pytest.mark.parametrize("what, raised", [("exit", "SystemExit"),
                                          ("interrupt", "KeyboardInterrupt"),
                                          ("bug", "ValueError"),
                                          ("none", "returned NoneType"),
                                          ("string", "cannot be sent")])
def test_whatever_step_raises_the_run_ends_error_naming_the_controller_rig_safe(
        lab, tmp_path, what, raised):
    run = run_from_dict({"name": "raiser", "duration_s": 1.0, "actuators": ["reaction_wheel"],
                         "controller": {"type": "lab_raiser", "what": what, "at_tick": 100}})
    with pytest.raises(ControllerError) as info:  # no stop asked for (as under the CLI)
        execute_run(run, out_dir=tmp_path, show_progress=False, should_stop=lambda: None)
    message = str(info.value)
    assert "'lab_raiser' of lab-ctrl" in message and raised in message and "tick 100" in message
    run_dir = info.value.run_dir  # type: ignore[attr-defined]
    s = json.loads((run_dir / "summary.json").read_text())
    assert s["stopped_by"] == "error" and raised in s["error"] and s["ticks"] == 100
    # the rig left safe: the last wheel command sent is 0 N m (the CAN log's last WHEEL_CMD)
    cols = RecordedColumns(run_dir / "run.rrd")
    assert cols.column("/wheel/torque_cmd_n_m")[-1] == pytest.approx(0.01)
    assert result_safe(run_dir)


def result_safe(run_dir) -> bool:
    """The CAN log's last wheel command is zero torque, disabled."""
    import can

    from drivers.dbc import load_protocol

    proto = load_protocol()
    wheel = proto.database.get_message_by_name("WHEEL_CMD")
    last = None
    with can.BLFReader(str(run_dir / "can.blf")) as reader:
        for msg in reader:
            if msg.arbitration_id == wheel.frame_id:
                last = wheel.decode(msg.data)
    assert last is not None
    return all(v == 0 for k, v in last.items() if k in ("torque_cmd", "enable"))


def test_systemexit_in_a_plugin_is_an_error_run_with_a_verdict_not_a_completed_one(
        lab, tmp_path):
    run_file = tmp_path / "raiser.yaml"
    run_file.write_text(yaml.safe_dump({
        "name": "raiser", "duration_s": 1.0, "actuators": ["reaction_wheel"],
        "controller": {"type": "lab_raiser", "what": "exit", "at_tick": 50}}))
    out = tmp_path / "logs"
    proc = harness_in_process("run", str(run_file), "--out", str(out), "--quiet", "--json")
    assert proc.returncode in (3, 4), proc.stderr
    assert "Traceback" not in proc.stderr
    assert "step() raised SystemExit" in proc.stderr and "lab_raiser" in proc.stderr
    (run_dir,) = [p for p in out.iterdir() if p.is_dir()]
    verdict = json.loads((run_dir / "verdict.json").read_text())
    assert verdict["verdict"] == "ERROR"
    assert "SystemExit" in (run_dir / "traceback.txt").read_text()
    printed = json.loads(proc.stdout)  # --json: the ERROR run's summary, not []
    assert printed["stopped_by"] == "error" and printed["run"] == "raiser"
    logs = harness_in_process("logs", "--logs", str(out), "--failed")
    assert "raiser" in logs.stdout


def test_systemexit_in_a_plugins_factory_is_refused_naming_it(monkeypatch, tmp_path):
    reg = registry.ControllerRegistry()

    def build(c, rig, dt_s):
        raise SystemExit(0)

    reg.add(registry.ControllerType("lab_exit", {"type": Field("str", required=True)}, build,
                                    "lab-ctrl", "lab_ctrl:exit"))
    monkeypatch.setattr(registry, "REGISTRY", reg)
    run_file = tmp_path / "exit.yaml"
    run_file.write_text(yaml.safe_dump({"name": "exit", "duration_s": 1.0,
                                        "controller": {"type": "lab_exit"}}))
    proc = harness_in_process("run", str(run_file), "--out", str(tmp_path / "logs"))
    assert proc.returncode == 2, proc.stderr
    assert "lab_exit" in proc.stderr and "SystemExit" in proc.stderr
    assert not (tmp_path / "logs").exists() or not any((tmp_path / "logs").iterdir())
