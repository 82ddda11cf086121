"""Device files as vendors ship them: identity from ``[DeviceInfo]`` or a DCF when 0x1018 has
no defaults (the error names the rig file's key that overrides it), the harness's own NMT
frames logged as transmitted."""

from __future__ import annotations

import os
import re
import time
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


# ----------------------------------------------------------------------------- bounded
def _drop_objects(text: str, *indices: int) -> str:
    """An EDS text without the objects ``indices`` (their sections and sub-sections)."""
    for index in indices:
        text = re.sub(rf"^\[{index:04X}(sub[0-9A-Fa-f]+)?\][^\[]*", "", text,
                      flags=re.M | re.I)
    return text


def _wheel_text() -> str:
    return Path(CO_RIG.binding.files["reaction_wheel"]).read_text()


def _refused(data: dict, match: str) -> None:
    from rig_models.schema import ConfigError

    with pytest.raises(ConfigError, match=match):
        rig_from_dict(data, "rig file x.yaml", base_dir=RIGS_DIR)


def test_a_fifo_as_eds_dbc_or_rig_base_is_refused_at_once(tmp_path):
    fifo = tmp_path / "wheel.eds"
    os.mkfifo(fifo)
    data = _co_data()
    data["devices"]["reaction_wheel"]["eds"] = str(fifo)
    _refused(data, r"devices\.reaction_wheel\.eds: wheel\.eds: a FIFO, not a regular file")
    (tmp_path / "base.yaml").unlink(missing_ok=True)
    os.mkfifo(tmp_path / "base.yaml")
    rig = tmp_path / "rig.yaml"
    rig.write_text("extends: base.yaml\nname: x\n")
    from rig_models.schema import ConfigError

    with pytest.raises(ConfigError, match=r"base\.yaml: .*not a regular file"):
        load_rig(rig)
    from drivers.dbc import DbcError, load_protocol

    os.mkfifo(tmp_path / "bus.dbc")
    with pytest.raises(DbcError, match=r"bus\.dbc: a FIFO, not a regular file"):
        load_protocol(tmp_path / "bus.dbc")


def test_a_40_mb_eds_and_dbc_are_refused_fast(tmp_path):
    big = tmp_path / "big.eds"
    with open(big, "wb") as f:
        f.write(_wheel_text().encode())
        f.truncate(40 * 2**20)
    data = _co_data()
    data["devices"]["reaction_wheel"]["eds"] = str(big)
    t0 = time.monotonic()
    _refused(data, r"devices\.reaction_wheel\.eds.*big\.eds: 40\.0 MiB, more than the 4 MiB")
    big_dbc = tmp_path / "big.dbc"
    with open(big_dbc, "wb") as f:
        f.truncate(40 * 2**20)
    from drivers.dbc import DbcError, load_protocol

    with pytest.raises(DbcError, match=r"big\.dbc: 40\.0 MiB"):
        load_protocol(big_dbc)
    assert time.monotonic() - t0 < 2.0


def test_a_very_long_eds_path_is_one_line(tmp_path):
    data = _co_data()
    data["devices"]["reaction_wheel"]["eds"] = "/tmp/" + "x" * 5000 + ".eds"
    _refused(data, r"^rig file x\.yaml: devices\.reaction_wheel\.eds: the path is too long "
                   r"for the file system \(5009 characters\)$")
    data["devices"]["reaction_wheel"]["eds"] = "/tmp/" + "d/" * 3000 + "w.eds"
    _refused(data, r"devices\.reaction_wheel\.eds: ")


@pytest.mark.parametrize("top, kind", [("- a\n- b\n", "a list"), ("42\n", "an? int"),
                                       ("just text\n", "a str")])
def test_an_extends_base_whose_top_is_not_a_mapping_is_refused(tmp_path, top, kind):
    from rig_models.schema import ConfigError

    (tmp_path / "base.yaml").write_text(top)
    rig = tmp_path / "rig.yaml"
    rig.write_text("extends: base.yaml\nname: x\n")
    with pytest.raises(ConfigError, match=rf"^rig file rig\.yaml: extends: base\.yaml: its top "
                                          rf"level is {kind}"):
        load_rig(rig)


def test_an_eds_default_mapping_over_64_bits_is_the_masters_to_rewrite(tmp_path):
    """The wheel drive's EDS with a default TPDO1 of 96 bits: the master maps its own PDOs
    during set-up, so the emulated device of that file runs; a DCF (whose mapping is taken
    as it is) is refused naming the key (test_binding_canopen)."""
    text = _wheel_text()
    text = _edit(text, "1A00sub0", "DefaultValue", "0x4")
    text = _edit(text, "1A00sub3", "DefaultValue", "0x606C0020")
    eds = tmp_path / "wide.eds"
    eds.write_text(text)
    data = _co_data()
    data["devices"]["reaction_wheel"]["eds"] = str(eds)
    run = run_from_dict(dict(RUN, bus=f"virtual:{_channel()}",
                             rig=str(_rig_file(tmp_path, data))))
    result = execute_run(run, out_dir=tmp_path / "logs", show_progress=False)
    assert result.summary["stopped_by"] == "completed", result.summary.get("faults")


# ----------------------------------------------------------------------------- DBC
DBC_HEAD = 'VERSION ""\nNS_ :\nBS_:\nBU_: RIG HARNESS\n'


def _dbc_rig(tmp_path: Path, extra: str) -> dict:
    """The sgsrt rig with its hub sensor on a DBC of ours that has ``extra`` messages."""
    dbc = tmp_path / "lab.dbc"
    dbc.write_text(DBC_HEAD + 'BO_ 512 HUB: 8 RIG\n'
                   ' SG_ angle : 0|32@1- (1e-07,0) [-214|214] "rad" HARNESS\n'
                   ' SG_ rate : 32|32@1- (1e-07,0) [-214|214] "rad/s" HARNESS\n' + extra)
    data = yaml.safe_load(yaml.safe_dump(load_rig("sgsrt").data))
    data["devices"] = {"hub_sensor": {"binding": "dbc", "dbc": str(dbc), "telemetry": {
        "angle": {"message": "HUB", "signal": "angle"},
        "rate": {"message": "HUB", "signal": "rate"}}}}
    return data


OVERLAP = ('BO_ 1792 RADIO: 2 RIG\n SG_ a : 0|16@1+ (1,0) [0|0] "" HARNESS\n'
           ' SG_ b : 8|8@1+ (1,0) [0|0] "" HARNESS\n')


def test_a_problem_in_an_unbound_dbc_message_is_a_warning_naming_it(tmp_path):
    data = _dbc_rig(tmp_path, OVERLAP + 'BO_ 1793 DOOR: 1 RIG\n'
                    ' SG_ open : 0|1@1+ (1,0) [0|1] "" HARNESS\nVAL_ 1793 gone 0 "x" ;\n')
    rig = rig_from_dict(data, "rig file x.yaml", base_dir=RIGS_DIR)
    assert len(rig.binding.warnings) == 2
    door = next(w for w in rig.binding.warnings if "DOOR" in w)
    assert "VAL_ entry for a signal it lacks (gone)" in door
    radio = next(w for w in rig.binding.warnings if "RADIO" in w)
    assert radio.startswith("lab.dbc: message RADIO: ") and "overlap" in radio
    assert "not bound by this rig" in radio
    # the same DBC loads strictly in cantools only without those lines: it is a real fault
    import cantools

    with pytest.raises(Exception, match="overlap|VAL_"):
        cantools.database.load_file(str(tmp_path / "lab.dbc"), strict=True)


def test_a_bound_dbc_message_must_be_exact(tmp_path):
    data = _dbc_rig(tmp_path, OVERLAP)
    data["devices"]["hub_sensor"]["telemetry"]["rate"] = {"message": "RADIO", "signal": "b"}
    _refused(data, r"devices\.hub_sensor\.telemetry\.rate\.message: RADIO of lab\.dbc is not "
                   r"exact: .*overlap")


# ----------------------------------------------------------------------------- emulation
def _rig_with(tmp_path: Path, device: str, text: str, **cfg: object) -> dict:
    eds = tmp_path / f"{device}.eds"
    eds.write_text(text)
    data = _co_data()
    data["devices"][device]["eds"] = str(eds)
    data["devices"][device].update(cfg)
    return data


def test_optional_profile_objects_stay_optional(tmp_path):
    """A drive without 0x603F, 0x6072, 0x6007, 0x6502, 0x6060/0x6061 and an I/O module
    without its error mode / value objects: the virtual rig is such devices and the run
    completes (a drive without 0x6061 runs its one mode, the master reads no display)."""
    wheel = _drop_objects(_wheel_text(), 0x603F, 0x6072, 0x6007, 0x6502, 0x6060, 0x6061)
    data = _rig_with(tmp_path, "reaction_wheel", wheel)
    io = Path(CO_RIG.binding.files["thruster_valves"]).read_text()
    io_eds = tmp_path / "io.eds"
    io_eds.write_text(_drop_objects(io, 0x6206, 0x6207, 0x6443, 0x6444))
    for d in ("thruster_valves", "piezo_amplifier", "accelerometer"):
        data["devices"][d]["eds"] = str(io_eds)
    run = run_from_dict(dict(RUN, bus=f"virtual:{_channel()}",
                             rig=str(_rig_file(tmp_path, data))))
    result = execute_run(run, out_dir=tmp_path / "logs", show_progress=False)
    assert result.summary["stopped_by"] == "completed", result.summary.get("faults")
    assert abs(result.summary["final_angle_error_deg"]) < 1.5


def test_what_the_virtual_rig_cannot_be_is_refused_before_the_run(tmp_path):
    # a drive without its mode's target object (CST needs 0x6071): the binding's torque
    # command moves to 0x60FF so the harness side is fine, the emulation is not
    wheel = _drop_objects(_wheel_text(), 0x6071)
    text = _edit(_edit(wheel, "60FF", "PDOMapping", "1"), "6502", "DefaultValue", "0x300")
    data = _rig_with(tmp_path, "reaction_wheel", text)
    data["devices"]["reaction_wheel"]["commands"]["torque_cmd"] = {"object": 0x60FF,
                                                                   "scale": 6.5e-5}
    rig_file = _rig_file(tmp_path, data)
    run = run_from_dict(dict(RUN, bus=f"virtual:{_channel()}", rig=str(rig_file)))
    with pytest.raises(RunRefused, match=r"^devices\.reaction_wheel\.profile: the virtual rig "
                                         r"cannot emulate reaction_wheel\.eds as cia402: .*"
                                         r"lacks 0x6071:00$"):
        execute_run(run, out_dir=tmp_path / "logs", show_progress=False)
    assert not (tmp_path / "logs").exists() or not any((tmp_path / "logs").iterdir())
    # the command line: exit 2, one line, no traceback
    import subprocess
    import sys

    run_file = tmp_path / "run.yaml"
    run_file.write_text(yaml.safe_dump(dict(RUN, rig=str(rig_file))))
    out = subprocess.run([sys.executable, "-m", "harness", "run", str(run_file), "--bus",
                          f"virtual:{_channel()}", "--out", str(tmp_path / "cli"), "--quiet"],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 2, out.stderr
    assert "Traceback" not in out.stderr
    assert "devices.reaction_wheel.profile" in out.stderr and "0x6071" in out.stderr


def test_a_drive_whose_supported_modes_lack_the_mode_is_refused(tmp_path):
    text = _edit(_wheel_text(), "6502", "DefaultValue", "0x100")  # CSV only
    data = _rig_with(tmp_path, "reaction_wheel", text)
    _refused(data, r"devices\.reaction_wheel\.mode_of_operation: 10 \(cyclic synchronous "
                   r"torque\) is not among reaction_wheel\.eds's supported drive modes "
                   r"\(0x6502 = 0x100: 9 cyclic synchronous velocity\)")


def test_a_node_without_a_heartbeat_consumer_by_the_rig_file(tmp_path):
    """A device whose 0x1016 cannot take the harness's heartbeat: the set-up error names
    the key; with ``heartbeat_consumer: false`` 0x1016 is left alone and the run goes."""
    text = _edit(_wheel_text(), "1016sub1", "HighLimit", "0x0000FFFF")  # no producer id
    data = _rig_with(tmp_path, "reaction_wheel", text)
    run = run_from_dict(dict(RUN, bus=f"virtual:{_channel()}",
                             rig=str(_rig_file(tmp_path, data))))
    with pytest.raises(RunRefused, match=r"writing 0x1016\.1 \(heartbeat consumer\): SDO "
                                         r"abort 0x06090031.*set devices\.reaction_wheel\."
                                         r"heartbeat_consumer: false"):
        execute_run(run, out_dir=tmp_path / "logs", show_progress=False)
    data["devices"]["reaction_wheel"]["heartbeat_consumer"] = False
    run = run_from_dict(dict(RUN, bus=f"virtual:{_channel()}",
                             rig=str(_rig_file(tmp_path, data))))
    result = execute_run(run, out_dir=tmp_path / "logs", show_progress=False)
    assert result.summary["stopped_by"] == "completed", result.summary.get("faults")
    writes = [m for m in can.BLFReader(str(result.run_dir / "can.blf"))
              if m.arbitration_id == 0x602 and m.data[0] & 0xE0 == 0x20
              and m.data[1:3] == bytes((0x16, 0x10))]
    assert writes == []


def test_the_unbound_problems_are_shown_before_the_run(tmp_path, capsys):
    data = _dbc_rig(tmp_path, OVERLAP)
    run = run_from_dict(dict(RUN, actuators=["reaction_wheel"], bus=f"virtual:{_channel()}",
                             rig=str(_rig_file(tmp_path, data)), duration_s=0.1))
    result = execute_run(run, out_dir=tmp_path / "logs", show_progress=True)
    assert result.summary["stopped_by"] == "completed"
    err = capsys.readouterr().err
    assert "harness: warning: lab.dbc: message RADIO: " in err
