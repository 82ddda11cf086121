"""`harness replay`: a run's CAN log through the drivers again, and the determinism check."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import can
import numpy as np
import pytest

from drivers.dbc import load_protocol
from harness.cli import main
from harness.core.replay import check_run, replay_log, split_commands, write_rrd
from harness.core.runs import load_run
from harness.core.session import execute_run
from harness.record.reader import read_scalar_channel
from rig_models.faults import parse_fault
from rig_models.rig_file import load_rig

P = load_protocol()
TAMPER_TICK = 750  # t = 1.5 s, inside the slew (it starts at 1 s)


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("replay")
    res = execute_run(load_run("slew-rw", {"duration_s": 2.0}), out_dir=out,
                      show_progress=False)
    assert res.summary["stopped_by"] == "completed" and res.summary["ticks"] == 1001
    return res.run_dir


def _rewrite_log(src: Path, dst: Path, edit) -> None:
    """Copy a BLF frame by frame, ``edit(index, tick, msg)`` returning the frame to write
    (or None to drop it)."""
    msgs = list(can.LogReader(str(src)))
    writer = can.BLFWriter(str(dst))
    tick = -1
    for i, m in enumerate(msgs):
        if m.arbitration_id == P["SYNC"].frame_id and not m.is_error_frame:
            tick = int(P["SYNC"].decode(m.data)["tick"])
        m = edit(i, tick, m)
        if m is not None:
            writer.on_message_received(m)
    writer.stop()


def _tampered_copy(run_dir: Path, dst: Path, tick: int = TAMPER_TICK) -> Path:
    shutil.copytree(run_dir, dst)

    def edit(i, t, m):
        if t == tick and m.arbitration_id == P["WHEEL_CMD"].frame_id:
            v = P["WHEEL_CMD"].decode(m.data)
            v["torque_cmd"] = -v["torque_cmd"] + 0.01  # clearly not the controller's
            m.data = bytearray(P["WHEEL_CMD"].encode(v))
        return m

    _rewrite_log(run_dir / "can.blf", dst / "can.blf", edit)
    return dst


def test_replayed_states_match_the_recording(run_dir):
    rep = replay_log(run_dir / "can.blf", load_rig("sgsrt"), 1 / 500)
    assert [t.tick for t in rep.ticks] == list(range(1001))
    t_rrd, angle = read_scalar_channel(run_dir / "run.rrd", "/attitude/angle_deg")
    _, accel = read_scalar_channel(run_dir / "run.rrd", "/tip/accel_m_s2")
    _, torque_cmd = read_scalar_channel(run_dir / "run.rrd", "/wheel/torque_cmd_n_m")
    # Rerun keeps time in integer ns
    np.testing.assert_allclose([t.time_s for t in rep.ticks], t_rrd, rtol=0, atol=1e-9)
    # the same drivers on the same frames: the same numbers, bit for bit
    np.testing.assert_array_equal(np.degrees([t.state.hub_angle_rad for t in rep.ticks]), angle)
    np.testing.assert_array_equal([t.state.tip_accel_m_s2 for t in rep.ticks], accel)
    assert np.ptp(angle) > 0.005  # the slew moved: the comparison is not trivially zeros
    # the logged command is the recorded one, quantised to the DBC's 1e-5 N m
    logged = np.array([split_commands(t.commands)[0][0].values["torque_cmd"]
                       for t in rep.ticks])
    assert np.max(np.abs(logged - torque_cmd)) <= 0.5e-5 + 1e-12
    assert np.max(np.abs(torque_cmd)) > 0.01
    s = json.loads((run_dir / "summary.json").read_text())["frames"]
    assert rep.unknown == s["unknown"] == 0 and rep.error_frames == 0
    assert sum(rep.malformed.values()) == s["malformed"] == 0
    assert rep.missing_frames == s["missing"] and rep.sync_gaps == 0
    assert rep.total_frames == s["sent"] + s["received"]
    # the last tick ends with the leave-safe group after the controller's command
    ctrl, safe = split_commands(rep.ticks[-1].commands)
    assert [c.name for c in ctrl] == ["WHEEL_CMD"] and len(safe) == 4
    assert all(not split_commands(t.commands)[1] for t in rep.ticks[:-1])


def test_check_all_ticks_match(run_dir):
    _, res = check_run(run_dir)
    assert res.consistent
    assert res.ticks_compared == res.ticks_matching == res.ticks_identical == 1001
    assert res.first_mismatch is None and res.skipped == []
    assert res.safe_tick == 1000 and res.stopped_by == "completed"
    assert res.monitor_event is None and res.logged_fault is None and res.monitor_consistent


def test_check_finds_a_tampered_command(run_dir, tmp_path):
    bad = _tampered_copy(run_dir, tmp_path / "tampered")
    _, res = check_run(bad)
    assert not res.consistent
    assert res.ticks_compared == 1001 and res.ticks_matching == 1000
    m = res.first_mismatch
    assert m is not None and m.tick == TAMPER_TICK and m.frame == "WHEEL_CMD"
    assert m.time_s == pytest.approx(1.5)
    assert "torque_cmd" in m.detail
    assert m.logged["torque_cmd"] == pytest.approx(-m.replayed["torque_cmd"] + 0.01, abs=1e-5)


def test_missing_command_is_a_mismatch_but_not_on_the_last_tick(run_dir, tmp_path):
    wheel = P["WHEEL_CMD"].frame_id

    def drop_at(tick):
        def edit(i, t, m):
            if t == tick and m.arbitration_id == wheel and P["WHEEL_CMD"].decode(
                    m.data)["enable"] == 1:
                return None
            return m
        return edit

    mid = shutil.copytree(run_dir, tmp_path / "mid")
    _rewrite_log(run_dir / "can.blf", mid / "can.blf", drop_at(400))
    _, res = check_run(mid)
    assert res.first_mismatch is not None and res.first_mismatch.tick == 400
    assert res.first_mismatch.frame == "(frames)"
    last = shutil.copytree(run_dir, tmp_path / "last")
    _rewrite_log(run_dir / "can.blf", last / "can.blf", drop_at(1000))
    _, res = check_run(last)  # as if interrupted before its commands: skipped, said why
    assert res.consistent and res.ticks_compared == 1000
    assert [k for k, _ in res.skipped] == [1000] and "safe commands" in res.skipped[0][1]


def test_fault_run_replays(tmp_path):
    res = execute_run(load_run("slew-rw", {"duration_s": 2.0}), out_dir=tmp_path,
                      show_progress=False, faults=[parse_fault("wrong_length@1.2:reaction_wheel")])
    s = res.summary
    assert s["stopped_by"] == "fault"
    rep, chk = check_run(res.run_dir)
    assert len(rep.ticks) == s["ticks"] < 1001
    assert rep.malformed["WHEEL_TLM"] == s["frames"]["malformed"] >= 1
    # the fault tick: the controller's command, then the safe commands; all consistent
    assert chk.consistent and chk.ticks_compared == s["ticks"]
    assert chk.safe_tick == rep.ticks[-1].tick == s["faults"][0]["tick"]
    # the fault monitor, re-run on the replay, raises the same fault at the same tick
    assert chk.monitor_event is not None and chk.monitor_consistent
    assert (chk.monitor_event.tick, chk.monitor_event.device, chk.monitor_event.kind) == (
        s["faults"][0]["tick"], "reaction_wheel", "malformed frame")


def test_monitor_rerun_catches_a_summary_that_disagrees(tmp_path, capsys):
    res = execute_run(load_run("slew-rw", {"duration_s": 2.0}), out_dir=tmp_path,
                      show_progress=False, faults=[parse_fault("silent_sensor@0.5:hub_sensor")])
    s = res.summary
    assert s["stopped_by"] == "fault"
    _, chk = check_run(res.run_dir)
    assert chk.consistent and chk.monitor_event.kind == "silent"
    # a summary claiming the fault came a tick earlier no longer agrees with the log
    s["faults"][0]["tick"] -= 1
    (res.run_dir / "summary.json").write_text(json.dumps(s))
    _, chk = check_run(res.run_dir)
    assert not chk.monitor_consistent and not chk.consistent
    assert main(["replay", str(res.run_dir), "--check"]) == 1
    assert "MISMATCH" in capsys.readouterr().out


def test_interrupted_run_replays(tmp_path):
    calls = iter(range(10**6))
    res = execute_run(load_run("slew-rw", {"duration_s": 2.0}), out_dir=tmp_path,
                      show_progress=False,
                      should_stop=lambda: "test" if next(calls) >= 600 else None)
    assert res.summary["stopped_by"] == "interrupted"
    rep, chk = check_run(res.run_dir)
    assert chk.consistent and chk.ticks_compared == len(rep.ticks) == res.summary["ticks"]
    assert chk.safe_tick == rep.ticks[-1].tick


def test_other_log_formats_replay_the_same(run_dir, tmp_path):
    msgs = list(can.LogReader(str(run_dir / "can.blf")))
    rig = load_rig("sgsrt")
    ref = replay_log(run_dir / "can.blf", rig, 1 / 500)
    for suffix, writer_cls in ((".asc", can.ASCWriter), (".log", can.CanutilsLogWriter)):
        path = tmp_path / f"capture{suffix}"
        writer = writer_cls(str(path))
        for m in msgs:
            writer.on_message_received(m)
        writer.stop()
        rep = replay_log(path, rig, 1 / 500)
        assert rep.frames_by_id == ref.frames_by_id
        assert [t.state for t in rep.ticks] == [t.state for t in ref.ticks]


def test_write_rrd(run_dir, tmp_path):
    rep = replay_log(run_dir / "can.blf", load_rig("sgsrt"), 1 / 500)
    out = write_rrd(rep, tmp_path / "replay.rrd")
    t, a = read_scalar_channel(out, "/tip/accel_m_s2")
    _, a_run = read_scalar_channel(run_dir / "run.rrd", "/tip/accel_m_s2")
    np.testing.assert_array_equal(a, a_run)
    assert t[-1] == pytest.approx(2.0)
    _, cmd = read_scalar_channel(out, "/wheel/torque_cmd_n_m")
    assert len(cmd) == 1001 and np.max(np.abs(cmd)) > 0.01


# ------------------------------------------------------------------ command line
def test_cli_consistent_exit_0(run_dir, capsys, tmp_path):
    rrd = tmp_path / "out.rrd"
    assert main(["replay", str(run_dir), "--check", "--json", "--rrd", str(rrd)]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["ticks"] == 1001 and report["check"]["consistent"]
    assert report["check"]["ticks_matching"] == 1001
    names = {f["name"]: f["frames"] for f in report["frames"]}
    assert names["SYNC"] == 1001 and names["HUB_TLM"] == 1001
    assert rrd.exists()
    assert main(["replay", str(run_dir / "can.blf")]) == 0  # a bare log, default rig
    out = capsys.readouterr().out
    assert "HUB_TLM" in out and "malformed 0" in out and "check:" not in out


def test_cli_tampered_exit_1(run_dir, capsys, tmp_path):
    bad = _tampered_copy(run_dir, tmp_path / "tampered")
    assert main(["replay", str(bad), "--check"]) == 1
    out = capsys.readouterr().out
    assert f"MISMATCH: first at tick {TAMPER_TICK}" in out and "WHEEL_CMD" in out
    assert "1001 ticks compared, 1000 matching" in out


def test_cli_bad_input_exit_2(run_dir, capsys, tmp_path):
    assert main(["replay", str(tmp_path / "nothing.blf")]) == 2
    assert "nothing.blf: no such file" in capsys.readouterr().err
    assert main(["replay", str(run_dir / "can.blf"), "--check"]) == 2
    assert "--check needs a run directory" in capsys.readouterr().err
    junk = tmp_path / "junk.blf"
    junk.write_bytes(b"not a BLF file at all" * 10)
    assert main(["replay", str(junk)]) == 2
    assert "junk.blf: cannot read as a CAN log" in capsys.readouterr().err
    empty_dir = tmp_path / "not-a-run"
    empty_dir.mkdir()
    assert main(["replay", str(empty_dir), "--check"]) == 2
    assert "config.yaml: no such file" in capsys.readouterr().err
    assert main(["replay", str(run_dir / "can.blf"), "--rig", "no-such-rig"]) == 2
    assert "no-such-rig" in capsys.readouterr().err


def test_strict_exits_1_on_unknown_ids_gaps_and_missing_telemetry(run_dir, capsys, tmp_path):
    """A capture with foreign ids replays (exit 0) but is not accepted with --strict."""
    assert main(["replay", str(run_dir / "can.blf"), "--strict"]) == 0  # a clean log
    capsys.readouterr()
    hub = P["HUB_TLM"].frame_id

    def edit(i, t, m):
        if t == 300 and m.arbitration_id == P["SYNC"].frame_id:
            return None  # a SYNC gap
        if t == 400 and m.arbitration_id == hub:
            return None  # missing telemetry
        if i % 50 == 0 and t > 0:
            return can.Message(timestamp=m.timestamp, arbitration_id=0x7A5, data=b"\x01",
                               is_extended_id=False)  # an id no device has
        return m

    bad = tmp_path / "foreign.blf"
    _rewrite_log(run_dir / "can.blf", bad, edit)
    assert main(["replay", str(bad), "--json"]) == 0  # read, not judged
    capsys.readouterr()
    assert main(["replay", str(bad), "--strict", "--json"]) == 1
    cap = capsys.readouterr()
    problems = json.loads(cap.out)["strict_problems"]
    assert any("unknown ids" in p for p in problems)
    assert any("SYNC gaps" in p for p in problems)
    assert any("missing" in p for p in problems)
    assert "harness replay --strict:" in cap.err
