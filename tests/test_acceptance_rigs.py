"""The lab's daily check over the lab's kind of devices: `harness test acceptance` on the
CANopen rig and on the custom-DBC rig, in lockstep, ends with the verdicts it has on sgsrt
(every test PASS), and `left_safe` decodes each rig's own command frames."""

from __future__ import annotations

import json

import can
import pytest
from in_process import harness_in_process

from harness.testing.judge import left_safe_problems
from rig_models.rig_file import load_rig


@pytest.mark.slow
@pytest.mark.parametrize("rig", ["sgsrt-canopen", "sgsrt-dbc2"])
def test_acceptance_passes_on_the_labs_devices(tmp_path, rig):
    # in process (tests/in_process.py): the claim is the suite's verdicts on that rig
    out = harness_in_process("test", "acceptance", "--rig", rig, "--out", str(tmp_path),
                             "--quiet")
    assert out.returncode == 0, out.stdout[-2000:] + out.stderr[-2000:]
    (results,) = tmp_path.glob("*/results.json")
    tests = json.loads(results.read_text())["tests"]
    verdicts = {t["item"]: t["verdict"] for t in tests}
    assert verdicts == {
        "probe": "PASS", "slew-rw": "PASS", "free-decay": "PASS",
        "identify[free-decay]": "PASS", "fault-hub-silent": "PASS",
        "fault-accel-malformed": "PASS"}, verdicts
    # every run really went over that rig's frames
    for cfg in tmp_path.glob("*/*/config.yaml"):
        assert f"name: {rig}" in cfg.read_text()


def test_left_safe_decodes_a_custom_dbc(tmp_path):
    rig = load_rig("sgsrt-dbc2")
    (cmap,) = rig.binding.commands["reaction_wheel"]
    blf = tmp_path / "a.blf"
    with can.BLFWriter(str(blf)) as w:
        w.on_message_received(can.Message(
            arbitration_id=cmap.key[0], is_extended_id=True, timestamp=1.0,
            data=cmap.encode({"torque_cmd": 0.02, "enable": 1}, 3)))
    problems = left_safe_problems(blf, rig.data)
    assert any("RW_Cmd: wheel torque 0.02" in p for p in problems), problems
    assert left_safe_problems(blf, load_rig("sgsrt").data) == []  # not sgsrt's frame


def test_a_counter_wraps_at_its_signal_width():
    """The custom DBC's alive counters are 4 bits: the rig's 8-bit count wraps, it does not
    stick at the signal's maximum."""
    (tmap,) = load_rig("sgsrt-dbc2").binding.telemetry["reaction_wheel"]
    values = {"speed": 0.0, "torque": 0.0, "counter": 17}
    assert tmap.decode(tmap.encode(values))["counter"] == 1
