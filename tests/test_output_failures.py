"""A full, read-only or failing output folder: the run leaves the rig safe at
once, ends in bounded time with one line naming the folder and exit 4, never claims
"completed", and what was already written stays readable; a recording cut at any byte reads
back to its last complete message; nothing is written through a link in the run folder."""

from __future__ import annotations

import contextlib
import errno
import json
import os
import random
import subprocess
import sys
import uuid
from pathlib import Path

import can
import pytest
from in_process import harness_in_process

import harness.core.loop as loop_module
import harness.record.output as output
from drivers.dbc import load_protocol
from harness.core.runs import load_run
from harness.core.session import execute_run
from harness.record.can_log import CanLog
from harness.record.output import OutputError, SpaceGuard, fresh_output_path, write_text_atomic
from harness.record.reader import RrdReader, complete_length, iter_chunks

ROOT = Path(__file__).resolve().parents[1]
P = load_protocol()


def _rows(rrd: Path) -> int:
    return sum(c.num_rows for c in iter_chunks(rrd))


def _last_commands(blf: Path) -> dict[str, dict[str, float]]:
    last = {}
    for msg in can.LogReader(str(blf)):
        codec = P.by_id.get(msg.arbitration_id)
        if codec is not None and codec.name.endswith("_CMD"):
            last[codec.name] = codec.decode(msg.data)
    return last


@pytest.fixture(scope="module")
def short_run(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("runs")
    res = execute_run(load_run("slew-rw", {"duration_s": 2.0}), out_dir=out,
                      show_progress=False)
    return res.run_dir


# -- a cut recording ----------------------------------------------------------------------

def test_cut_recording_reads_back_to_its_last_complete_message(short_run, tmp_path):
    data = (short_run / "run.rrd").read_bytes()
    full = _rows(short_run / "run.rrd")
    cut_path = tmp_path / "cut.rrd"
    rng = random.Random(24)
    # the last bytes one by one (inside the last message and its header), then anywhere
    cuts = [len(data) - k for k in range(1, 40)] + rng.sample(range(len(data) // 4, len(data)), 30)
    for cut in cuts:
        cut_path.write_bytes(data[:cut])
        end = complete_length(cut_path)
        assert end <= cut
        # what Rerun itself reads of the same file ended at that message boundary
        whole = tmp_path / "whole.rrd"
        whole.write_bytes(data[:end])
        expected = sum(c.num_rows for c in RrdReader(whole).stream())
        got = _rows(cut_path)
        assert got == expected, cut
        assert 0 < got <= full
    # a cut in the last message loses that message only
    cut_path.write_bytes(data[:-1])
    assert _rows(cut_path) < full
    assert complete_length(short_run / "run.rrd") == len(data)


def test_cut_before_any_message_is_a_clear_error(short_run, tmp_path):
    cut_path = tmp_path / "cut.rrd"
    cut_path.write_bytes((short_run / "run.rrd").read_bytes()[:20])
    with pytest.raises(ValueError):
        _rows(cut_path)


def test_cut_reader_leaves_no_temporary_copy(short_run, tmp_path, monkeypatch):
    import tempfile

    # a temporary folder of this test's own: another test in another worker may be reading a
    # cut recording at the same moment
    own_tmp = tmp_path / "tmp"
    own_tmp.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(own_tmp))
    before = set(Path(tempfile.gettempdir()).glob("sgsrt-cut-*"))
    cut_path = tmp_path / "cut.rrd"
    cut_path.write_bytes((short_run / "run.rrd").read_bytes()[:-7])
    assert _rows(cut_path) > 0
    import gc

    gc.collect()
    assert set(Path(tempfile.gettempdir()).glob("sgsrt-cut-*")) == before


# -- the guard and atomic writes ------------------------------------------------------------

def test_space_guard_names_the_folder(tmp_path, monkeypatch):
    monkeypatch.setattr(output, "free_bytes", lambda folder: 1000)
    with pytest.raises(OutputError, match=str(tmp_path)):
        SpaceGuard(tmp_path, reserve_bytes=4096).check()
    SpaceGuard(tmp_path, reserve_bytes=500).check()


def test_atomic_write_leaves_the_old_file_on_failure(tmp_path, monkeypatch):
    target = tmp_path / "summary.json"
    target.write_text('{"old": 1}')

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(os, "replace", full)
    with pytest.raises(OutputError, match="No space left"):
        write_text_atomic(target, '{"new": 2}')
    assert target.read_text() == '{"old": 1}'
    assert list(tmp_path.iterdir()) == [target]


def test_writes_never_go_through_a_link(tmp_path):
    outside = tmp_path / "outside.txt"
    outside.write_text("precious")
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    (run_dir / "verdict.json").symlink_to(outside)
    (run_dir / "verdict.rrd").symlink_to(outside)
    write_text_atomic(run_dir / "verdict.json", "{}")
    fresh_output_path(run_dir / "verdict.rrd").write_text("x")
    assert outside.read_text() == "precious"
    assert not (run_dir / "verdict.json").is_symlink()
    assert not (run_dir / "verdict.rrd").is_symlink()


def test_judge_writes_through_no_link(short_run, tmp_path):
    import shutil

    run_dir = tmp_path / "run"
    shutil.copytree(short_run, run_dir)
    outside_json = tmp_path / "outside.json"
    outside_rrd = tmp_path / "outside.rrd"
    outside_json.write_text("keep")
    outside_rrd.write_text("keep")
    outside_run = tmp_path / "outside-run.rrd"
    shutil.copy(run_dir / "run.rrd", outside_run)
    before = outside_run.read_bytes()
    for name, target in (("verdict.json", outside_json), ("verdict.rrd", outside_rrd),
                         ("run.rrd", outside_run)):
        (run_dir / name).unlink(missing_ok=True)
        (run_dir / name).symlink_to(target)
    # in process (tests/in_process.py): an exception would reach this test
    proc = harness_in_process("judge", str(run_dir))
    assert "Traceback" not in proc.stderr
    assert outside_json.read_text() == "keep" and outside_rrd.read_text() == "keep"
    assert outside_run.read_bytes() == before  # the verdict is not appended through a link
    assert json.loads((run_dir / "verdict.json").read_text())["verdict"]


# -- a run whose folder fails ------------------------------------------------------------

@pytest.mark.slow
@pytest.mark.parametrize("clock", ["lockstep", "realtime"])
def test_guard_stops_the_run_safe_and_never_completed(tmp_path, monkeypatch, clock):
    """The disk fills during the run (a fake statvfs): the loop stops at the next block,
    the rig is commanded safe, summary.json says error, everything written reads back."""
    calls = {"n": 0}

    def free(folder):
        calls["n"] += 1
        return 10**9 if calls["n"] < 4 else 1000

    monkeypatch.setattr(output, "free_bytes", free)
    # the guard looks once a block: 500 rows in real time, 2500 in lockstep (session.py)
    duration_s = 10.0 if clock == "realtime" else 20.0
    with pytest.raises(OutputError) as info:
        execute_run(load_run("slew-rw", {"duration_s": duration_s}), out_dir=tmp_path,
                    show_progress=False, clock=clock)
    (run_dir,) = tmp_path.iterdir()
    assert str(run_dir) in str(info.value)
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["stopped_by"] == "error" and "output folder" in summary["error"]
    assert 0 < summary["ticks"] < duration_s * 500
    last = _last_commands(run_dir / "can.blf")
    assert last["WHEEL_CMD"]["torque_cmd"] == 0
    assert _rows(run_dir / "run.rrd") > 0


@pytest.mark.parametrize("code", [errno.ENOSPC, errno.EROFS, errno.EIO])
def test_can_log_that_cannot_write_stops_the_run_safe(tmp_path, monkeypatch, code):
    """A write of the CAN log fails (a fake writer: a full disk, a folder remounted
    read-only, an I/O error): the loop leaves the rig safe, the run raises OutputError,
    summary.json never says completed."""
    safe_calls: list[int] = []
    real_leave_safe = loop_module.leave_safe

    def leave_safe(interface, pump):
        safe_calls.append(1)
        real_leave_safe(interface, pump)

    monkeypatch.setattr(loop_module, "leave_safe", leave_safe)
    real_drain = CanLog._drain
    count = {"n": 0}

    def failing_drain(self):
        count["n"] += 1
        if count["n"] > 5:
            raise OSError(code, os.strerror(code), str(self.path))
        return real_drain(self)

    monkeypatch.setattr(CanLog, "_drain", failing_drain)
    with pytest.raises(OutputError, match=os.strerror(code)):
        execute_run(load_run("slew-rw", {"duration_s": 10.0}), out_dir=tmp_path,
                    show_progress=False)
    assert safe_calls == [1]
    (run_dir,) = tmp_path.iterdir()
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["stopped_by"] == "error"
    assert summary["ticks"] < 5000
    assert _rows(run_dir / "run.rrd") > 0


def test_refused_when_the_folder_is_already_full(tmp_path, monkeypatch):
    monkeypatch.setattr(output, "free_bytes", lambda folder: 1000)
    with pytest.raises(OutputError, match="free"):
        execute_run(load_run("slew-rw", {"duration_s": 1.0}), out_dir=tmp_path / "logs",
                    show_progress=False)
    assert not (tmp_path / "logs").exists()


@contextlib.contextmanager
def _small_filesystem(size: str):
    mnt = Path(f"/tmp/sgsrt-small-fs-{uuid.uuid4().hex[:8]}")
    mnt.mkdir()
    try:
        proc = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(mnt)],
                              capture_output=True, text=True)
        if proc.returncode != 0:
            pytest.skip(f"cannot mount a small tmpfs here: {proc.stderr.strip()}")
        try:
            yield mnt
        finally:
            subprocess.run(["umount", "-l", str(mnt)], capture_output=True)
    finally:
        with contextlib.suppress(OSError):
            mnt.rmdir()


RUN_WITH_RESERVE = """
import sys
import harness.record.output as o
o.DEFAULT_RESERVE_BYTES = int(sys.argv[1])
from harness.cli import main
sys.exit(main(sys.argv[2:]))
"""


@pytest.mark.slow
@pytest.mark.parametrize("size,reserve", [("5m", None), ("5m", 0), ("64k", 0)])
def test_run_on_a_small_filesystem(size, reserve):
    """A real full disk: with the guard (default reserve) and without it (reserve 0: the
    writes themselves fail, in Rerun's file sink and the CAN log)."""
    with _small_filesystem(size) as mnt:
        argv = ["run", "slew-rw", "--out", str(mnt), "--quiet"]
        cmd = [sys.executable, "-m", "harness", *argv] if reserve is None else \
            [sys.executable, "-c", RUN_WITH_RESERVE, str(reserve), *argv]
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=150, cwd=ROOT)
        assert proc.returncode == 4, proc.stderr
        assert "Traceback" not in proc.stderr
        lines = [line for line in proc.stderr.splitlines() if line.strip()]
        assert len(lines) == 1 and str(mnt) in lines[0], proc.stderr  # Rerun's own too
        for run_dir in mnt.iterdir():
            summary = run_dir / "summary.json"
            if summary.exists():
                assert json.loads(summary.read_text())["stopped_by"] != "completed"
            assert not (run_dir / "verdict.json").exists()
            rrd = run_dir / "run.rrd"
            if rrd.exists() and rrd.stat().st_size > 1_000_000:
                assert _rows(rrd) > 0
            elif rrd.exists():  # the layout only, or some rows: never an unreadable file
                try:
                    _rows(rrd)
                except ValueError as exc:
                    assert "No recording store" in str(exc)


# -- the live view ---------------------------------------------------------------------------

def test_view_with_no_viewer_listening_is_refused_before_the_run(tmp_path):
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    proc = harness_in_process("run", "slew-rw", "--duration-s", "1", "--view",
                              f"rerun+http://127.0.0.1:{port}/proxy", "--out", str(tmp_path),
                              "--quiet")  # the command's answer, in process
    assert proc.returncode == 2 and "no viewer answers" in proc.stderr, proc.stderr
    assert not any(tmp_path.iterdir())


MUTE_VIEWER = """
import socket, sys, threading
import harness.record.recording as r
r.FLUSH_TIMEOUT_S = 3.0
server = socket.socket()
server.bind(("127.0.0.1", 0))
server.listen(16)
held = []
def accept():
    while True:
        held.append(server.accept()[0])  # accepts, never answers: a viewer gone mute
threading.Thread(target=accept, daemon=True).start()
port = server.getsockname()[1]
from harness.cli import main
code = main(["run", "slew-rw", "--duration-s", "1", "--quiet", "--out", sys.argv[1],
             "--view", f"rerun+http://127.0.0.1:{port}/proxy"])
sys.exit(code)
"""


@pytest.mark.slow
def test_view_to_a_mute_viewer_ends_in_bounded_time(tmp_path):
    """A viewer that accepts and never answers held the end of the run forever (Rerun's
    flush and disconnect wait for its sink): now the run ends with exit 4 and never says
    completed."""
    proc = subprocess.run([sys.executable, "-c", MUTE_VIEWER, str(tmp_path)],
                          capture_output=True, text=True, timeout=90, cwd=ROOT)
    assert proc.returncode == 4, proc.stderr
    assert "Traceback" not in proc.stderr
    (run_dir,) = tmp_path.iterdir()
    assert json.loads((run_dir / "summary.json").read_text())["stopped_by"] != "completed"


# -- a child process dies with its parent ----------------------------------------------------

def _children(pid: int) -> list[int]:
    out = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            out.append(int(stat.parent.name))
    return out


@pytest.mark.skipif(not Path("/proc").exists(), reason="needs Linux /proc")
def test_rig_process_dies_with_a_sigkilled_harness(tmp_path):
    import signal
    import time

    proc = subprocess.Popen([sys.executable, "-m", "harness", "run", "slew-rw", "--clock",
                             "realtime", "--duration-s", "60", "--quiet", "--rig-process", "--out",
                             str(tmp_path)], cwd=ROOT, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 60
        rigs: list[int] = []
        while time.monotonic() < deadline and not rigs:
            rigs = [c for c in _children(proc.pid)
                    if b"virtual-rig" in Path(f"/proc/{c}/cmdline").read_bytes()]
            time.sleep(0.2)
        assert rigs, "the rig process did not start"
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and Path(f"/proc/{rigs[0]}").exists():
            state = (Path(f"/proc/{rigs[0]}/stat").read_text().rsplit(")", 1)[1].split()[0]
                     if Path(f"/proc/{rigs[0]}/stat").exists() else "X")
            if state == "Z":
                break
            time.sleep(0.1)
        alive = Path(f"/proc/{rigs[0]}/stat").exists() and \
            Path(f"/proc/{rigs[0]}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
        assert not alive, "the rig process outlived the harness"
    finally:
        if proc.poll() is None:
            proc.kill()


# -- signals ---------------------------------------------------------------------------------

def test_second_signal_aborts_a_loop_but_not_the_closing():
    import signal
    import sys as _sys

    from harness.core.interrupts import StopRequest

    req = StopRequest()
    req.begin()
    req._handler(signal.SIGTERM, _sys._getframe())
    assert req() == "SIGTERM"
    # after the loop (closing and judging the run): noted, not a KeyboardInterrupt
    req._handler(signal.SIGTERM, _sys._getframe())
    # inside a ticking loop: at once
    scope = {"__name__": "harness.core.loop", "req": req, "signal": signal, "_sys": _sys}
    exec("def run_loop():\n    req._handler(signal.SIGTERM, _sys._getframe())\n", scope)
    with pytest.raises(KeyboardInterrupt):
        scope["run_loop"]()


# -- hand-edited results ---------------------------------------------------------------------

SHAPES = ['{"faults": "x", "stopped_by": "completed"}', "[1, 2]", '"text"',
          "[" * 5000 + "]" * 5000,
          '{"stopped_by": 5, "faults": [1], "ticks": "x", "final_angle_error_deg": "a"}',
          '{"frames": 3, "faults": [{"device": 1}], "run": [], "error": {}}']


def test_hand_edited_summaries_never_crash_judge_or_logs(short_run, tmp_path):
    import shutil

    from harness.cli import main

    logs = tmp_path / "logs"
    for i, text in enumerate(SHAPES):
        run_dir = logs / f"run{i}"
        shutil.copytree(short_run, run_dir)
        (run_dir / "summary.json").write_text(text)
        if text.startswith("[" * 100):  # the nesting, at the entry point's stack depth
            proc = subprocess.run([sys.executable, "-m", "harness", "judge", str(run_dir)],
                                  capture_output=True, text=True, timeout=120, cwd=ROOT)
        else:  # in process (tests/in_process.py): an exception would reach this test
            proc = harness_in_process("judge", str(run_dir))
        assert "Traceback" not in proc.stderr + proc.stdout, text[:80]
        assert proc.returncode in (3, 4), (text[:80], proc.stdout, proc.stderr)
        assert "summary.json" in proc.stdout + proc.stderr
    assert main(["logs", "--logs", str(logs)]) == 0


# -- replay in bounded memory ----------------------------------------------------------------

def test_streamed_replay_keeps_no_tick_and_checks_the_same(short_run):
    from harness.core.replay import (
        ReplayChecker,
        check_replay,
        load_run_dir,
        replay_log,
    )

    run, summary = load_run_dir(short_run)
    kept = replay_log(short_run / "can.blf", run.rig, run.dt_s)
    checker = ReplayChecker(run)
    streamed = replay_log(short_run / "can.blf", run.rig, run.dt_s, keep_ticks=False,
                          on_tick=checker)
    assert streamed.ticks == [] and streamed.n_ticks == len(kept.ticks) > 0
    assert (streamed.first_tick, streamed.last_tick) == (kept.ticks[0].tick,
                                                         kept.ticks[-1].tick)
    assert streamed.missing_frames == kept.missing_frames
    assert checker.finish() == check_replay(kept, run)


def test_harness_test_on_a_full_filesystem_is_exit_4_without_traceback(tmp_path):
    import yaml

    run = yaml.safe_load((ROOT / "harness/runs/slew-rw.yaml").read_text())
    run["duration_s"] = 0.5
    run["expect"] = {"final_error": {"measure": "final_angle_error_deg", "max_abs_deg": 100}}
    run_file = tmp_path / "small.yaml"
    run_file.write_text(yaml.safe_dump(run))
    with _small_filesystem("64k") as mnt:
        proc = subprocess.run([sys.executable, "-m", "harness", "test", str(run_file), "--out",
                               str(mnt), "--workers", "1"],
                              capture_output=True, text=True, timeout=150, cwd=ROOT)
        assert proc.returncode == 4, proc.stderr
        assert "Traceback" not in proc.stderr
        assert str(mnt) in proc.stderr
