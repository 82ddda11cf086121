"""The harness on the rig as it is: the as-built devices (bearing friction with breakaway,
a slower torque loop, sensor biases, hub inertia and modes off the file, a quarter of the
file's damping, weaker valves; rig_models/rigs/sgsrt-as-built.yaml) played against the
ideal rig files, wired right. No run stops for a fault and no check calls the rig
mis-wired; what the real rig cannot meet (the modes and damping the file states) fails as
the criterion that states it (docs/as_built.md)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from in_process import harness_in_process

from harness.core.runs import load_run
from harness.core.session import execute_run
from rig_models.rig_file import load_rig


@pytest.mark.parametrize("rig", ["sgsrt", "sgsrt-canopen", "sgsrt-dbc2"])
@pytest.mark.parametrize("case", ["slew-rw", "slew-thruster-hllh"])
def test_a_plain_run_on_the_as_built_devices_raises_no_fault(tmp_path, rig, case):
    """On the CANopen rig the PD's hold before the slew commands about 0.3 mN m, below the
    bearing's 0.8 mN m breakaway: the wheel rightly stays still, and the monitor's wheel
    check must allow the friction the file tolerates (tolerances.wheel_friction_n_m)."""
    run = load_run(case, {"rig": rig, "duration_s": 12.0})
    s = execute_run(run, out_dir=tmp_path, show_progress=False,
                    device_rig=load_rig(f"{rig}-as-built")).summary
    assert s["stopped_by"] == "completed", s["faults"]


def test_without_the_friction_tolerance_the_wheel_at_breakaway_is_called_implausible(
        tmp_path):
    """The control case: the same CANopen run with the file allowing no unmodelled friction
    stops at the first window (what the monitor did before it knew of friction)."""
    raw = load_rig("sgsrt-canopen").data
    rig = tmp_path / "no-friction.yaml"
    rig.write_text(json.dumps({"extends": "sgsrt-canopen", "name": "no-friction",
                               "tolerances": {"wheel_friction_n_m": 0.0}}))
    assert raw["tolerances"]["wheel_friction_n_m"] > 0.0
    run = load_run("slew-rw", {"rig": str(rig), "duration_s": 3.0})
    s = execute_run(run, out_dir=tmp_path, show_progress=False,
                    device_rig=load_rig("sgsrt-canopen-as-built")).summary
    assert s["stopped_by"] == "fault"
    assert s["faults"][0]["device"] == "reaction_wheel", s["faults"]


@pytest.mark.slow
def test_acceptance_on_the_as_built_devices_fails_only_where_the_file_is_wrong(tmp_path: Path):
    """The lab's daily check against the ideal file, on the rig as built: the slew and the
    fault tests pass (the residual vibration is judged about its mean: the accelerometer's
    bias is no vibration); the free decay's identified modes are not the file's, and that
    criterion says so."""
    out = harness_in_process("test", "acceptance", "--devices-rig", "sgsrt-as-built",
                             "--out", str(tmp_path), "--quiet")
    (results,) = tmp_path.glob("*/results.json")
    tests = json.loads(results.read_text())["tests"]
    verdicts = {t["item"]: t["verdict"] for t in tests}
    assert verdicts == {
        "probe": "PASS", "slew-rw": "PASS", "free-decay": "PASS",
        "identify[free-decay]": "FAIL", "fault-hub-silent": "PASS",
        "fault-accel-malformed": "PASS", "sequence-valve-fault": "PASS"}, (
        verdicts, out.stdout[-3000:])
    (ident,) = [t for t in tests if t["item"] == "identify[free-decay]"]
    failed = {c["name"] for c in ident.get("criteria", []) if c["verdict"] == "FAIL"}
    assert failed == {"frequencies", "damping"}, ident


def test_the_twin_is_the_files_model_never_its_as_built_overlay():
    """The twin measures the rig against its model: on sgsrt-as-built it must run the
    model's inertia (15 kg m^2), not the overlay's 15.6 that the virtual rig emulates."""
    from harness.history.twin import TwinModel

    rig = load_rig("sgsrt-as-built")
    twin = TwinModel(rig.data, 0.002)
    assert twin.rig.rig.data["hub"]["inertia_kg_m2"] == 15.0
    assert rig.as_built_rig().data["hub"]["inertia_kg_m2"] == 15.6
