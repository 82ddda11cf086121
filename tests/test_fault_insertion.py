"""The fault-insertion unit: a fault taken by the virtual rig at run time, from a frame on the
bus, acting from the next SYNC exactly as one given at start."""

from __future__ import annotations

import copy
import math

import can
import pytest

from drivers.dbc import load_protocol
from harness.bus import CopyingVirtualBus, open_bus, parse_bus
from harness.bus.rig_interface import RigInterface
from harness.bus.rig_process import RigProcess
from harness.core.replay import frame_names, replay_log
from harness.core.runs import load_run
from harness.core.session import execute_run
from harness.state import RigCommand
from rig_models.faults import (
    FAULT_CLEAR,
    FAULT_CODES,
    FAULT_KINDS,
    FaultFrameError,
    FaultSpec,
    decode_fault_insertion,
    encode_fault_clear,
    encode_fault_insertion,
)
from rig_models.rig_file import RIGS_DIR, load_rig, rig_from_dict
from rig_models.schema import ConfigError
from rig_models.virtual_rig import VirtualRig, check_fault_insertion

DT = 0.002
K = 100  # the tick in which the harness inserts the fault
P = load_protocol()


# ------------------------------------------------------------------ the frame
def test_every_kind_has_a_fixed_code():
    assert set(FAULT_CODES) == set(FAULT_KINDS) | {FAULT_CLEAR}
    assert len(set(FAULT_CODES.values())) == len(FAULT_CODES)
    # the codes are the frame's contract: pinned, never renumbered
    assert (FAULT_CODES[FAULT_CLEAR], FAULT_CODES["silent_sensor"],
            FAULT_CODES["valve_stuck_open"], FAULT_CODES["sdo_abort"]) == (0, 8, 12, 22)


@pytest.mark.parametrize("spec", [
    FaultSpec("silent_sensor", 0.0, 0.0, "hub_sensor"),
    FaultSpec("silent_sensor", 0.0, 0.2, "hub_sensor"),
    FaultSpec("valve_stuck_open", 0.0),
    FaultSpec("accel_saturation", 0.0, 655.35, "", 40.0),
    FaultSpec("node_emcy", 0.0, 0.0, "reaction_wheel", float(0x5000)),
    FaultSpec("delay_frames", 0.0, 1.5, "disturbance_rotor", 3.0),
])
def test_round_trip(spec):
    data = encode_fault_insertion(spec)
    assert len(data) == 8
    kind, device, duration_s, value = decode_fault_insertion(data, "frame")
    assert (kind, device, value) == (spec.kind, spec.device, spec.value)
    assert duration_s == pytest.approx(spec.duration_s, abs=1e-9)


def test_layout_is_little_endian():
    data = encode_fault_insertion(FaultSpec("wheel_fault", 0.0, 0.5, "reaction_wheel", 1.0))
    assert data[:4] == bytes([10, 2, 50, 0]) and data[4:] == b"\x00\x00\x80\x3f"
    assert decode_fault_insertion(encode_fault_clear(), "f") == (FAULT_CLEAR, "", 0.0, None)


@pytest.mark.parametrize("spec,field", [
    (FaultSpec("no_such_kind", 0.0), "kind"),
    (FaultSpec("silent_sensor", 0.0), "device"),
    (FaultSpec("silent_sensor", 0.0, 0.0, "tachometer"), "device"),
    (FaultSpec("silent_sensor", 0.0, 0.004, "hub_sensor"), "duration_s"),
    (FaultSpec("silent_sensor", 0.0, 700.0, "hub_sensor"), "duration_s"),
    (FaultSpec("silent_sensor", 0.0, -1.0, "hub_sensor"), "duration_s"),
    (FaultSpec("accel_saturation", 0.0, 0.0, "", math.inf), "value"),
])
def test_encode_refuses_what_the_frame_cannot_carry(spec, field):
    with pytest.raises(ConfigError, match=rf"^fault insertion.*: {field}:"):
        encode_fault_insertion(spec)


@pytest.mark.parametrize("data,what", [
    (bytes(7), "expected 8 bytes, got 7"),
    (bytes([99, 0xFF, 0, 0, 0, 0, 0xC0, 0x7F]), "kind code 99"),
    (bytes([8, 6, 0, 0, 0, 0, 0xC0, 0x7F]), "device code 6"),
    (bytes([8, 0xFF, 0, 0, 0, 0, 0xC0, 0x7F]), "silent_sensor needs a device"),
])
def test_decode_refuses_a_bad_frame_naming_it(data, what):
    with pytest.raises(FaultFrameError, match=rf"^FAULT_INSERTION \(0x6C0\): .*{what}"):
        decode_fault_insertion(data, "FAULT_INSERTION (0x6C0)")


# ------------------------------------------------------------------ the rig file
def _rig(name: str, fid: object) -> object:
    data = copy.deepcopy(load_rig(name).data)
    data["bus"]["fault_insertion_id"] = fid
    return rig_from_dict(data, f"rig file {name}-x.yaml", base_dir=RIGS_DIR)


def test_every_built_in_rig_has_a_fault_insertion_unit():
    for name in ("sgsrt", "sgsrt-as-built", "sgsrt-canopen", "sgsrt-canopen-as-built",
                 "sgsrt-dbc2", "sgsrt-dbc2-as-built"):
        rig = load_rig(name)
        assert rig.fault_insertion_key == (0x6C0, False), name
        check_fault_insertion(rig)


def test_a_rig_without_the_unit_is_refused_naming_the_key():
    rig = _rig("sgsrt", None)
    assert rig.fault_insertion_key is None
    with pytest.raises(ConfigError, match="bus.fault_insertion_id: absent: this rig has no "
                                          "fault-insertion unit"):
        check_fault_insertion(rig)
    iface = RigInterface(type("NoBus", (), {"send": lambda self, m: None})(), P, rig, None)
    with pytest.raises(ConfigError, match="bus.fault_insertion_id"):
        iface.insert_fault(FaultSpec("wheel_fault", 0.0))


@pytest.mark.parametrize("name,fid,what", [
    ("sgsrt", 0x200, "HUB_TLM's id"),
    ("sgsrt", 0x080, "the SYNC's id"),
    ("sgsrt", 0x090, "the master heartbeat's id"),
    ("sgsrt", 0x6A5, "unknown_ids fault frames"),
    ("sgsrt-dbc2", 0x311, "THR_Cmd's id"),
    ("sgsrt-dbc2", 0x701, "the master heartbeat's id"),
    ("sgsrt-canopen", 0x100, "the CANopen TIME"),
    ("sgsrt-canopen", 0x182, "TPDO1 node 2's id \\(devices.reaction_wheel.telemetry"),
    ("sgsrt-canopen", 0x482, "TPDO4 of CANopen node 2"),
    ("sgsrt-canopen", 0x602, "SDO request of CANopen node 2"),
    ("sgsrt-canopen", 0x77F, "heartbeat"),
])
def test_a_clash_is_refused_naming_the_key(name, fid, what):
    with pytest.raises(ConfigError, match=rf"bus.fault_insertion_id: 0x{fid:03X} is .*{what}"):
        _rig(name, fid)


def test_a_dbc_message_no_device_binds_is_a_clash_too():
    # sgsrt_dbc2.dbc's AUX_STATUS is extended; its standard messages: every one refused
    for codec in load_protocol(str(RIGS_DIR.parent.parent / "drivers" / "sgsrt_dbc2.dbc")
                               ).by_id.values():
        with pytest.raises(ConfigError, match="bus.fault_insertion_id"):
            _rig("sgsrt-dbc2", codec.frame_id)


def test_faults_a_rig_cannot_take_at_run_time_are_refused():
    sg, co = load_rig("sgsrt"), load_rig("sgsrt-canopen")
    with pytest.raises(ConfigError, match=r"drive_fault:reaction_wheel: .*not a CANopen "
                                          r"device .*devices.reaction_wheel.binding"):
        check_fault_insertion(sg, [FaultSpec("drive_fault", 0.0, 0.0, "reaction_wheel")])
    check_fault_insertion(co, [FaultSpec("drive_fault", 0.0, 0.0, "reaction_wheel")])
    with pytest.raises(ConfigError, match="sdo_abort.*set-up"):
        check_fault_insertion(co, [FaultSpec("sdo_abort", 0.0, 0.0, "reaction_wheel")])
    with pytest.raises(ConfigError, match="bad_checksum.*declares no checksum"):
        check_fault_insertion(sg, [FaultSpec("bad_checksum", 0.0, 0.0, "hub_sensor")])
    check_fault_insertion(load_rig("sgsrt-dbc2"),
                          [FaultSpec("bad_checksum", 0.0, 0.0, "reaction_wheel")])


# ------------------------------------------------------------------ in process, lockstep
class _Log:
    def __init__(self) -> None:
        self.frames: list[can.Message] = []

    def log(self, msg: can.Message) -> None:
        self.frames.append(msg)


def _lockstep(name: str, n_ticks: int, insert: FaultSpec | None = None,
              given: list[FaultSpec] | None = None, clear_at: int | None = None
              ) -> tuple[list[tuple[int, int, bytes]], VirtualRig, RigInterface, _Log]:
    """The sgsrt rig in lockstep, wheel and valves armed and commanded; ``insert`` sent by
    the harness in tick K, or ``given`` at start. Every telemetry frame as (tick, id, data)."""
    rig_cfg = load_rig("sgsrt")
    harness_bus, rig_bus = CopyingVirtualBus(channel=name), CopyingVirtualBus(channel=name)
    rig = VirtualRig(rig_cfg, rig_bus, DT, faults=given)
    log = _Log()
    iface = RigInterface(harness_bus, P, rig_cfg, log,  # type: ignore[arg-type]
                         ("reaction_wheel", "thruster_valves"))
    frames: list[tuple[int, int, bytes]] = []
    try:
        for k in range(n_ticks):
            iface.send_heartbeat(True)
            iface.send_sync(k)
            rig.service()
            while (m := harness_bus.recv(0)) is not None:
                frames.append((k, m.arbitration_id, bytes(m.data)))
                iface.feed(m, k)
            iface.command(RigCommand(wheel_torque_n_m=0.03, valve_direction=-1))
            if insert is not None and k == K:
                iface.insert_fault(insert)
            if clear_at is not None and k == clear_at:
                iface.clear_faults()
        return frames, rig, iface, log
    finally:
        harness_bus.shutdown()
        rig_bus.shutdown()


@pytest.mark.parametrize("spec", [
    FaultSpec("silent_sensor", 0.0, 0.0, "hub_sensor"),
    FaultSpec("silent_sensor", 0.0, 0.05, "hub_sensor"),
    FaultSpec("valve_stuck_open", 0.0),
    FaultSpec("wheel_fault", 0.0),
    FaultSpec("corrupt_payload", 0.0, 0.1, "accelerometer", 1.0),
], ids=lambda s: f"{s.kind}+{s.duration_s:g}")
def test_a_fault_inserted_in_tick_k_acts_from_tick_k_plus_1_as_one_given_at_start(
        request, spec):
    n = K + 60
    got, rig, iface, log = _lockstep(f"fi-{request.node.name}", n, insert=spec)
    # the same fault given at start, at the time of tick K + 1: every frame the same
    at_s = rig.inserted_faults[0].at_s
    assert at_s == pytest.approx((K + 1) * DT)
    given, _, _, _ = _lockstep(f"fi-given-{request.node.name}", n,
                               given=[FaultSpec(spec.kind, at_s, spec.duration_s,
                                                spec.device, spec.value)])
    plain, _, _, _ = _lockstep(f"fi-plain-{request.node.name}", n)
    assert got == given
    # not before: up to tick K the frames are those of a run without a fault
    assert [f for f in got if f[0] <= K] == [f for f in plain if f[0] <= K]
    assert [f for f in got if f[0] == K + 1] != [f for f in plain if f[0] == K + 1] or (
        spec.kind == "valve_stuck_open")  # the valves answer every 5th SYNC
    # the frame is a sent frame of the CAN log; nothing unknown or malformed either side
    sent = [m for m in log.frames if m.arbitration_id == 0x6C0]
    assert len(sent) == 1 and not sent[0].is_rx
    assert iface.counters.unknown == 0
    assert rig.counters.unknown == 0 and rig.counters.malformed == 0


def test_silent_sensor_by_tick_and_the_state_of_the_devices(request):
    got, rig, _, _ = _lockstep(f"fi-{request.node.name}", K + 20,
                               insert=FaultSpec("silent_sensor", 0.0, 0.0, "hub_sensor"))
    hub = P["HUB_TLM"].frame_id
    assert max(k for k, fid, _ in got if fid == hub) == K
    _, rig, _, _ = _lockstep(f"fi-v-{request.node.name}", K + 20,
                             insert=FaultSpec("valve_stuck_open", 0.0))
    assert rig.valves.stuck_open
    _, rig, _, _ = _lockstep(f"fi-w-{request.node.name}", K + 2,
                             insert=FaultSpec("wheel_fault", 0.0))
    assert rig.wheel.fault


def test_clear_ends_every_fault_from_the_next_sync(request):
    got, rig, _, _ = _lockstep(f"fi-{request.node.name}", K + 40,
                               insert=FaultSpec("silent_sensor", 0.0, 0.0, "hub_sensor"),
                               clear_at=K + 10)
    hub = {k for k, fid, _ in got if fid == P["HUB_TLM"].frame_id}
    assert K in hub and not hub & set(range(K + 1, K + 11)) and K + 11 in hub


def test_a_bad_insertion_frame_is_malformed_at_the_rig_and_logged(request):
    rig_cfg = load_rig("sgsrt")
    bus, rig_bus = (CopyingVirtualBus(channel=f"fi-{request.node.name}") for _ in range(2))
    told: list[str] = []
    try:
        rig = VirtualRig(rig_cfg, rig_bus, DT)
        rig.on_fault_inserted = told.append
        bus.send(can.Message(arbitration_id=0x6C0, data=bytes([99, 0xFF, 0, 0, 0, 0, 0, 0]),
                             is_extended_id=False))
        rig.service()
        assert rig.counters.malformed == 1 and not rig.injector.faults
        assert told and "kind code 99" in told[0]
    finally:
        bus.shutdown()
        rig_bus.shutdown()


# ------------------------------------------------------------------ a whole run
def _insert_at(monkeypatch, tick: int, spec: FaultSpec) -> None:
    """The harness inserts ``spec`` in ``tick``, after its commands (a sequence's step)."""
    command = RigInterface.command

    def command_then_insert(self: RigInterface, cmd: RigCommand) -> RigCommand:
        sent = command(self, cmd)
        if self.state.tick == tick:
            self.insert_fault(spec)
        return sent
    monkeypatch.setattr(RigInterface, "command", command_then_insert)


@pytest.mark.parametrize("rig,kind,device,detected", [
    ("sgsrt", "silent_sensor", "hub_sensor", "silent"),
    ("sgsrt-canopen", "silent_sensor", "hub_sensor", "silent"),
    ("sgsrt-canopen", "drive_disabled", "reaction_wheel", "drive disabled"),
    ("sgsrt-dbc2", "silent_sensor", "hub_sensor", "silent"),
])
def test_a_run_detects_an_inserted_fault_as_a_timed_one(tmp_path, monkeypatch, rig, kind,
                                                         device, detected):
    run = load_run("slew-rw", {"duration_s": 1.5, "rig": rig})
    timed = execute_run(run, out_dir=tmp_path / "timed", show_progress=False,
                        faults=[FaultSpec(kind, 501 * DT, 0.0, device)])
    _insert_at(monkeypatch, 500, FaultSpec(kind, 0.0, 0.0, device))
    res = execute_run(run, out_dir=tmp_path / "inserted", show_progress=False)
    s = res.summary
    assert s["faults"] == timed.summary["faults"]
    assert s["faults"][0]["kind"] == detected and s["faults"][0]["device"] == device
    assert s["faults"][0]["tick"] > 500
    assert s["frames"]["unknown"] == 0 and s["frames"]["malformed"] == 0
    assert [f["kind"] for f in s["inserted_faults"]] == [kind]
    # the CAN log replays with the frame named and nothing unknown
    replay = replay_log(res.run_dir / "can.blf", load_rig(rig), DT, keep_ticks=False)
    assert replay.unknown == 0 and replay.frames_by_id[0x6C0] == 1
    assert 0x6C0 in replay.harness_ids
    assert frame_names(load_rig(rig))[0x6C0] == ("FAULT_INSERTION", "harness")


# ------------------------------------------------------------------ the rig as its process
@pytest.mark.parametrize("transport", ["unix", "tcp"])
def test_a_rig_process_takes_the_fault(tmp_path, transport):
    # over a Unix socket, and socketcand on 127.0.0.1
    rig_cfg = load_rig("sgsrt")
    with RigProcess(rig_cfg, 1.0 / DT, tmp_path, transport=transport,
                    lifetime_s=120) as where:
        bus = open_bus(parse_bus(where))
        try:
            iface = RigInterface(bus, P, rig_cfg, None, ())
            hub_ticks = []
            for k in range(K + 10):
                iface.send_heartbeat(False)
                iface.send_sync(k)
                before = iface.hub.last_tick
                # every frame due; from K + 1 on, every frame but the hub's and a short wait
                iface.receive(k, 5.0 if k <= K else 0.15)
                if iface.hub.last_tick != before:
                    hub_ticks.append(k)
                if k == K:
                    iface.insert_fault(FaultSpec("silent_sensor", 0.0, 0.0, "hub_sensor"))
        finally:
            bus.shutdown()
    assert max(hub_ticks) == K and set(range(K + 1)) <= set(hub_ticks)
    assert iface.counters.unknown == 0
    log = (tmp_path / "rig.log").read_text()
    assert f"(tick {K}): silent_sensor:hub_sensor from t = " in log, log
