"""The lab's daily check over the lab's kind of devices: `harness test acceptance` on the
CANopen rig and on the custom-DBC rig, in lockstep, ends with the verdicts it has on sgsrt
(every test PASS), and `left_safe` decodes each rig's own command frames."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from pathlib import Path

import can
import pytest
from in_process import harness_in_process

from harness.history.db import HistoryDB
from harness.testing.judge import left_safe_problems
from rig_models.rig_file import load_rig, rig_sha256


@pytest.mark.slow
@pytest.mark.parametrize("rig", ["sgsrt-canopen", "sgsrt-dbc2"])
def test_acceptance_passes_on_the_labs_devices(tmp_path, rig):
    # in process (tests/in_process.py): the claim is the suite's verdicts on that rig
    out = harness_in_process("test", "acceptance", "--rig", rig, "--out", str(tmp_path),
                             "--quiet", "--junit", str(tmp_path / "junit.xml"))
    assert out.returncode == 0, out.stdout[-2000:] + out.stderr[-2000:]
    (results,) = tmp_path.glob("*/results.json")
    tests = json.loads(results.read_text())["tests"]
    verdicts = {t["item"]: t["verdict"] for t in tests}
    assert verdicts == {
        "probe": "PASS", "slew-rw": "PASS", "free-decay": "PASS",
        "identify[free-decay]": "PASS", "fault-hub-silent": "PASS",
        "fault-accel-malformed": "PASS", "sequence-valve-fault": "PASS"}, verdicts
    # every run really went over that rig's frames
    for cfg in tmp_path.glob("*/*/config.yaml"):
        assert f"name: {rig}" in cfg.read_text()
    check_names_its_rig(tmp_path, results, rig)


def check_names_its_rig(out: Path, results: Path, rig: str) -> None:
    """Every output of the suite names the rig it ran on, with its hash."""
    sha = rig_sha256(load_rig(rig).data)
    doc = json.loads(results.read_text())
    assert [(r["rig"], r["rig_sha256"]) for r in doc["rigs"]] == [(rig, sha)]
    assert all(t["rig"]["rig"] == rig for t in doc["tests"])
    head = f"rig {rig} (sha256 {sha[:12]})"
    for report in ("report.md", "report.html"):
        text = (results.parent / report).read_text()
        assert f"on {rig}" in text.splitlines()[0] + text[:400] and head in text, report
    suite_props = {p.get("name"): p.get("value") for p in
                   ET.parse(out / "junit.xml").getroot().find("testsuite/properties")}
    assert suite_props["rig"] == rig and suite_props["rig_sha256"] == sha
    for run_dir in results.parent.glob("*/summary.json"):
        summary = json.loads(run_dir.read_text())
        assert summary["rig"] == rig and summary["bus"].endswith(f"-{rig}")
        verdict = json.loads((run_dir.parent / "verdict.json").read_text())
        assert verdict["identity"]["rig"] == rig
        assert verdict["identity"]["rig_sha256"] == summary["rig_sha256"]
    with HistoryDB(str(out / "history.sqlite")) as db:
        assert {r["rig"] for r in db.records()} == {rig}


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
