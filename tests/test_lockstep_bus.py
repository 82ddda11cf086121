"""Lockstep over a bus: the virtual rig as its own process (``harness virtual-rig
--lockstep``) and the harness in lockstep over the bus between them (``--clock lockstep``), as
CI runs the acceptance suite over vcan0 in its emulated VM (tests/test_socketcan.py). Here
the bus is socketcand on 127.0.0.1 (no SocketCAN on this machine)."""

from __future__ import annotations

import socket
import subprocess
import sys
import time

import can
import pytest
from in_process import harness_in_process

from harness.core.runs import load_run
from harness.core.session import execute_run
from rig_models.rig_file import load_rig
from rig_models.virtual_rig import LOCKSTEP_BACKSTOP_S, VirtualRig

SYNC = (0x080, bytes((1,)))  # CiA 301 SYNC with its counter's first value


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _frames(run_dir) -> list[tuple[int, bytes]]:  # noqa: ANN001
    return [(m.arbitration_id, bytes(m.data)) for m in can.LogReader(str(run_dir / "can.blf"))
            if not m.is_error_frame]


@pytest.mark.slow
def test_a_canopen_run_over_a_bus_in_lockstep_is_the_in_process_run_frame_for_frame(tmp_path):
    """The same short slew on sgsrt-canopen, once in process and once over socketcand against
    the rig's own process in lockstep: the CANopen set-up (NMT, SDO), every SYNC, PDO and
    heartbeat carry the same bytes in the same order. So a lockstep run over vcan0 in CI
    tests the protocol the in-process suite judges, not an approximation of it."""
    port = _free_port()
    rig = subprocess.Popen([sys.executable, "-m", "harness", "virtual-rig", "--rig",
                            "sgsrt-canopen", "--serve-socketcand", str(port), "--lockstep",
                            "--duration-s", "120"], stderr=subprocess.PIPE, text=True)
    try:
        assert "in lockstep" in rig.stderr.readline()
        run = load_run("slew-rw", {"duration_s": 3.0, "rig": "sgsrt-canopen"})
        over_bus = execute_run(run, out_dir=tmp_path / "bus", clock="lockstep",
                               bus=f"socketcand:127.0.0.1:{port}", show_progress=False)
    finally:
        rig.terminate()
        rig.communicate(timeout=20)
    in_process = execute_run(run, out_dir=tmp_path / "proc", show_progress=False)
    assert over_bus.summary["stopped_by"] == in_process.summary["stopped_by"] == "completed"
    assert over_bus.summary["frames"]["missing"] == 0
    a, b = _frames(over_bus.run_dir), _frames(in_process.run_dir)
    assert len(a) > 6 * over_bus.summary["ticks"]
    # the set-up's SDO requests and answers are logged from the canopen library's thread
    # and the in-process rig's boot-ups come before the master's reset: same frames, their
    # order may differ; from the first SYNC on, the tick's frames are in the tick's order
    sa, sb = a.index(SYNC), b.index(SYNC)
    boot_ups = [(0x700 + n, b"\x00") for n in range(2, 6)]
    setup_b = list(b[:sb])
    for f in boot_ups:
        setup_b.remove(f)  # booted before the master's reset comm (over the bus: earlier)
    assert sorted(a[:sa]) == sorted(setup_b)
    assert a[sa:] == b[sb:]
    assert over_bus.summary["final_angle_error_deg"] == in_process.summary[
        "final_angle_error_deg"]


def test_a_rig_process_in_lockstep_lets_its_nodes_time_out_when_the_syncs_stop():
    """In lockstep the nodes' timers run on the rig's time, which stands still without SYNC;
    past the backstop the wall clock carries it on (never backwards), so a harness that died
    still trips the nodes' heartbeat consumers."""
    rig = VirtualRig(load_rig("sgsrt-canopen"), can.Bus(interface="virtual", channel="ls-t"),
                     0.002)
    rig.lockstep_process = True
    rig.time_s = 7.0
    rig.last_sync_wall = time.monotonic()
    assert rig.co_now() == 7.0  # a SYNC just came: the rig's own time
    rig.last_sync_wall = time.monotonic() - LOCKSTEP_BACKSTOP_S - 1.5
    t1 = rig.co_now()
    assert 8.4 < t1 < 8.7  # 1.5 s past the backstop
    rig.last_sync_wall = time.monotonic()  # the SYNCs resume
    assert rig.co_now() >= t1


def test_harness_test_refuses_clock_without_a_bus(tmp_path):
    # the command's answer, in process (tests/in_process.py: no second interpreter)
    out = harness_in_process("test", "acceptance", "--clock", "lockstep", "--out",
                             str(tmp_path))
    assert out.returncode == 2
    assert "--clock lockstep" in out.stderr and "--bus" in out.stderr


MIXED = """extends: sgsrt-canopen
name: sgsrt-mixed
devices:
  accelerometer:   # another binding: replaces the base's CANopen device whole
    binding: dbc
    dbc: {dbc}
    telemetry:
      accel: {{message: ACC_Tlm, signal: ACC_TipAcc_mg, scale: 9.80665e-3}}
      sample_counter: {{message: ACC_Tlm, signal: ACC_SmplCnt}}
      saturated: {{message: ACC_Tlm, signal: ACC_Sat}}
      fault: {{message: ACC_Tlm, signal: ACC_Flt}}
"""


@pytest.mark.slow
def test_a_rig_mixing_canopen_and_dbc_devices_runs_over_a_bus_and_is_left_safe(tmp_path):
    """CANopen nodes and a vendor-DBC accelerometer on one bus, the rig in its own process:
    set up, run, judged (every criterion of the slew, left safe among them) as in process."""
    import json

    from drivers.dbc import DBC_PATH

    rig_file = tmp_path / "sgsrt-mixed.yaml"
    rig_file.write_text(MIXED.format(dbc=DBC_PATH.with_name("sgsrt_dbc2.dbc")))
    rig_cfg = load_rig(str(rig_file))
    assert rig_cfg.binding.kinds["accelerometer"] == "dbc"
    assert rig_cfg.binding.kinds["hub_sensor"] == "canopen"
    port = _free_port()
    rig = subprocess.Popen([sys.executable, "-m", "harness", "virtual-rig", "--rig",
                            str(rig_file), "--serve-socketcand", str(port), "--lockstep",
                            "--duration-s", "120"], stderr=subprocess.PIPE, text=True)
    try:
        assert "in lockstep" in rig.stderr.readline()
        # `harness run` in this process (tests/in_process.py), the rig in its own
        out = harness_in_process("run", "slew-rw", "--rig", str(rig_file), "--bus",
                                 f"socketcand:127.0.0.1:{port}", "--clock", "lockstep",
                                 "--duration-s", "4", "--quiet", "--out",
                                 str(tmp_path / "logs"))
    finally:
        rig.terminate()
        rig.communicate(timeout=20)
    (run_dir,) = [p for p in (tmp_path / "logs").iterdir() if p.is_dir()]
    verdict = json.loads((run_dir / "verdict.json").read_text())
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["stopped_by"] == "completed", out.stderr[-2000:]
    assert summary["frames"]["missing"] == 0 and summary["frames"]["unknown"] == 0
    by_name = {c["name"]: c["verdict"] for c in verdict["criteria"]}
    assert by_name["safe"] == "PASS" and by_name["malformed"] == "PASS", by_name
    ids = {m.arbitration_id for m in can.LogReader(str(run_dir / "can.blf"))}
    assert 0x1A0 in ids and 0x184 in ids  # the DBC accelerometer and the encoder's TPDO
