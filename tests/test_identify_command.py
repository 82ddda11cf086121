"""`harness identify` on a free-decay recording of the virtual rig (accelerometer noise on)."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
import yaml
from in_process import harness_in_process

from rig_models.rig_file import load_rig


@pytest.fixture
def free_decay(free_decay_run):
    """The session's free-decay run (tests/conftest.py)."""
    return free_decay_run


def identify_json(*args):
    # in process (tests/in_process.py); the entry point: test_identify_bad_input_exit_code
    out = harness_in_process("identify", *map(str, args), "--json")
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout)


# acceptance (rel. frequency error, rel. damping error) against the model's hub-free modes
TOLERANCE = {1: (0.005, 0.10), 2: (0.005, 0.10), 3: (0.01, 0.15)}


def test_identifies_modes_1_to_3_against_the_model(free_decay):
    cfg = yaml.safe_load((free_decay.run_dir / "config.yaml").read_text())["run"]
    assert cfg["rig_overrides"] is None
    rig = load_rig(cfg["rig"])  # the rig the run was made on
    assert rig.data["accelerometer"]["noise_rms_m_s2"] > 0  # noise on
    report = identify_json(free_decay.run_dir)
    modes = report["modes"]
    assert [m["model_mode"] for m in modes] == [1, 2, 3]
    for number, m in enumerate(modes, start=1):
        f_tol, z_tol = TOLERANCE[number]
        assert abs(m["omega_error_percent"]) < 100 * f_tol, m
        assert abs(m["damping_error_percent"]) < 100 * z_tol, m
        # and consistent with the reported 1-sigma
        assert abs(m["omega_rad_s"] - m["model_omega_rad_s"]) < 4 * m["sigma_omega_rad_s"], m
        assert abs(m["damping_ratio"] - m["model_damping_ratio"]) < 4 * m["sigma_damping"], m
    # modes 1 and 2 from the long free decay, mode 3 from the repeated short ones after its
    # own bursts (the run file's nominal 36.9 rad/s only groups those windows)
    final = len(report["windows"]) - 1
    assert modes[0]["source"]["windows"] == modes[1]["source"]["windows"] == [final]
    assert modes[2]["source"]["n_windows"] >= 4
    assert "after 36.9 rad/s bursts" in modes[2]["source"]["experiment"]
    assert all(w["end_s"] is not None for w in report["windows"][:final])
    # the FFT view of 1.9 s windows does not resolve mode 3, and the output says so
    assert modes[2]["fft_rough"] and not modes[0]["fft_rough"]
    assert any(n.startswith("mode 3") and "rough" in n for n in report["notes"])
    assert (free_decay.run_dir / "identify.rrd").stat().st_size > 0


def _final_start(free_decay) -> float:
    """Start of the long free decay after all the bursts (from the run's config.yaml)."""
    from harness.core.identify import default_start

    return default_start(yaml.safe_load((free_decay.run_dir / "config.yaml").read_text()))


def test_the_long_free_decay_alone_gives_modes_1_and_2_only(free_decay):
    start = _final_start(free_decay)
    report = identify_json(free_decay.run_dir, "--window", f"{start}:")
    assert [m["model_mode"] for m in report["modes"]] == [1, 2]
    table = harness_in_process("identify", str(free_decay.run_dir), "--n-modes", "2")
    assert table.returncode == 0, table.stderr
    assert "mode 3" not in table.stdout and "from 35" in table.stdout


def test_identify_reads_a_csv(free_decay, tmp_path):
    from harness.record.reader import read_scalar_channel

    t, a = read_scalar_channel(free_decay.run_dir / "run.rrd", "/tip/accel_m_s2")
    csv = tmp_path / "decay.csv"
    sel = t >= _final_start(free_decay)  # the long free decay only
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
