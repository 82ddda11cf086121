"""A virtual rig process that does not start refuses the run: exit 2 with one line
carrying what the process said (rig.log's diagnosis), and no run folder left behind, which
``harness logs --failed`` would list as a run killed on the way."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

import harness.bus.rig_process as rig_process
from harness.cli import main
from harness.core.runs import load_run
from harness.core.session import RunRefused, execute_run

SAID = "harness: rig file rig.yaml: reaction_wheel.max_torque_n_m: a stand-in refusal"


def _fake_python(tmp: Path, body: str) -> Path:
    """What the run starts as ``sys.executable -m harness virtual-rig ...``: a rig process
    that fails as the test says (only the child sees it; the run file is valid)."""
    exe = tmp / "fake-python"
    exe.write_text(f"#!/bin/sh\n{body}\n")
    exe.chmod(0o755)
    return exe


@pytest.fixture
def exiting_rig(tmp_path, monkeypatch):
    exe = _fake_python(tmp_path, f"echo 'Traceback (most recent call last):' >&2\n"
                                 f"echo '  a frame' >&2\necho '{SAID}' >&2\nexit 2")
    monkeypatch.setattr(sys, "executable", str(exe))


def _run_rig_process(out: Path) -> None:
    execute_run(load_run("slew-rw", {"duration_s": 1.0}), out_dir=out, clock="realtime",
                rig_process=True, show_progress=False)


def test_a_rig_process_that_exits_refuses_the_run_leaving_no_folder(tmp_path, exiting_rig):
    out = tmp_path / "logs"
    out.mkdir()
    with pytest.raises(RunRefused) as info:
        _run_rig_process(out)
    msg = str(info.value)
    assert "exited (2) before serving" in msg and SAID in msg, msg
    assert "rig.log" not in msg  # it went with the folder: its words are in the message
    assert list(out.iterdir()) == []


def test_harness_run_exits_2_with_one_line_and_logs_lists_nothing(tmp_path, exiting_rig,
                                                                  capsys):
    out = tmp_path / "logs"
    code = main(["run", "slew-rw", "--clock", "realtime", "--rig-process", "--duration-s", "1",
                 "--quiet", "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2, err
    [line] = [ln for ln in err.splitlines() if SAID in ln]
    assert line.startswith("harness: ") and "Traceback" not in err
    assert not [p for p in out.iterdir() if p.is_dir()]
    main(["logs", "--logs", str(out), "--failed"])
    assert "no run directories" in capsys.readouterr().err


def test_a_rig_process_that_never_serves_refuses_the_run_in_bounded_time(tmp_path,
                                                                         monkeypatch):
    exe = _fake_python(tmp_path, "echo 'harness virtual-rig: loading' >&2\nexec sleep 30")
    monkeypatch.setattr(sys, "executable", str(exe))
    monkeypatch.setattr(rig_process, "START_TIMEOUT_S", 1.0)
    out = tmp_path / "logs"
    out.mkdir()
    with pytest.raises(RunRefused, match="did not start within 1 s; it said: harness "
                                         "virtual-rig: loading"):
        _run_rig_process(out)
    assert list(out.iterdir()) == []
