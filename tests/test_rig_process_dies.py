"""The virtual rig's own process ends or stops answering in the middle of a real-time run
(``realtime.virtual_rig: process-unix``, the default, and ``process-tcp`` over
socketcand). Killed: the run ends within seconds, ERROR naming the process and how it
ended, the rig commanded safe (the frames the dead peer cannot take are counted, none
raises), the files closed and judged. Stopped (SIGSTOP): no device answers, which is the
bench's stall, not a device's fault: the run ends at ``monitor.bench_stall_s`` naming the
bus, and never hangs on a peer that does not read."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import can
import pytest
import yaml
from rerun.chunk import RrdReader

import harness

DURATION_S = 20.0
RUN_BEFORE_SIGNAL_S = 2.5
TRANSPORTS = {"process-unix": [], "process-tcp": ["--rig-process"]}


def _run_file(tmp_path: Path) -> Path:
    """slew-rw with a wide real-time grace (this shared host may be busy)."""
    data = yaml.safe_load((Path(harness.__file__).parent / "runs" / "slew-rw.yaml")
                          .read_text())
    data.update(duration_s=DURATION_S, monitor={"realtime_grace_s": 1.0})
    path = tmp_path / "slew-rw.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def _children(pid: int) -> list[int]:
    kids: list[int] = []
    try:
        tasks = os.listdir(f"/proc/{pid}/task")
    except OSError:
        return kids
    for task in tasks:
        try:
            kids += [int(k) for k in Path(f"/proc/{pid}/task/{task}/children").read_text()
                     .split()]
        except OSError:
            pass
    return kids


def _alive(pid: int) -> bool:
    """Running, or stopped: not gone and not a zombie."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return False
    return fields[0] != "Z"


class Ended:
    def __init__(self, code: int, err: str, after_s: float, rig_pid: int, out: Path) -> None:
        self.code, self.err, self.after_s, self.rig_pid = code, err, after_s, rig_pid
        self.run_dir = next(p for p in out.iterdir() if p.is_dir())
        self.summary = json.loads((self.run_dir / "summary.json").read_text())
        self.verdict = json.loads((self.run_dir / "verdict.json").read_text())


def _run_and_signal(tmp_path: Path, transport: str, sig: signal.Signals) -> Ended:
    out = tmp_path / "logs"
    proc = subprocess.Popen(
        [sys.executable, "-m", "harness", "run", str(_run_file(tmp_path)), "--clock",
         "realtime", "--quiet", "--out", str(out), *TRANSPORTS[transport]],
        stderr=subprocess.PIPE, text=True)
    rig_pid = None
    try:
        deadline = time.monotonic() + 90
        while rig_pid is None and time.monotonic() < deadline and proc.poll() is None:
            logs = list(out.glob("*/rig.log"))
            if logs and "Ctrl-C to stop" in logs[0].read_text():  # it serves
                kids = _children(proc.pid)
                rig_pid = kids[0] if kids else None
            time.sleep(0.1)
        assert rig_pid is not None, "the rig process did not start"
        time.sleep(RUN_BEFORE_SIGNAL_S)
        assert proc.poll() is None, "the run ended before the rig process was signalled"
        os.kill(rig_pid, sig)
        t_sig = time.monotonic()
        err = proc.communicate(timeout=60)[1]
        after_s = time.monotonic() - t_sig
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
        if rig_pid is not None and _alive(rig_pid) and sig == signal.SIGSTOP:
            os.kill(rig_pid, signal.SIGKILL)
    return Ended(proc.returncode, err, after_s, rig_pid, out)


def _check_files(ended: Ended) -> None:
    """summary, verdict, can.blf and run.rrd written and readable; `harness judge` works."""
    run_dir, s = ended.run_dir, ended.summary
    frames = list(can.LogReader(str(run_dir / "can.blf")))
    assert len(frames) > 3 * s["ticks"]  # SYNC, a command and telemetry each tick
    rows = sum(c.num_rows for c in RrdReader(run_dir / "run.rrd").stream().to_chunks()
               if c.entity_path == "/wheel/torque_cmd_n_m" and not c.is_static)
    assert rows == s["ticks"] > 0
    judged = subprocess.run([sys.executable, "-m", "harness", "judge", str(run_dir)],
                            capture_output=True, text=True, timeout=120)
    assert judged.returncode == ended.code, judged.stderr
    assert "Traceback" not in judged.stderr + judged.stdout


def _no_leftovers(ended: Ended) -> None:
    deadline = time.monotonic() + 5
    while _alive(ended.rig_pid) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not _alive(ended.rig_pid), "the rig process outlived its run"
    assert list(ended.run_dir.glob("*.sock")) == []
    assert not any(p.name.startswith("tmp") for p in ended.run_dir.iterdir())


@pytest.mark.slow
@pytest.mark.parametrize("transport", list(TRANSPORTS))
def test_a_rig_process_killed_mid_run_ends_it_in_error_naming_the_process(tmp_path,
                                                                          transport):
    ended = _run_and_signal(tmp_path, transport, signal.SIGKILL)
    assert ended.code == 4, ended.err
    assert ended.after_s < 6.0, ended.after_s  # a second or so, then closing and judging
    assert "Traceback" not in ended.err, ended.err
    named = f"the virtual rig process (pid {ended.rig_pid}) exited (killed by SIGKILL, " \
            "exit code -9)"
    [line] = [ln for ln in ended.err.splitlines() if ln.startswith("harness: the run stop")]
    assert line.startswith("harness: the run stopped: the bus failed: " + named), line
    assert "rig.log" in line
    assert f"VERDICT ERROR (exit 4): run: the run raised: {named}" in ended.err
    s = ended.summary
    assert s["stopped_by"] == "error" and named in s["error"], s["error"]
    assert "\n" not in s["error"]
    assert s["ticks"] < 0.5 * DURATION_S * s["rate_hz"]
    # the safe state was commanded: the wheel, valves, piezo and rotor frames and the
    # disarming heartbeat, refused by the dead peer and counted, not raised
    assert s["frames"]["not_sent"] >= 5, s["frames"]
    assert "could not command the safe state" not in ended.err
    assert ended.verdict["verdict"] == "ERROR"
    run_row = next(c for c in ended.verdict["criteria"] if c["name"] == "run")
    assert run_row["verdict"] == "ERROR" and named in run_row["message"]
    safe_row = next(c for c in ended.verdict["criteria"] if c["name"] == "safe")
    assert safe_row["verdict"] == "PASS" or "the bus refused" in safe_row["message"]
    _check_files(ended)
    _no_leftovers(ended)


@pytest.mark.slow
@pytest.mark.parametrize("transport", list(TRANSPORTS))
def test_a_rig_process_that_stops_answering_is_a_bench_stall_naming_the_bus(tmp_path,
                                                                            transport):
    ended = _run_and_signal(tmp_path, transport, signal.SIGSTOP)
    s = ended.summary
    stall_s = max(1.0, 2 * 1.0)  # monitor.bench_stall_s at realtime_grace_s 1.0
    assert ended.code == 3, ended.err
    assert ended.after_s < stall_s + 6.0, ended.after_s  # never the run's duration
    assert "Traceback" not in ended.err, ended.err
    assert s["stopped_by"] == "fault"
    [fault] = s["faults"]
    assert fault["device"] == "bus" and fault["kind"] == "silent", fault  # not a device's
    assert "not one device" in fault["message"]
    assert ended.verdict["verdict"] == "ERROR"
    _check_files(ended)
    _no_leftovers(ended)
