"""`harness identify` on a free-decay recording of the virtual rig (accelerometer noise on)."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from harness.runs import load_run
from harness.session import execute_run


@pytest.fixture(scope="module")
def free_decay(tmp_path_factory):
    out = tmp_path_factory.mktemp("fd")
    res = execute_run(load_run("free-decay"), out_dir=out, show_progress=False)
    assert res.run_dir.exists()
    return res


def identify_json(*args):
    out = subprocess.run([sys.executable, "-m", "harness", "identify", *map(str, args),
                          "--json"], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout)


def test_identifies_modes_1_and_2_against_the_model(free_decay):
    rig = free_decay.virtual_rig.rig
    assert rig.data["accelerometer"]["noise_rms_m_s2"] > 0  # noise on
    report = identify_json(free_decay.run_dir)
    modes = report["modes"]
    assert len(modes) == 2
    for m in modes:
        assert abs(m["omega_error_percent"]) < 0.5, m
        assert abs(m["damping_error_percent"]) < 10.0, m
    assert (free_decay.run_dir / "identify.rrd").stat().st_size > 0


def test_identify_reads_a_csv(free_decay, tmp_path):
    from harness.recording_reader import read_scalar_channel

    t, a = read_scalar_channel(free_decay.run_dir / "run.rrd", "/tip/accel_m_s2")
    csv = tmp_path / "decay.csv"
    sel = t >= 8.8
    np.savetxt(csv, np.column_stack([t[sel], a[sel]]), delimiter=",",
               header="time_s,accel_m_s2", comments="")
    report = identify_json(csv)
    assert report["modes"][0]["omega_rad_s"] == pytest.approx(2.88, rel=0.01)


def test_identify_bad_input_exit_code(tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("t,a\n0,1\n0.1,x\n")
    out = subprocess.run([sys.executable, "-m", "harness", "identify", str(bad)],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 2 and "line" in out.stderr
