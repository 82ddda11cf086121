"""Device files as vendors ship them: identity from ``[DeviceInfo]`` or a DCF when 0x1018 has
no defaults (the error names the rig file's key that overrides it), the harness's own NMT
frames logged as transmitted."""

from __future__ import annotations

import re
import uuid
from pathlib import Path

import can
import pytest
import yaml

from harness.core.runs import run_from_dict
from harness.core.session import RunRefused, execute_run
from rig_models.rig_file import RIGS_DIR, load_rig, rig_from_dict

CO_RIG = load_rig("sgsrt-canopen")
RUN = {"name": "co", "rig": "sgsrt-canopen", "clock": "lockstep", "rate_hz": 500,
       "duration_s": 0.3, "actuators": ["reaction_wheel"],
       "controller": {"type": "pd_wheel", "angle_deg": 1.0, "start_s": 0.1}}


def _co_data() -> dict:
    return yaml.safe_load(yaml.safe_dump(CO_RIG.data))


def _channel() -> str:
    return f"files-{uuid.uuid4().hex[:10]}-test"


def _edit(text: str, section: str, key: str, value: str) -> str:
    """``key=value`` in ``[section]`` of an EDS text (replaced, or added if absent)."""
    head = f"[{section}]"
    i = text.index(head)
    end = text.find("\n[", i + 1)
    end = len(text) if end < 0 else end
    block = text[i:end]
    pattern = re.compile(rf"^{key}=.*$", re.M)
    if pattern.search(block):
        block = pattern.sub(f"{key}={value}", block)
    else:
        block = block.rstrip("\r\n") + f"\r\n{key}={value}\r\n"
    return text[:i] + block + text[end:]


def _vendor_style_wheel(path: Path) -> Path:
    """The wheel drive's EDS as vendors often write one: 0x1018's vendor id and product code
    without defaults, the device named in [DeviceInfo] only."""
    text = Path(CO_RIG.binding.files["reaction_wheel"]).read_text()
    text = _edit(text, "1018sub1", "DefaultValue", "")
    text = _edit(text, "1018sub2", "DefaultValue", "")
    text = _edit(text, "DeviceInfo", "VendorNumber", "0x000004D5")
    text = _edit(text, "DeviceInfo", "ProductNumber", "0x00000042")
    path.write_text(text)
    return path


def _rig_file(tmp_path: Path, data: dict) -> Path:
    path = tmp_path / "rig.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def test_identity_comes_from_device_info_when_0x1018_has_no_defaults(tmp_path):
    eds = _vendor_style_wheel(tmp_path / "wheel.eds")
    data = _co_data()
    data["devices"]["reaction_wheel"]["eds"] = str(eds)
    node = rig_from_dict(data, "rig file x.yaml", base_dir=RIGS_DIR).binding.canopen.nodes[2]
    assert node.identity == {"vendor_id": 0x4D5, "product_code": 0x42}
    assert "[DeviceInfo] VendorNumber" in node.identity_source["vendor_id"]
    # the emulated device of that file reports the identity its file names; the run goes
    run = run_from_dict(dict(RUN, bus=f"virtual:{_channel()}",
                             rig=str(_rig_file(tmp_path, data))))
    result = execute_run(run, out_dir=tmp_path / "logs", show_progress=False)
    assert result.summary["stopped_by"] == "completed", result.summary.get("faults")


def test_a_dcf_value_is_the_expected_identity_and_the_error_names_the_key(tmp_path):
    text = _vendor_style_wheel(tmp_path / "w.eds").read_text()
    text = _edit(text, "1018sub2", "ParameterValue", "0x00000043")  # a DCF's configured value
    dcf = tmp_path / "wheel_as_configured.dcf"
    dcf.write_text(text)
    harness = _co_data()
    harness["devices"]["reaction_wheel"]["eds"] = str(dcf)
    node = rig_from_dict(harness, "rig file x.yaml",
                         base_dir=RIGS_DIR).binding.canopen.nodes[2]
    assert node.identity["product_code"] == 0x43
    # the device on the bus is the plain vendor EDS (product 0x42): refused before the run,
    # the message says which key would accept it
    device = _co_data()
    device["devices"]["reaction_wheel"]["eds"] = str(tmp_path / "w.eds")
    from drivers.binding.canopen_master import CanopenMaster, SetupError
    from rig_models.virtual_rig import VirtualRig

    ch = _channel()
    buses = [can.Bus(interface="virtual", channel=ch) for _ in range(2)]
    try:
        rig = VirtualRig(rig_from_dict(device, "rig file d.yaml", base_dir=RIGS_DIR),
                         buses[1], 0.002)
        harness_rig = rig_from_dict(harness, "rig file x.yaml", base_dir=RIGS_DIR)
        with pytest.raises(SetupError, match=r"identity product_code \(0x1018\.2\) is "
                                             r"0x00000042 on the device, "
                                             r"wheel_as_configured\.dcf's configured 0x1018\.2 "
                                             r"\(ParameterValue\) expects 0x00000043; .* set "
                                             r"devices\.reaction_wheel\.identity\.product_code: "
                                             r"0x00000042 in the rig file"):
            CanopenMaster(buses[0], harness_rig.binding.canopen).setup(pump=rig.service)
    finally:
        for b in buses:
            b.shutdown()


def test_the_rig_file_identity_overrides_the_file_and_is_named(tmp_path):
    data = _co_data()
    data["devices"]["reaction_wheel"]["identity"] = {"vendor_id": 0x1234}
    run = run_from_dict(dict(RUN, bus=f"virtual:{_channel()}",
                             rig=str(_rig_file(tmp_path, data))))
    with pytest.raises(RunRefused, match=r"is 0x53475254 on the device, the rig file's "
                                         r"devices\.reaction_wheel\.identity\.vendor_id "
                                         r"expects 0x00001234"):
        execute_run(run, out_dir=tmp_path / "logs", show_progress=False)


def test_the_harness_nmt_frames_are_logged_as_transmitted(tmp_path):
    run = run_from_dict(dict(RUN, bus=f"virtual:{_channel()}"))
    result = execute_run(run, out_dir=tmp_path, show_progress=False)
    nmt = [m for m in can.BLFReader(str(result.run_dir / "can.blf"))
           if m.arbitration_id == 0 and not m.is_extended_id]
    # reset communication and start at set-up, pre-operational at the end
    assert [bytes(m.data[:1]) for m in nmt] == [b"\x82", b"\x01", b"\x80"]
    assert all(not m.is_rx for m in nmt)
    boot_ups = [m for m in can.BLFReader(str(result.run_dir / "can.blf"))
                if m.arbitration_id == 0x702]
    assert boot_ups and all(m.is_rx for m in boot_ups)
