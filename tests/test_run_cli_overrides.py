"""`harness run`'s command-line overrides reach every variant of a run file."""

from __future__ import annotations

import yaml
from in_process import harness_in_process


def test_rig_and_duration_reach_each_variant(tmp_path):
    """Before, `harness run case-a --rig sgsrt-canopen` ran its variants on the run file's own
    rig (sgsrt) without a word: a lab's variant run on the built-in rig."""
    # in process (tests/in_process.py): the claim is the command's handling of its options
    out = harness_in_process("run", "case-a", "--variant", "beta-0.6", "--rig",
                             "sgsrt-canopen", "--duration-s", "0.2", "--quiet", "--out",
                             str(tmp_path))
    (run_dir,) = [p for p in tmp_path.iterdir() if p.is_dir()]
    config = yaml.safe_load((run_dir / "config.yaml").read_text())
    assert config["run"]["rig"] == "sgsrt-canopen", out.stderr[-2000:]
    assert config["run"]["duration_s"] == 0.2
    assert config["run"]["name"] == "case-a-beta-0.6"


def test_the_canopen_rotor_drive_reports_its_angle(tmp_path):
    """The square-wave compensation reads the rotor's angle from the bus: on sgsrt-canopen the
    rotor drive's position actual value 0x6064 carries it (before, unbound, it read 0 and case
    A's compensation ran on a constant phase)."""
    from harness.core.runs import load_run
    from harness.core.session import execute_run
    from harness.record.reader import read_scalar_channel

    run = load_run("case-a", {"rig": "sgsrt-canopen", "duration_s": 3.0})
    res = execute_run(run, out_dir=tmp_path, show_progress=False)
    _, angle = read_scalar_channel(res.run_dir / "run.rrd", "/rotor/angle_rad")
    _, speed = read_scalar_channel(res.run_dir / "run.rrd", "/rotor/speed_rad_s")
    assert speed[-1] > 1.0
    assert angle.max() > 3.0 and len(set(angle.round(3))) > 50  # it turns, and is read
