"""Device files no one on this project wrote, as their vendors and projects publish them
(tests/data/third_party/README.md names each file's source, commit and licence; the files
are fetched, not committed: a test whose file is absent is skipped).

Each file binds and runs on the virtual rig in a short lockstep run, or is refused before
the run naming the file's own limitation; the `canopen` library (PDOs) or cantools (DBC
messages) decodes each recording as the harness recorded it; the harness's CANopen master
sets up an independent slave, the `canopen` library's LocalNode, built from each EDS."""

from __future__ import annotations

import struct
import threading
import time
import uuid
from pathlib import Path

import can
import canopen
import cantools
import numpy as np
import pytest
import yaml

from harness.core.runs import run_from_dict
from harness.core.session import execute_run
from harness.record.reader import read_scalar_channel
from rig_models.rig_file import RIGS_DIR, load_rig, rig_from_dict
from rig_models.schema import ConfigError

TP = Path(__file__).parent / "data" / "third_party"
RUN = {"name": "tp", "clock": "lockstep", "rate_hz": 500, "duration_s": 0.4,
       "actuators": ["reaction_wheel"],
       "controller": {"type": "pd_wheel", "angle_deg": 1.0, "start_s": 0.1}}


def _file(rel: str) -> Path:
    p = TP / rel.split("#")[0]
    if not p.is_file():
        pytest.skip(f"{rel}: not here (tests/data/third_party/README.md says where it is from)")
    return p


def _channel() -> str:
    return f"tp-{uuid.uuid4().hex[:10]}-test"


def _co_data() -> dict:
    return yaml.safe_load(yaml.safe_dump(load_rig("sgsrt-canopen").data))


def _run(tmp_path: Path, data: dict, **over: object):  # noqa: ANN202
    rig_file = tmp_path / "rig.yaml"
    rig_file.write_text(yaml.safe_dump(data))
    run = run_from_dict(dict(RUN, bus=f"virtual:{_channel()}", rig=str(rig_file), **over))
    return execute_run(run, out_dir=tmp_path / "logs", show_progress=False)


WHEEL = {"binding": "canopen", "node_id": 2, "profile": "cia402", "mode_of_operation": 10,
         "telemetry": {"speed": {"object": 0x606C, "scale": 0.001},
                       "torque": {"object": 0x6077, "scale": 6.5e-5},
                       "enabled": {"object": 0x6041, "mask": 0x6F, "equals": 0x27},
                       "fault": {"object": 0x6041, "bit": 3}},
         "commands": {"torque_cmd": {"object": 0x6071, "scale": 6.5e-5},
                      "enable": {"object": 0x6040, "values": {0: 0x06, 1: 0x0F}}}}
ROTOR = {"binding": "canopen", "node_id": 5, "profile": "cia402", "mode_of_operation": 9,
         "telemetry": {"speed": {"object": 0x606C, "scale": 0.001}},
         "commands": {"speed_cmd": {"object": 0x60FF, "scale": 0.001}}}


def _wheel_rig(eds: Path) -> dict:
    data = _co_data()
    data["devices"]["reaction_wheel"] = dict(WHEEL, eds=str(eds))
    return data


def _io_rig(eds: Path) -> dict:
    data = _co_data()
    for d in ("thruster_valves", "piezo_amplifier", "accelerometer"):
        data["devices"][d]["eds"] = str(eds)
    return data


def _sample_io_rig(eds: Path) -> dict:
    """canopen's sample device as the accelerometer's input: its INTEGER16 0x2001."""
    data = _co_data()
    data["devices"]["accelerometer"] = {
        "binding": "canopen", "node_id": 6, "eds": str(eds), "profile": "cia401",
        "telemetry": {"accel": {"object": 0x2001, "scale": 1.52587890625e-3}}}
    return data


def _rotor_rig(eds: Path) -> dict:
    data = _co_data()
    data["devices"]["disturbance_rotor"] = dict(ROTOR, eds=str(eds))
    return data


def _pv_rotor_rig(eds: Path) -> dict:
    data = _rotor_rig(eds)
    data["devices"]["disturbance_rotor"]["mode_of_operation"] = 3  # profile velocity
    return data


# file -> (rig builder, the device whose TPDOs are checked, None or the refusal's text)
CANOPEN_CASES = {
    # Technosoft iPOS servo drive (vendor EDS): profile velocity for the rotor
    "eds/technosoft_ipos.eds": (_pv_rotor_rig, "disturbance_rotor", None),
    # Technosoft IDM/ISCM as configured for a ROS test (vendor DCF, taken as it is): its
    # TPDOs carry the status word and mode only, not the velocity the rotor reports
    "eds/technosoft_ISD860.dcf": (
        _pv_rotor_rig, "disturbance_rotor",
        r"devices\.disturbance_rotor\.telemetry\.speed: 0x606C\.0 is in no TPDO of "
        r"technosoft_ISD860\.dcf's mapping"),
    # the same device's EDS: the harness maps its own PDOs
    "eds/technosoft_ISD860.eds": (_pv_rotor_rig, "disturbance_rotor", None),
    # Pilz servo drive (vendor EDS): profile position, velocity and interpolated position
    # only, no profile or cyclic velocity (0x6502 = 0x43)
    "eds/pilz.eds": (
        _pv_rotor_rig, "disturbance_rotor",
        r"devices\.disturbance_rotor\.mode_of_operation: 3 \(profile velocity\) is not among "
        r"pilz\.eds's supported drive modes \(0x6502 = 0x43: 1 profile position, 2 velocity, "
        r"7 interpolated position\)"),
    # a drive example shipped with the canopen library (CST; no 0x1016: no consumer)
    "eds/canopen_python_e35.eds": (_wheel_rig, "reaction_wheel", None),
    # ROS-Industrial's CiA 402 test drive, in profile velocity
    "eds/ros2_canopen_cia402_slave.eds": (_pv_rotor_rig, "disturbance_rotor", None),
    # ... whose modes lack cyclic synchronous velocity (0x6502 = 0xA5)
    "eds/ros2_canopen_cia402_slave.eds#csv": (
        _rotor_rig, "disturbance_rotor",
        r"devices\.disturbance_rotor\.mode_of_operation: 9 \(cyclic synchronous velocity\) "
        r"is not among ros2_canopen_cia402_slave\.eds's supported drive modes "
        r"\(0x6502 = 0xA5: 1 profile position, 3 profile velocity, 6 homing, "
        r"8 cyclic synchronous position\)"),
    # CANopenNode's CiA 401 I/O example device ([Comments] count wrong, empty identity)
    "eds/CANopenNode_IO.eds": (_io_rig, "accelerometer", None),
    # the canopen library's test device: its INTEGER16 as an analog input
    "eds/canopen_python_sample.eds": (_sample_io_rig, "accelerometer", None),
    # CANopenNode's bare CiA 301 profile: no application object at all
    "eds/CANopenNode_DS301_profile.eds": (
        _io_rig, "accelerometer",
        r"devices\.accelerometer\.telemetry\.accel\.object: 0x6401 is not in "
        r"CANopenNode_DS301_profile\.eds"),
}


def _decoded_by_canopen(blf: Path, eds: Path, node_id: int, pdo) -> list[list[float]]:  # noqa: ANN001
    """Every frame of the binding's TPDO ``pdo`` in the recording, decoded by the canopen
    library's own PDO map over the EDS (raw values, one list per frame)."""
    node = canopen.RemoteNode(node_id, canopen.import_od(
        *_od_source(eds), node_id))
    m = node.tpdo[pdo.number]
    m.clear()
    for e in pdo.codec.entries:
        m.add_variable(e.index, e.sub)
    out = []
    for msg in can.BLFReader(str(blf)):
        if msg.arbitration_id == pdo.cob_id and not msg.is_extended_id:
            m.data = bytearray(msg.data)
            out.append([v.raw for v in m.map])
    return out


def _od_source(eds: Path) -> tuple:
    """The EDS for the canopen library itself (its own parser, on the file as it is where
    it can read it)."""
    import io

    from drivers.binding.canopen import _without_empty_device_info

    source = io.StringIO(_without_empty_device_info(eds.read_text(errors="replace")))
    source.name = str(eds)
    return (source,)


@pytest.mark.parametrize("rel", sorted(CANOPEN_CASES))
def test_each_eds_runs_on_the_virtual_rig_or_is_refused_naming_its_limit(tmp_path, rel):
    eds = _file(rel)
    build, device, refusal = CANOPEN_CASES[rel]
    data = build(eds)
    if refusal is not None:
        with pytest.raises(ConfigError, match=refusal):
            rig_from_dict(data, "rig file tp.yaml", base_dir=RIGS_DIR)
        return
    result = _run(tmp_path, data)
    assert result.summary["stopped_by"] == "completed", result.summary.get("faults")
    assert result.summary["frames"]["malformed"] == 0
    # the recording decoded by the canopen library equals what the harness recorded (the
    # rig as the run read it: the PDO layout follows the rig file's order of quantities)
    rig = load_rig(tmp_path / "rig.yaml")
    co = rig.binding.canopen
    nid = co.node_of[device]
    rrd = result.run_dir / "run.rrd"
    checked = 0
    for tmap in rig.binding.telemetry[device]:
        pdo = next(p for p in co.nodes[nid].tpdos if p.codec is tmap.codec)
        frames = _decoded_by_canopen(result.run_dir / "can.blf", eds, nid, pdo)
        assert frames, f"no {pdo.codec.name} in the recording"
        for f in tmap.fields:
            if f.conv.mask is not None or f.conv.bit is not None:
                continue
            i = list(pdo.codec.entries).index(f.ref)
            theirs = np.array([fr[i] for fr in frames], dtype=float) * f.conv.scale
            unit = {"speed": "rad_s", "torque": "n_m", "accel": "m_s2",
                    "angle": "rad"}[f.quantity]
            _, ours = read_scalar_channel(rrd, f"/bus/{device}/tlm/{f.quantity}_{unit}")
            assert len(ours) == len(theirs)
            np.testing.assert_allclose(ours, theirs, rtol=0, atol=1e-12)
            checked += 1
    assert checked


# ----------------------------------------------------------------------------- LocalNode
def _cia402_device(local: canopen.LocalNode) -> None:
    """The least a CiA 402 drive does for a master's set-up: its status word follows the
    control word, its mode display the mode written (the test's own, not the virtual
    rig's)."""
    states = {0x06: 0x21, 0x07: 0x23, 0x0F: 0x27, 0x80: 0x40, 0x00: 0x40}

    def on_write(index: int, subindex: int, od: object, data: bytes) -> None:
        if index == 0x6040:
            cw = struct.unpack("<H", data)[0]
            local.data_store.setdefault(0x6041, {})[0] = struct.pack(
                "<H", states.get(cw & 0x8F, 0x40))
        elif index == 0x6060 and 0x6061 in local.object_dictionary:
            local.data_store.setdefault(0x6061, {})[0] = bytes(data)

    local.add_write_callback(on_write)


def _every_object_has_a_value(local: canopen.LocalNode) -> None:
    """A device reads something from every object; the library's LocalNode aborts an
    upload of an object its EDS gives no default (0x060A0023): its ParameterValue, else
    0 there."""
    from canopen.objectdictionary import ODVariable

    for index in local.object_dictionary:
        obj = local.object_dictionary[index]
        for var in [obj] if isinstance(obj, ODVariable) else obj.subindices.values():
            if var.default is None and var.data_type in var.STRUCT_TYPES:
                value = var.value if var.value is not None else 0  # a DCF-style value
                local.data_store.setdefault(var.index, {}).setdefault(
                    var.subindex, var.STRUCT_TYPES[var.data_type].pack(value))


@pytest.mark.parametrize("rel", sorted(r for r, c in CANOPEN_CASES.items() if c[2] is None))
def test_the_harness_master_sets_up_an_independent_slave_of_each_eds(rel):
    from drivers.binding.canopen_master import CanopenMaster

    eds = _file(rel)
    build, device, _ = CANOPEN_CASES[rel]
    rig = rig_from_dict(build(eds), "rig file tp.yaml", base_dir=RIGS_DIR)
    co = rig.binding.canopen
    nid = co.node_of[device]
    spec = co.nodes[nid]
    # the harness talks to that one node only
    from drivers.binding.canopen import CanopenBus

    one = CanopenBus(co.master_id, {nid: spec}, co.consumer_timeout_ms, co.node_of)
    ch = _channel()
    net = canopen.Network()
    net.connect(interface="virtual", channel=ch)
    local = canopen.LocalNode(nid, canopen.import_od(*_od_source(eds), nid))
    net.add_node(local)
    _every_object_has_a_value(local)
    if spec.profile == "cia402":
        _cia402_device(local)

    def on_nmt(can_id: int, data: bytearray, timestamp: float) -> None:
        if data[0] in (0x81, 0x82) and data[1] in (0, nid):  # a reset: boot-up, then pre-op
            net.send_message(0x700 + nid, [0])
            local.nmt.state = "PRE-OPERATIONAL"

    net.subscribe(0, on_nmt)
    bus = can.Bus(interface="virtual", channel=ch)
    try:
        report = CanopenMaster(bus, one).setup()
        deadline = time.monotonic() + 2.0
        while local.nmt.state != "OPERATIONAL" and time.monotonic() < deadline:
            time.sleep(0.01)
        assert local.nmt.state == "OPERATIONAL"
        assert report[0]["node_id"] == nid
        # the mapping the binding decided is what the slave now holds
        for base, pdos in ((0x1A00, spec.tpdos), (0x1600, spec.rpdos)):
            for p in pdos:
                store = local.data_store[base + p.number - 1]
                assert store[0] == bytes((len(p.codec.entries),))
                for i, e in enumerate(p.codec.entries, start=1):
                    assert struct.unpack("<I", store[i])[0] == e.mapping_entry
        if 0x1016 in local.object_dictionary and spec.heartbeat_consumer:
            assert struct.unpack("<I", local.data_store[0x1016][1])[0] == (
                co.master_id << 16 | co.consumer_timeout_ms)
        if spec.profile == "cia402":
            assert local.data_store[0x6041][0] == struct.pack("<H", 0x27)  # enabled
    finally:
        bus.shutdown()
        net.disconnect()


# ----------------------------------------------------------------------------- DBC
HUB = {"hub_sensor": None}
DBC_CASES = {
    # cantools' MotoHawk example: Motorola byte order, a signed 12-bit value with an offset
    "dbc/cantools_motohawk.dbc": {
        "angle": {"message": "ExampleMessage", "signal": "Temperature", "offset": -250.0},
        "rate": {"message": "ExampleMessage", "signal": "AverageRadius", "offset": -2.5}},
    # opendbc's comma body: Motorola, signed, a counter and checksum in the message
    "dbc/opendbc_comma_body.dbc": {
        "angle": {"message": "MOTORS_ANGLE", "signal": "LEFT_ANGLE_SENSOR", "scale": 1e-4,
                  "offset": -0.8},
        "rate": {"message": "MOTORS_DATA", "signal": "SPEED_L", "scale": 1e-3}},
    # a vehicle DBC collection's Model 3 file (strict cantools refuses it for another
    # message): the steering angle and speed, in degrees
    "dbc/model3dbc_Model3CAN.dbc": {
        "angle": {"message": "ID129SteeringAngle", "signal": "SteeringAngle129",
                  "scale": 0.017453292519943295},
        "rate": {"message": "ID129SteeringAngle", "signal": "SteeringSpeed129",
                 "scale": 0.017453292519943295}},
}


def _dbc_rig(dbc: Path, telemetry: dict) -> dict:
    data = yaml.safe_load(yaml.safe_dump(load_rig("sgsrt").data))
    data["devices"] = {"hub_sensor": {"binding": "dbc", "dbc": str(dbc),
                                      "telemetry": telemetry}}
    return data


@pytest.mark.parametrize("rel", sorted(DBC_CASES))
def test_each_dbc_binds_runs_and_cantools_decodes_the_recording(tmp_path, rel):
    dbc = _file(rel)
    tel = DBC_CASES[rel]
    data = _dbc_rig(dbc, tel)
    # these signals are far coarser than the hub sensor's (0.01 rad, 0.1 deg steps): at rest
    # they repeat, which the monitor's count of equal samples alone calls stuck
    # (harness.core.plausibility has the rule that knows the resolution)
    result = _run(tmp_path, data, monitor={"stuck_ticks": 100_000})
    assert result.summary["stopped_by"] == "completed", result.summary.get("faults")
    assert result.summary["frames"]["malformed"] == 0
    db = cantools.database.load_file(str(dbc), strict=False)
    rrd = result.run_dir / "run.rrd"
    for q, unit in (("angle", "rad"), ("rate", "rad_s")):
        spec = tel[q]
        msg = db.get_message_by_name(spec["message"])
        theirs = [db.decode_message(m.arbitration_id, m.data, decode_choices=False)
                  [spec["signal"]] * spec.get("scale", 1.0) + spec.get("offset", 0.0)
                  for m in can.BLFReader(str(result.run_dir / "can.blf"))
                  if m.arbitration_id == msg.frame_id and m.is_extended_id == msg.is_extended_frame]
        _, ours = read_scalar_channel(rrd, f"/bus/hub_sensor/tlm/{q}_{unit}")
        assert len(theirs) == len(ours) > 100
        np.testing.assert_allclose(ours, theirs, rtol=0, atol=1e-9)


def test_a_vehicle_dbc_with_one_inexact_message_warns_naming_it():
    dbc = _file("dbc/model3dbc_Model3CAN.dbc")
    with pytest.raises(Exception, match="DI_lashAngle"):  # strict cantools: the whole file
        cantools.database.load_file(str(dbc), strict=True)
    rig = rig_from_dict(_dbc_rig(dbc, DBC_CASES["dbc/model3dbc_Model3CAN.dbc"]),
                        "rig file tp.yaml", base_dir=RIGS_DIR)
    assert any(w.startswith("model3dbc_Model3CAN.dbc: message ID5D5RearDItemps: ")
               for w in rig.binding.warnings), rig.binding.warnings


def test_a_dbc_cantools_refuses_whole_loads_without_the_stray_entry():
    """opendbc's tesla_can.dbc has a VAL_ table for a signal its message lacks: cantools
    refuses the whole file, the harness drops that entry and notes it on the message."""
    from drivers.dbc import load_protocol

    dbc = _file("dbc/opendbc_tesla_can.dbc")
    with pytest.raises(Exception, match="unused VAL_"):
        cantools.database.load_file(str(dbc), strict=False)
    p = load_protocol(dbc)
    assert len(p.by_name) > 40
    noted = [n for n, why in p.problems.items() if "UI_mapSpeedLimit" in why]
    assert noted and p.database.get_message_by_frame_id(568).name in noted


def test_an_extended_multiplexer_is_refused_only_where_bound():
    from drivers.dbc import load_protocol

    dbc = _file("dbc/cantools_extended_mux_cascaded.dbc")
    p = load_protocol(dbc)
    (name, why), = p.problems.items()
    assert "extended multiplexing" in why
    sig = next(s.name for s in p.database.get_message_by_name(name).signals)
    with pytest.raises(ConfigError, match=rf"devices\.hub_sensor\.telemetry\.angle\.message: "
                                          rf"{name} of cantools_extended_mux_cascaded\.dbc is "
                                          r"not exact: .*extended multiplexing"):
        rig_from_dict(_dbc_rig(dbc, {"angle": {"message": name, "signal": sig},
                                     "rate": {"message": name, "signal": sig}}),
                      "rig file tp.yaml", base_dir=RIGS_DIR)


def test_no_third_party_run_left_a_thread():
    # the LocalNode tests start the canopen library's notifier threads: all stopped
    time.sleep(0.2)
    assert not [t for t in threading.enumerate() if "canopen" in t.name.lower()
                and t.is_alive() and t is not threading.current_thread()]
