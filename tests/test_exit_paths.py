"""Every exit path leaves the actuators safe and the recording and CAN log readable."""

from __future__ import annotations

import json
import socket
import subprocess
import sys
from pathlib import Path

import can
import pytest
from rerun.chunk import RrdReader

from drivers.dbc import load_protocol
from harness.controllers import registry
from harness.core.runs import load_run, run_from_dict
from harness.core.session import execute_run
from harness.state import RigCommand

P = load_protocol()


class ExplodingController:
    def __init__(self, at_tick: int) -> None:
        self.at_tick = at_tick

    def reset(self) -> None:
        pass

    def step(self, state):
        if state.tick >= self.at_tick:
            raise RuntimeError("controller blew up")
        return RigCommand(wheel_torque_n_m=0.05)


@pytest.fixture
def exploding(monkeypatch):
    reg = registry.ControllerRegistry()
    reg.add(registry.ControllerType("explode", {"type": registry.Field("str", required=True)},
                                    lambda c, rig, dt: ExplodingController(300)))
    monkeypatch.setattr(registry, "REGISTRY", reg)


def _last_commands(blf: Path) -> dict[str, dict[str, float]]:
    last = {}
    for msg in can.LogReader(str(blf)):
        codec = P.by_id.get(msg.arbitration_id)
        if codec is not None and codec.name.endswith("_CMD"):
            last[codec.name] = codec.decode(msg.data)
    return last


def test_controller_exception_leaves_rig_safe_and_logs_complete(tmp_path, exploding):
    run = run_from_dict({"name": "boom", "duration_s": 5.0, "controller": {"type": "explode"}})
    with pytest.raises(RuntimeError, match="blew up"):
        execute_run(run, out_dir=tmp_path, show_progress=False)
    (run_dir,) = tmp_path.iterdir()
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["stopped_by"] == "error" and "blew up" in summary["error"]
    assert summary["ticks"] == 300
    last = _last_commands(run_dir / "can.blf")
    assert last["WHEEL_CMD"]["torque_cmd"] == 0.0 and last["WHEEL_CMD"]["enable"] == 0
    assert last["VALVE_CMD"]["valve_pos"] == 0 and last["VALVE_CMD"]["valve_neg"] == 0
    assert last["PIEZO_CMD"]["voltage_ch1"] == 0.0 and last["PIEZO_CMD"]["voltage_ch2"] == 0.0
    rows = sum(c.num_rows for c in RrdReader(run_dir / "run.rrd").stream().to_chunks()
               if c.entity_path == "/wheel/torque_cmd_n_m" and not c.is_static)  # the legend's name
    assert rows == 300


def test_realtime_clock_in_process(tmp_path):
    res = execute_run(load_run("slew-rw", {"duration_s": 1.0,
                                           "monitor": {"realtime_grace_s": 2.0}}),
                      out_dir=tmp_path, clock="realtime", show_progress=False)
    s = res.summary
    assert s["stopped_by"] == "completed" and s["ticks"] == 501
    assert 0.9 < s["wall_time_s"] < 3.0  # paced by the wall clock, not as fast as possible
    assert any("gc.freeze" in m for m in s["realtime_measures"]["applied"])
    import gc

    assert gc.isenabled()  # restored after the run


def test_dry_run_sends_no_command_frame(tmp_path):
    res = execute_run(load_run("slew-rw", {"duration_s": 1.0}), out_dir=tmp_path,
                      show_progress=False, dry_run=True)
    ids = {m.arbitration_id for m in can.LogReader(str(res.run_dir / "can.blf"))}
    assert not ids & {P[n].frame_id for n in ("WHEEL_CMD", "VALVE_CMD", "PIEZO_CMD",
                                              "ROTOR_CMD")}
    assert P["HUB_TLM"].frame_id in ids
    assert res.virtual_rig is not None and res.virtual_rig.x[0] == 0.0


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.slow
def test_rig_in_its_own_process_over_socketcand(tmp_path):
    port = _free_port()
    rig = subprocess.Popen([sys.executable, "-m", "harness", "virtual-rig",
                            "--serve-socketcand", str(port), "--duration-s", "60"],
                           stderr=subprocess.PIPE, text=True)
    try:
        assert "socketcand" in rig.stderr.readline()
        run = load_run("slew-rw", {"duration_s": 2.0, "monitor": {"realtime_grace_s": 2.0}})
        res = execute_run(run, out_dir=tmp_path, bus=f"socketcand:127.0.0.1:{port}",
                          clock="realtime", show_progress=False)
    finally:
        rig.terminate()
        out = rig.communicate(timeout=10)[1]
    s = res.summary
    assert s["stopped_by"] == "completed"
    assert s["frames"]["received"] > 0.9 * 4 * s["ticks"]
    assert "stopped after" in out


@pytest.mark.slow
def test_rig_process_dying_mid_run_ends_in_an_error_verdict_without_traceback(tmp_path):
    """The virtual rig's own process is killed during a real-time run: the run ends with
    exit 4 and a one-line reason naming the bus (not a traceback), the recording and the
    CAN log up to that tick read back, and the verdict says why."""
    import os
    import signal
    import time

    proc = subprocess.Popen([sys.executable, "-m", "harness", "run", "slew-rw", "--clock",
                             "realtime", "--duration-s", "20", "--quiet", "--out",
                             str(tmp_path)], stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 60
        rig_pid = None
        while rig_pid is None and time.monotonic() < deadline:
            logs = list(tmp_path.glob("*/rig.log"))
            if logs and "Ctrl-C to stop" in logs[0].read_text():
                out = subprocess.run(["pgrep", "-f", "--", f"--rig {logs[0].parent}/rig.yaml"],
                                     capture_output=True, text=True).stdout.split()
                rig_pid = int(out[0]) if out else None
            time.sleep(0.2)
        assert rig_pid is not None, "the rig process did not start"
        time.sleep(1.0)
        os.kill(rig_pid, signal.SIGKILL)
        err = proc.communicate(timeout=60)[1]
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 4, err
    assert "Traceback" not in err
    assert "the bus failed" in err and "rig.log" in err
    run_dir = next(tmp_path.glob("*-slew-rw"))
    verdict = json.loads((run_dir / "verdict.json").read_text())
    run_row = next(c for c in verdict["criteria"] if c["name"] == "run")
    assert run_row["verdict"] == "ERROR" and "closed the bus" in run_row["message"]
    frames = sum(1 for _ in can.LogReader(str(run_dir / "can.blf")))
    assert frames > 500  # about a second of traffic at least, read back whole
