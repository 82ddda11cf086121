"""The device binding on CANopen: refused bindings name the key, an independent master
scans the virtual CANopen rig, each CANopen fault is detected within its bound and the rig
is left safe, and `left_safe` judges through the binding."""

from __future__ import annotations

import threading
import time
import uuid
from pathlib import Path

import can
import canopen
import pytest
import yaml

from drivers.binding import BindingError, build_binding
from drivers.binding.canopen import PdoCodec
from harness.core.runs import run_from_dict
from harness.core.session import RunRefused, execute_run
from harness.record.reader import read_scalar_channel
from harness.testing.judge import left_safe_problems
from rig_models.faults import FaultSpec
from rig_models.rig_file import RIGS_DIR, load_rig, rig_from_dict
from rig_models.schema import ConfigError
from rig_models.virtual_rig import VirtualRig

CO_RIG = load_rig("sgsrt-canopen")


def _co_data() -> dict:
    return yaml.safe_load(yaml.safe_dump(CO_RIG.data))


def _channel() -> str:
    return f"co-{uuid.uuid4().hex[:10]}-test"


# ----------------------------------------------------------------------------- bindings
def test_sgsrt_default_binding_is_the_sgsrt_dbc():
    b = load_rig("sgsrt").binding
    frames = {(f.name, f.device, f.kind, f.key) for f in b.frames()}
    assert ("WHEEL_CMD", "reaction_wheel", "cmd", (0x100, False)) in frames
    assert ("HUB_TLM", "hub_sensor", "tlm", (0x200, False)) in frames
    assert ("SYNC", "harness", "sync", (0x80, False)) in frames
    assert all(k == "sgsrt" for k in b.kinds.values())


def test_canopen_binding_pdos_from_the_rig_file():
    co = CO_RIG.binding.canopen
    assert sorted(co.nodes) == [2, 3, 4, 5]
    wheel = co.nodes[2]
    assert [e.label for e in wheel.tpdos[0].codec.entries] == ["0x606C.0", "0x6077.0",
                                                               "0x6041.0"]
    assert wheel.tpdos[0].cob_id == 0x182 and wheel.rpdos[0].cob_id == 0x202
    io = co.nodes[3]
    assert sorted(io.devices) == ["accelerometer", "piezo_amplifier", "thruster_valves"]
    # each device's TPDO at its own divider (the valves answer every 5th SYNC)
    trans = {p.codec.name: p.trans_type for p in io.tpdos}
    assert trans == {"TPDO1 node 3": 1, "TPDO2 node 3": 5, "TPDO3 node 3": 1}


def _refused(data: dict, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        rig_from_dict(data, "rig file x.yaml", base_dir=RIGS_DIR)


def test_object_the_eds_lacks_is_refused_naming_the_key():
    d = _co_data()
    d["devices"]["reaction_wheel"]["telemetry"]["speed"]["object"] = 0x6099
    _refused(d, r"devices\.reaction_wheel\.telemetry\.speed\.object: 0x6099 is not in "
                r"sgsrt_wheel_drive\.eds")


def test_node_id_twice_is_refused():
    d = _co_data()
    d["devices"]["hub_sensor"]["node_id"] = 2  # the wheel drive's node, another EDS
    _refused(d, r"devices\.(hub_sensor|reaction_wheel)\.node_id: node 2 is also")


def test_master_node_id_clash_is_refused():
    d = _co_data()
    d["bus"]["master_node_id"] = 4
    _refused(d, r"devices\.hub_sensor\.node_id: 4 is the harness's own node id")


def test_quantity_the_harness_needs_left_unbound_is_refused():
    d = _co_data()
    del d["devices"]["accelerometer"]["telemetry"]["accel"]
    _refused(d, r"devices\.accelerometer\.telemetry\.accel: missing")


def test_unknown_quantity_and_bad_conversion_are_refused():
    d = _co_data()
    d["devices"]["hub_sensor"]["telemetry"]["angel"] = {"object": 0x6004}
    _refused(d, r"devices\.hub_sensor\.telemetry\.angel: unknown quantity")
    d = _co_data()
    d["devices"]["hub_sensor"]["telemetry"]["angle"]["scale"] = float("nan")
    _refused(d, r"devices\.hub_sensor\.telemetry\.angle\.scale: expected a finite")


def test_pdo_over_eight_bytes_is_refused():
    ref = CO_RIG.binding.canopen.nodes[4].tpdos[0].codec.entries[0]  # a 32-bit object
    with pytest.raises(BindingError, match="TPDO9: mapping of 96 bits"):
        PdoCodec("TPDO9", 0x180, (ref, ref, ref))


def test_sgsrt_device_on_a_canopen_bus_is_refused():
    d = _co_data()
    d["devices"]["hub_sensor"] = {"binding": "sgsrt"}
    _refused(d, r"bus\.sync: hub_sensor bind sgsrt")


def test_dbc_binding_names_message_and_signal():
    data = {"bus": {}, "devices": {"hub_sensor": {
        "binding": "dbc", "dbc": "sgsrt.dbc",
        "telemetry": {"angle": {"message": "HUB_TLMX", "signal": "angle"}}}}}
    with pytest.raises(BindingError, match=r"devices\.hub_sensor\.telemetry\.angle\.message: "
                                           r"'HUB_TLMX' is not a message of sgsrt\.dbc"):
        build_binding(data)
    data["devices"]["hub_sensor"]["telemetry"] = {
        "angle": {"message": "HUB_TLM", "signal": "angel"}, "rate": {"message": "HUB_TLM",
                                                                     "signal": "rate"}}
    with pytest.raises(BindingError, match=r"telemetry\.angle\.signal: 'angel' is not a signal"):
        build_binding(data)


def test_dbc_binding_converts_to_si_both_ways():
    """A DBC binding with a scale: the rig encodes SI through it, the harness decodes it
    back; the frame carries the DBC's own physical value."""
    data = {"bus": {}, "devices": {"hub_sensor": {
        "binding": "dbc", "dbc": "sgsrt.dbc",
        "telemetry": {"angle": {"message": "HUB_TLM", "signal": "angle", "scale": 2.0},
                      "rate": {"message": "HUB_TLM", "signal": "rate", "sensitivity": 4.0}}}}}
    b = build_binding(data)
    (tmap,) = b.telemetry["hub_sensor"]
    payload = tmap.encode({"angle": 1.0, "rate": 0.25})
    raw = tmap.codec.decode(payload)
    assert raw["angle"] == pytest.approx(0.5) and raw["rate"] == pytest.approx(1.0)
    back = tmap.decode(payload)
    assert back["angle"] == pytest.approx(1.0) and back["rate"] == pytest.approx(0.25)


# ----------------------------------------------------------------------------- scan
def test_independent_master_scans_the_virtual_canopen_rig():
    """The canopen library's RemoteNode as an independent master: every node boots per
    CiA 301, answers SDO for 0x1000, 0x1018 and its PDO mapping, and sends its heartbeat."""
    ch = _channel()
    rig_bus = can.Bus(interface="virtual", channel=ch)
    rig = VirtualRig(CO_RIG, rig_bus, 0.002)
    rig.wall_clock = True  # heartbeats on the wall clock, as in the rig's own process
    stop = threading.Event()

    def pump() -> None:
        while not stop.is_set():
            rig.service()
            rig.co_devices.poll(rig.co_now())
            time.sleep(0.0005)

    t = threading.Thread(target=pump, daemon=True)
    net = canopen.Network()
    net.connect(interface="virtual", channel=ch)
    t.start()
    try:
        for nid, spec in CO_RIG.binding.canopen.nodes.items():
            node = canopen.RemoteNode(nid, spec.eds)
            node.sdo.RESPONSE_TIMEOUT = 5.0  # a loaded machine: no time is asserted here
            net.add_node(node)
            booted = threading.Event()
            node.nmt.add_heartbeat_callback(lambda s, ev=booted: s == 0 and ev.set())
            node.nmt.send_command(0x81)  # reset node: boot-up frame, pre-operational
            assert booted.wait(10.0), f"node {nid}: no boot-up"
            assert node.nmt.state == "PRE-OPERATIONAL"
            device_type = node.sdo.upload(0x1000, 0)
            assert int.from_bytes(device_type, "little") == spec.od[0x1000].default
            vendor = int.from_bytes(node.sdo.upload(0x1018, 1), "little")
            assert vendor == spec.od[0x1018][1].default
            for sub in (2, 3, 4):
                assert len(node.sdo.upload(0x1018, sub)) == 4
            node.tpdo.read()
            node.rpdo.read()
            assert any(m.enabled for m in node.tpdo.map.values())
            node.sdo.download(0x1017, 0, (20).to_bytes(2, "little"))
            states = []
            node.nmt.add_heartbeat_callback(states.append)
            t0 = time.monotonic()
            while len(states) < 3 and time.monotonic() - t0 < 10.0:
                time.sleep(0.005)
            assert len(states) >= 3 and all(s == 0x7F for s in states[1:]), states
    finally:
        stop.set()
        t.join(2.0)
        net.disconnect()
        rig_bus.shutdown()


# ----------------------------------------------------------------------------- runs
RUN = {"name": "co", "rig": "sgsrt-canopen", "clock": "lockstep", "rate_hz": 500,
       "duration_s": 2.0, "actuators": ["reaction_wheel"],
       "controller": {"type": "pd_wheel", "angle_deg": 1.0, "start_s": 0.2}}


def _run(tmp_path: Path, faults: list[FaultSpec]):  # noqa: ANN202
    run = run_from_dict(dict(RUN, bus=f"virtual:{_channel()}"))
    return execute_run(run, out_dir=tmp_path, show_progress=False, faults=faults)


def _assert_left_safe(result) -> None:  # noqa: ANN001
    assert left_safe_problems(result.run_dir / "can.blf", CO_RIG.data) == []
    co = result.virtual_rig.co_devices
    assert not co.drive("reaction_wheel").operation_enabled
    # what the physics would take from the objects at its next step: no torque, no valve
    assert co.commands("reaction_wheel") == {"torque_cmd": 0.0, "enable": 0.0}
    assert co.commands("thruster_valves") == {"valve_pos": 0.0, "valve_neg": 0.0}
    for node in co.nodes.values():
        assert node.state.name in ("PRE_OPERATIONAL", "STOPPED"), node.state


def test_canopen_run_completes_and_is_left_safe(tmp_path):
    result = _run(tmp_path, [])
    assert result.summary["stopped_by"] == "completed", result.summary.get("faults")
    assert result.summary["frames"]["malformed"] == 0
    assert result.summary["frames"]["unknown"] == 0
    # every due frame came (the valves' and rotor's every-5th-SYNC TPDOs from tick 5 on)
    assert result.summary["frames"]["missing"] == 0
    assert abs(result.summary["final_angle_error_deg"]) < 0.05
    _assert_left_safe(result)
    _, late = read_scalar_channel(result.run_dir / "run.rrd", "/bus/late_or_missing")
    assert late.sum() == 0
    # the recording's bus view decoded the PDOs through the binding, by quantity, in SI,
    # and every node's heartbeat state
    rrd = result.run_dir / "run.rrd"
    t_cmd, torque = read_scalar_channel(rrd, "/bus/reaction_wheel/cmd/torque_cmd_n_m")
    t_loop, sent = read_scalar_channel(rrd, "/wheel/torque_cmd_n_m")
    assert len(t_cmd) >= len(t_loop)
    assert abs(torque.max() - sent.max()) <= 6.5e-5  # one count of the per-mille torque
    _, speed = read_scalar_channel(rrd, "/bus/reaction_wheel/tlm/speed_rad_s")
    _, loop_speed = read_scalar_channel(rrd, "/wheel/speed_rad_s")
    assert speed[-1] == pytest.approx(loop_speed[-1], abs=1e-9)
    for nid in (2, 3, 4, 5):
        _, state = read_scalar_channel(rrd, f"/bus/canopen/node_{nid}/nmt_state")
        assert len(state) > 10 and state[-1] == 5.0


CO_CASES = [
    # a heartbeat missing past 3 periods (50 ms each), seen by the next tick
    ("node_heartbeat_lost", "hub_sensor", "heartbeat lost", 0.15 + 0.05 + 0.002),
    ("node_emcy", "accelerometer", "EMCY", 0.002),          # the tick it arrives
    ("drive_fault", "reaction_wheel", "EMCY", 0.002),       # its EMCY, the same tick
    ("drive_disabled", "reaction_wheel", "drive disabled", 0.010),  # still off 2 d + 2 ticks
    ("node_reboot", "thruster_valves", "node rebooted", 0.002),
    ("node_stopped", "hub_sensor", "NMT state", 0.05 + 0.002),  # its next heartbeat
]


def test_every_canopen_fault_kind_has_a_case():
    from rig_models.faults import CANOPEN_FAULTS

    # sdo_abort: test_sdo_abort_during_setup_refuses_the_run_naming_node_and_code
    assert {c[0] for c in CO_CASES} | {"sdo_abort"} == CANOPEN_FAULTS


@pytest.mark.parametrize("kind, device, expect_kind, bound_s", CO_CASES)
def test_canopen_fault_detected_within_bound_and_left_safe(tmp_path, kind, device,
                                                           expect_kind, bound_s):
    at = 1.0
    result = _run(tmp_path, [FaultSpec(kind, at, device=device)])
    faults = result.summary["faults"]
    assert result.summary["stopped_by"] == "fault" and faults, result.summary["stopped_by"]
    f = faults[0]
    assert f["kind"] == expect_kind
    assert device in f["device"]
    assert at <= f["time_s"] <= at + bound_s, f
    _assert_left_safe(result)


def test_sdo_abort_during_setup_refuses_the_run_naming_node_and_code(tmp_path):
    ch = _channel()
    spy = can.Bus(interface="virtual", channel=ch)  # every frame of the attempt, both ways
    try:
        run = run_from_dict(dict(RUN, bus=f"virtual:{ch}"))
        with pytest.raises(RunRefused, match=r"node 2 \(reaction_wheel\): writing 0x1017\.0 "
                                             r"\(heartbeat producer time\): SDO abort "
                                             r"0x08000020"):
            execute_run(run, out_dir=tmp_path, show_progress=False,
                        faults=[FaultSpec("sdo_abort", 0.0, device="reaction_wheel")])
        ids = []
        while (m := spy.recv(0.0)) is not None:
            ids.append((m.arbitration_id, bytes(m.data)))
    finally:
        spy.shutdown()
    # nothing of the run was sent: no SYNC, no PDO; only set-up, then every node to
    # pre-operational; and a refused run leaves no folder
    assert all(cid != 0x080 and not 0x180 <= cid < 0x580 for cid, _ in ids)
    assert (0x000, bytes((0x80, 0))) in ids
    assert not any(tmp_path.iterdir())


# ----------------------------------------------------------------------------- left safe
def _blf(path: Path, frames: list[tuple[int, bytes]]) -> Path:
    with can.BLFWriter(str(path)) as w:
        for i, (cid, data) in enumerate(frames):
            w.on_message_received(can.Message(arbitration_id=cid, data=data, timestamp=i,
                                              is_extended_id=False))
    return path


def test_left_safe_judges_canopen_commands_and_nmt(tmp_path):
    codec = CO_RIG.binding.commands["reaction_wheel"][0]
    torque = codec.encode({"torque_cmd": 0.01, "enable": 1})
    safe = codec.encode({"torque_cmd": 0.0, "enable": 0})
    preop = bytes((0x80, 0))
    bad = left_safe_problems(_blf(tmp_path / "a.blf", [(0x202, torque), (0, preop)]),
                             CO_RIG.data)
    assert any("wheel torque" in p for p in bad) and any("wheel enable" in p for p in bad)
    no_nmt = left_safe_problems(_blf(tmp_path / "b.blf", [(0x202, safe)]), CO_RIG.data)
    assert any("pre-operational" in p for p in no_nmt)
    assert left_safe_problems(_blf(tmp_path / "c.blf", [(0x202, safe), (0, preop)]),
                              CO_RIG.data) == []


# ----------------------------------------------------------------------------- DCF
def _wheel_dcf(path: Path, second: int, third: int) -> Path:
    """The wheel drive's EDS as a DCF whose TPDO1 maps 0x6041 then ``second``, ``third``."""
    text = (Path(CO_RIG.binding.files["reaction_wheel"])).read_text()
    for sub, word in ((2, second), (3, third)):
        head = f"[1A00sub{sub}]"
        i = text.index(head)
        j = text.index("PDOMapping=", i)
        text = text[:j] + f"ParameterValue=0x{word:08X}\r\n" + text[j:]
    path.write_text(text)
    return path


def _dcf_rig(tmp_path: Path, dcf: Path) -> dict:
    d = _co_data()
    d["devices"]["reaction_wheel"]["eds"] = str(dcf)
    return d


def test_a_dcf_mapping_is_taken_and_verified_not_written(tmp_path):
    """A device bound to a DCF: the harness takes its PDO mapping from the DCF (here the
    velocity before the torque) and checks it on the device instead of writing it; the run
    works over it. A quantity in none of the DCF's PDOs is refused naming the key."""
    dcf = _wheel_dcf(tmp_path / "wheel.dcf", 0x606C0020, 0x60770010)
    data = _dcf_rig(tmp_path, dcf)
    rig = rig_from_dict(data, "rig file dcf.yaml", base_dir=RIGS_DIR)
    node = rig.binding.canopen.nodes[2]
    assert node.verify
    assert [e.label for e in node.tpdos[0].codec.entries] == ["0x6041.0", "0x606C.0",
                                                              "0x6077.0"]
    rig_file = tmp_path / "dcf.yaml"
    rig_file.write_text(yaml.safe_dump(data))
    run = run_from_dict(dict(RUN, bus=f"virtual:{_channel()}", rig=str(rig_file)))
    result = execute_run(run, out_dir=tmp_path / "logs", show_progress=False)
    assert result.summary["stopped_by"] == "completed", result.summary.get("faults")
    # verified, not written: no SDO download to the wheel's mapping 0x1A00 in the log
    writes = [m for m in can.LogReader(str(result.run_dir / "can.blf"))
              if m.arbitration_id == 0x602 and m.data[0] & 0xE0 == 0x20
              and m.data[1:3] == bytes((0x00, 0x1A))]
    assert writes == []
    bad = dict(data)
    bad["devices"] = dict(data["devices"], reaction_wheel=dict(
        data["devices"]["reaction_wheel"], telemetry=dict(
            data["devices"]["reaction_wheel"]["telemetry"],
            torque={"object": 0x6071, "scale": 6.5e-5})))
    with pytest.raises(ConfigError, match=r"devices\.reaction_wheel\.telemetry\.torque: "
                                          r"0x6071\.0 is in no TPDO of wheel\.dcf"):
        rig_from_dict(bad, "rig file dcf.yaml", base_dir=RIGS_DIR)


def test_a_device_whose_mapping_differs_from_its_dcf_stops_the_setup(tmp_path):
    """The device (here the virtual rig with the EDS's own mapping) is not configured as
    the DCF says: the set-up names the PDO and the first differing entry."""
    from drivers.binding.canopen_master import CanopenMaster, SetupError

    dcf = _wheel_dcf(tmp_path / "wheel.dcf", 0x606C0020, 0x60770010)
    harness_rig = rig_from_dict(_dcf_rig(tmp_path, dcf), "rig file dcf.yaml",
                                base_dir=RIGS_DIR)
    ch = _channel()
    buses = [can.Bus(interface="virtual", channel=ch) for _ in range(2)]
    try:
        rig = VirtualRig(CO_RIG, buses[1], 0.002)  # the device: the EDS's mapping
        master = CanopenMaster(buses[0], harness_rig.binding.canopen)
        with pytest.raises(SetupError, match=r"node 2 \(reaction_wheel\): TPDO1: mapped object "
                                             r"2 is 0x60770010 on the device, the DCF says "
                                             r"0x606C0020"):
            master.setup(pump=rig.service)
    finally:
        for b in buses:
            b.shutdown()


def test_a_dcf_pdo_over_eight_bytes_is_refused_naming_the_key(tmp_path):
    # TPDO1 of the DCF maps 0x6041 (16 bit) + two 32-bit velocities + 0x6077: 96 bits
    dcf = _wheel_dcf(tmp_path / "wheel.dcf", 0x606C0020, 0x606C0020)
    text = dcf.read_text()
    i = text.index("[1A00sub0]")
    j = text.index("PDOMapping=", i)
    text = text[:j] + "ParameterValue=0x4\r\n" + text[j:]
    i = text.index("[1A00sub4]")
    j = text.index("PDOMapping=", i)
    dcf.write_text(text[:j] + "ParameterValue=0x60770010\r\n" + text[j:])
    with pytest.raises(ConfigError, match=r"devices\.reaction_wheel\.eds: wheel\.dcf: TPDO1 "
                                          r"node 2: mapping of 96 bits"):
        rig_from_dict(_dcf_rig(tmp_path, dcf), "rig file dcf.yaml", base_dir=RIGS_DIR)


def test_replay_decodes_a_canopen_run_by_name(tmp_path):
    """`harness replay` on a CANopen run: every frame named by the binding (NMT, SYNC, each
    node's PDOs, SDO and heartbeat), the ticks unwrapped from the SYNC counter, the states
    decoded through the same maps; `--check` says it compares sgsrt frames only."""
    import json
    import subprocess
    import sys

    result = _run(tmp_path, [])
    from in_process import harness_in_process

    out = harness_in_process("replay", str(result.run_dir), "--json")  # the entry point: below
    assert out.returncode == 0, out.stderr
    rep = json.loads(out.stdout)
    assert rep["ticks"] == result.summary["ticks"]
    assert rep["unknown_ids"] == 0 and rep["malformed"] == 0
    names = {f["name"] for f in rep["frames"]}
    assert {"NMT", "SYNC", "TPDO1 node 2 (reaction_wheel)", "RPDO1 node 2",
            "SDO request node 2", "SDO response node 2", "heartbeat node 4"} <= names, names
    assert "?" not in names
    check = subprocess.run([sys.executable, "-m", "harness", "replay", str(result.run_dir),
                            "--check"], capture_output=True, text=True, timeout=300)
    assert check.returncode == 2 and "compares sgsrt command frames only" in check.stderr


def test_a_nodes_emcy_about_the_harness_heartbeat_is_named_as_such(tmp_path):
    """EMCY 0x8130 from a node (no vendor byte, or the harness's node id in it): the node
    heard no heartbeat from the harness. In lockstep the loop is never held back, so it is
    the node's: named as the harness's heartbeat lost at that node, not a bare EMCY."""
    result = _run(tmp_path, [FaultSpec("node_emcy", 1.0, device="hub_sensor", value=0x8130)])
    f = result.summary["faults"][0]
    assert (f["device"], f["kind"]) == ("hub_sensor", "harness heartbeat lost"), f
    assert "heard no heartbeat from the harness" in f["message"] and "0x8130" in f["message"]
    _assert_left_safe(result)


def test_the_harness_heartbeat_late_after_a_tick_held_back_is_the_benchs():
    """On the wall clock, a node's EMCY 0x8130 within the watchdog's time of a tick the loop
    held back is the bench's (the run stops as the bus being late); long after it, the
    node's."""
    from drivers.dbc import load_protocol
    from harness.bus.rig_interface import HARNESS_HEARTBEAT_LOST, RigInterface
    from harness.core.runs import load_run
    from harness.core.session import make_monitor

    run = load_run("slew-rw", {"duration_s": 2.0})
    bus = can.Bus(interface="virtual", channel=_channel())
    try:
        iface = RigInterface(bus, load_protocol(), run.rig, None)
        monitor = make_monitor(run, iface, realtime=True)
        report = ("hub_sensor", HARNESS_HEARTBEAT_LOST, "node 4: EMCY 0x8130")
        monitor._protocol_fault = lambda tick: report
        monitor.note_not_held(300, 1.0)  # tick 300 woke a second late
        near = monitor._protocol(310, None, None)
        monitor.not_held_tick = -(1 << 62)
        far = monitor._protocol(900, None, None)
    finally:
        bus.shutdown()
    assert (near.device, near.kind) == ("bus", "late"), near
    assert "held back tick 300" in near.message and "hub_sensor" in near.message
    assert (far.device, far.kind) == ("hub_sensor", HARNESS_HEARTBEAT_LOST), far
