"""The virtual rig's CANopen devices scanned by an independent master (the canopen library's
Network + RemoteNode) over python-can's virtual bus, and the PDO codec against canopen's own
PDO packing."""

from __future__ import annotations

import importlib.util
import itertools
import random
import struct
import sys
import threading
import time
from pathlib import Path

import can
import canopen
import pytest
from canopen.objectdictionary import ObjectDictionary, ODVariable
from canopen.objectdictionary import datatypes as dt
from canopen.sdo import SdoAbortedError, SdoCommunicationError

from drivers.canopen_pdo import PdoCodec, PdoEntry, PdoMappingError, compile_mapping
from drivers.dbc import FrameError
from rig_models.canopen.node import NmtState, VirtualNode
from rig_models.canopen.profiles import Cia401Io, Cia402Drive, Cia406Encoder, DriveState

ROOT = Path(__file__).resolve().parent.parent
EDS = ROOT / "drivers" / "eds"
MASTER_ID = 0x01
WHEEL, ROTOR, IO, ENC = 0x10, 0x11, 0x20, 0x30
FILES = {WHEEL: "sgsrt_wheel_drive.eds", ROTOR: "sgsrt_rotor_drive.eds",
         IO: "sgsrt_io_module.eds", ENC: "sgsrt_encoder.eds"}
_channel = itertools.count()


# ------------------------------------------------------------------ EDS files
def test_eds_files_are_the_generators_output():
    spec = importlib.util.spec_from_file_location("make_eds", ROOT / "tools" / "make_eds.py")
    make_eds = importlib.util.module_from_spec(spec)
    sys.modules["make_eds"] = make_eds  # dataclasses look their module up there
    spec.loader.exec_module(make_eds)
    for name in FILES.values():
        assert (EDS / name).read_bytes() == make_eds.render(name).encode("ascii"), name


@pytest.mark.parametrize("name", FILES.values())
def test_eds_has_the_cia301_objects(name):
    od = canopen.import_od(str(EDS / name), 5)
    for index in (0x1000, 0x1001, 0x1005, 0x1014, 0x1016, 0x1017, 0x1018, 0x1029,
                  *range(0x1400, 0x1404), *range(0x1600, 0x1604),
                  *range(0x1800, 0x1804), *range(0x1A00, 0x1A04)):
        assert index in od, f"{name}: 0x{index:04X}"
    assert od[0x1018][1].default == 0x53475254
    assert od[0x1014].default == 0x85
    assert od[0x1800][1].default & 0x7FF == 0x185


def test_eds_ranges_hold_the_rig_values():
    wheel = canopen.import_od(str(EDS / FILES[WHEEL]), WHEEL)
    assert wheel[0x6076].default == 65  # mN.m = the rig's 0.065 N.m torque limit
    assert wheel[0x1000].default == 0x00020192
    # 628 rad/s of the wheel in 0.001 rad/s counts fits INTEGER32
    assert wheel[0x606C].data_type == dt.INTEGER32 and 628_000 < 2**31
    assert wheel[0x6502].default == (1 << 8) | (1 << 9)
    enc = canopen.import_od(str(EDS / FILES[ENC]), ENC)
    assert enc[0x6004].data_type == dt.INTEGER32 and 214 / 1e-7 < 2**31
    io = canopen.import_od(str(EDS / FILES[IO]), IO)
    assert io[0x1000].default == 0x000F0191
    assert len([s for s in io[0x6401].subindices if s]) >= 3
    assert len([s for s in io[0x6411].subindices if s]) == 2


# ------------------------------------------------------------------ PDO codec
def _od_with(types: list[int]) -> ObjectDictionary:
    od = canopen.import_od(str(EDS / FILES[ENC]), 5)
    for i, t in enumerate(types):
        v = ODVariable(f"v{i}", 0x2100 + i, 0)
        v.data_type = t
        v.pdo_mappable = True
        od.add_object(v)
    return od


def _random_value(rng: random.Random, t: int, bits: int) -> int | float:
    if t in dt.FLOAT_TYPES:
        return struct.unpack("<f", struct.pack("<f", rng.uniform(-1e6, 1e6)))[0] \
            if t == dt.REAL32 else rng.uniform(-1e12, 1e12)
    if t == dt.BOOLEAN:
        return rng.randint(0, 1)
    if t in dt.SIGNED_TYPES:
        return rng.randint(-(1 << (bits - 1)), (1 << (bits - 1)) - 1)
    return rng.randint(0, (1 << bits) - 1)


_WIDTH = {dt.BOOLEAN: 8, dt.INTEGER8: 8, dt.UNSIGNED8: 8, dt.INTEGER16: 16,
          dt.UNSIGNED16: 16, dt.INTEGER32: 32, dt.UNSIGNED32: 32, dt.REAL32: 32,
          dt.INTEGER64: 64, dt.UNSIGNED64: 64, dt.REAL64: 64}


@pytest.mark.parametrize("mapping", [
    [(dt.UNSIGNED16, 16), (dt.INTEGER16, 16), (dt.INTEGER32, 32)],
    [(dt.INTEGER32, 32), (dt.INTEGER32, 32)],
    [(dt.INTEGER8, 8), (dt.UNSIGNED8, 8), (dt.REAL32, 32), (dt.INTEGER16, 16)],
    [(dt.INTEGER64, 64)],
    [(dt.REAL64, 64)],
    [(dt.BOOLEAN, 1), (dt.BOOLEAN, 1), (dt.UNSIGNED8, 6), (dt.INTEGER16, 16)],
    [(dt.UNSIGNED8, 4), (dt.UNSIGNED8, 4), (dt.INTEGER8, 8), (dt.UNSIGNED32, 32)],
])
def test_pdo_codec_matches_canopens_packing(mapping):
    types = [t for t, _ in mapping]
    od = _od_with(types)
    node = canopen.LocalNode(5, od)
    pdo = node.tpdo[1]
    pdo.clear()
    for i, (_t, bits) in enumerate(mapping):
        pdo.add_variable(0x2100 + i, 0, bits)
    codec = PdoCodec("TPDO1", [PdoEntry(0x2100 + i, 0, bits, t)
                               for i, (t, bits) in enumerate(mapping)])
    assert codec.length == len(pdo.data)
    rng = random.Random(7)
    for _ in range(300):
        values = [_random_value(rng, t, bits) for t, bits in mapping]
        pdo.data = bytearray(len(pdo.data))
        for var, v in zip(pdo.map, values, strict=True):
            if var.length == _WIDTH[var.od.data_type]:
                var.raw = v
            else:  # canopen packs a partial field from its full-width encoding
                var.set_data(var.od.STRUCT_TYPES[
                    dt.UNSIGNED8 if var.od.data_type == dt.BOOLEAN else var.od.data_type
                ].pack(v))
        assert codec.encode(values) == bytes(pdo.data)
        decoded = codec.decode(bytes(pdo.data))
        theirs = [var.od.decode_raw(var.get_data()) for var in pdo.map]
        assert list(decoded) == [int(x) if isinstance(x, bool) else x for x in theirs]
        assert list(decoded) == [int(v) if not isinstance(v, float) else v for v in values]


def test_pdo_codec_refuses_bad_mappings_and_payloads():
    with pytest.raises(PdoMappingError, match="TPDO3.*72 bits"):
        PdoCodec("TPDO3", [(0x2000, 0, 32, dt.INTEGER32), (0x2001, 0, 32, dt.INTEGER32),
                           (0x2002, 0, 8, dt.UNSIGNED8)])
    with pytest.raises(PdoMappingError, match="not a number"):
        PdoCodec("RPDO1", [(0x1008, 0, 32, dt.VISIBLE_STRING)])
    codec = PdoCodec("TPDO1 of node 5", [(0x6041, 0, 16, dt.UNSIGNED16),
                                         (0x606C, 0, 32, dt.INTEGER32)])
    with pytest.raises(FrameError, match="TPDO1 of node 5: 5 bytes, the mapping has 6"):
        codec.decode(b"\x00" * 5)
    with pytest.raises(FrameError):
        codec.decode(b"\x00" * 7)
    with pytest.raises(ValueError, match="0x606C:00 = 4294967296 does not fit"):
        codec.encode([1, 1 << 32])
    bits = PdoCodec("RPDO2", [(0x6200, 1, 4, dt.UNSIGNED8), (0x6401, 1, 12, dt.INTEGER16)])
    with pytest.raises(ValueError, match="0x6401:01 = 2048 does not fit 12 bits"):
        bits.encode([1, 2048])
    assert bits.decode(bits.encode([15, -2048])) == (15, -2048)
    od = canopen.import_od(str(EDS / FILES[IO]), IO)
    codec = compile_mapping("TPDO1 of node 32", od, [0x64010110, 0x64010310, 0x60000108])
    assert codec.decode(struct.pack("<hhB", -2, 3, 0x81)) == (-2, 3, 0x81)
    with pytest.raises(PdoMappingError, match="TPDO1 of node 32: maps 0x6401:09"):
        compile_mapping("TPDO1 of node 32", od, [0x64010910])  # array has 3 inputs


# ------------------------------------------------------------------ the rig on a virtual bus
class Recorder(can.Listener):
    def __init__(self) -> None:
        self.frames: list[tuple[float, int, bytes]] = []
        self.lock = threading.Lock()

    def on_message_received(self, msg: can.Message) -> None:
        with self.lock:
            # the send time (python-can's virtual bus stamps it), not when this thread woke
            self.frames.append((msg.timestamp, msg.arbitration_id, bytes(msg.data)))

    def mark(self) -> int:
        with self.lock:
            return len(self.frames)

    def since(self, mark: int, can_id: int | None = None) -> list[tuple[float, int, bytes]]:
        with self.lock:
            return [f for f in self.frames[mark:] if can_id is None or f[1] == can_id]

    def wait_for(self, mark: int, can_id: int, timeout: float = 1.0,
                  n: int = 1) -> list[tuple[float, int, bytes]]:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            got = self.since(mark, can_id)
            if len(got) >= n:
                return got
            time.sleep(0.002)
        return self.since(mark, can_id)


class Rig:
    """The four virtual nodes pumped by one thread (the nodes have none) and a canopen
    master on the same virtual channel."""

    def __init__(self) -> None:
        channel = f"canopen-node-test-{next(_channel)}-{time.monotonic_ns()}"
        self.bus = can.Bus(interface="virtual", channel=channel)
        self.lock = threading.RLock()

        def send(can_id: int, data: bytes) -> None:
            self.bus.send(can.Message(arbitration_id=can_id, data=data, is_extended_id=False))

        self.nodes = {nid: VirtualNode(nid, EDS / f, send) for nid, f in FILES.items()}
        self.wheel = Cia402Drive(self.nodes[WHEEL], "cst")
        self.rotor = Cia402Drive(self.nodes[ROTOR], "csv")
        self.io = Cia401Io(self.nodes[IO])
        self.encoder = Cia406Encoder(self.nodes[ENC])
        self.rec = Recorder()
        self.net = canopen.Network()
        self.net.listeners.append(self.rec)
        self.net.connect(interface="virtual", channel=channel)
        self.remote = {nid: self.net.add_node(nid, str(EDS / f)) for nid, f in FILES.items()}
        self.handled: dict[int, int] = {}  # frames the pump handed to the nodes, by id
        self._stop = threading.Event()
        self.thread = threading.Thread(target=self._pump, daemon=True)
        self.thread.start()
        for nid in FILES:  # every node booted before the test talks to it
            assert self.rec.wait_for(0, 0x700 + nid), f"node {nid}: no boot-up"

    def _pump(self) -> None:
        while not self._stop.is_set():
            msg = self.bus.recv(0.001)
            with self.lock:
                now = time.monotonic()
                if msg is not None:
                    for node in self.nodes.values():
                        node.handle(msg.arbitration_id, msg.data, now)
                    self.handled[msg.arbitration_id] = \
                        self.handled.get(msg.arbitration_id, 0) + 1
                for node in self.nodes.values():
                    node.poll(now)

    def close(self) -> None:
        self._stop.set()
        self.thread.join(2)
        self.net.disconnect()
        self.bus.shutdown()

    def send(self, can_id: int, data: bytes) -> None:
        """Sends a frame and returns once every node has handled it (whatever the load)."""
        with self.lock:
            before = self.handled.get(can_id, 0)
        self.net.send_message(can_id, data)
        end = time.monotonic() + 5
        while time.monotonic() < end:
            with self.lock:
                if self.handled.get(can_id, 0) > before:
                    break
            time.sleep(0.001)
        else:
            raise AssertionError(f"the pump did not handle frame 0x{can_id:X}")
        time.sleep(0.005)  # the nodes' answers reach the master's recorder

    def nmt(self, cmd: int, node_id: int = 0) -> None:
        self.send(0, bytes((cmd, node_id)))

    def sync(self) -> None:
        self.send(0x80, b"")

    def raw_sdo(self, node_id: int, frame: bytes) -> bytes:
        mark = self.rec.mark()
        self.net.send_message(0x600 + node_id, frame)
        got = self.rec.wait_for(mark, 0x580 + node_id)
        assert got, "no SDO answer"
        return got[0][2]


@pytest.fixture
def rig():
    r = Rig()
    yield r
    r.close()


def test_master_scans_every_node(rig):
    """The master's scan: reset communication, every boot-up, 0x1000, 0x1018 and the PDO
    mapping by SDO to an independent master."""
    mark = rig.rec.mark()
    rig.nmt(0x82)  # reset communication, all nodes
    for nid in FILES:
        boot = rig.rec.wait_for(mark, 0x700 + nid)
        assert boot and boot[0][2] == b"\x00", f"node {nid}: no boot-up frame"
    for nid, remote in rig.remote.items():
        od = canopen.import_od(str(EDS / FILES[nid]), nid)
        assert remote.sdo[0x1000].raw == od[0x1000].default
        for sub in range(1, 5):
            assert remote.sdo[0x1018][sub].raw == od[0x1018][sub].default
        remote.tpdo.read()
        remote.rpdo.read()
        for maps, base in ((remote.tpdo, 0x1A00), (remote.rpdo, 0x1600)):
            for n, pdo_map in maps.map.items():
                expected = [(w >> 16, (w >> 8) & 0xFF) for w in (
                    od[base + n - 1][i].default
                    for i in range(1, od[base + n - 1][0].default + 1))]
                assert [(v.index, v.subindex) for v in pdo_map.map] == expected
        assert remote.tpdo[1].enabled and remote.tpdo[1].trans_type == 1
        assert remote.tpdo[1].cob_id == 0x180 + nid


def test_boot_up_on_reset_node_and_reboot(rig):
    mark = rig.rec.mark()
    rig.nmt(0x81, IO)
    assert [f[2] for f in rig.rec.wait_for(mark, 0x700 + IO)] == [b"\x00"]
    assert rig.rec.since(mark, 0x700 + WHEEL) == []  # addressed to IO only
    assert rig.nodes[IO].state == NmtState.PRE_OPERATIONAL
    # a node that reboots mid-run (fault injection) loses its settings and says boot-up
    rig.remote[ENC].sdo[0x1017].raw = 20
    rig.nmt(0x01, ENC)
    mark = rig.rec.mark()
    with rig.lock:
        rig.nodes[ENC].reboot()
    frames = rig.rec.wait_for(mark, 0x700 + ENC)
    assert frames[0][2] == b"\x00"
    assert rig.nodes[ENC].state == NmtState.PRE_OPERATIONAL
    assert rig.remote[ENC].sdo[0x1017].raw == 0


def test_heartbeat_period_and_silence(rig):
    period_ms = 50
    rig.remote[WHEEL].sdo[0x1017].raw = period_ms
    mark = rig.rec.mark()
    time.sleep(0.8)
    beats = rig.rec.since(mark, 0x700 + WHEEL)
    assert all(b[2] == bytes((NmtState.PRE_OPERATIONAL,)) for b in beats)
    gaps = sorted(b[0] - a[0] for a, b in itertools.pairwise(beats))
    assert len(beats) >= 10
    # the median: a stall of this test's pump thread on a loaded host delays one beat (the
    # node then resumes one period later, never in a burst), the schedule itself is exact
    # (test_heartbeat_schedule_in_rig_time)
    assert abs(gaps[len(gaps) // 2] - period_ms / 1000) < 0.1 * period_ms / 1000, gaps
    assert gaps[0] > 0.5 * period_ms / 1000, gaps
    rig.nmt(0x02, WHEEL)
    mark = rig.rec.mark()
    beats = rig.rec.wait_for(mark, 0x700 + WHEEL, timeout=0.5)
    assert beats and beats[-1][2] == bytes((NmtState.STOPPED,))
    with rig.lock:
        rig.nodes[WHEEL].stop_heartbeat()
    time.sleep(0.06)
    mark = rig.rec.mark()
    time.sleep(0.3)
    assert rig.rec.since(mark, 0x700 + WHEEL) == []


def test_nmt_states_gate_pdos_and_sdo(rig):
    remote = rig.remote[ENC]
    with rig.lock:
        rig.encoder.set_position(-1234567)
        rig.encoder.set_speed(42)
    mark = rig.rec.mark()
    rig.sync()
    assert rig.rec.since(mark, 0x180 + ENC) == []  # pre-operational: no PDO
    rig.nmt(0x01, ENC)
    mark = rig.rec.mark()
    rig.sync()
    frames = rig.rec.wait_for(mark, 0x180 + ENC)
    assert [f[2] for f in frames] == [struct.pack("<ii", -1234567, 42)]
    rig.nmt(0x02, ENC)
    mark = rig.rec.mark()
    rig.sync()
    assert rig.rec.since(mark, 0x180 + ENC) == []
    with pytest.raises(SdoCommunicationError):
        remote.sdo.upload(0x1000, 0)  # stopped: no SDO
    rig.nmt(0x80, ENC)
    assert remote.sdo[0x1000].raw == 0x00020196
    mark = rig.rec.mark()
    rig.sync()
    assert rig.rec.since(mark, 0x180 + ENC) == []
    # wrong NMT state injected: the node stops sending PDOs although the master started it
    rig.nmt(0x01, ENC)
    with rig.lock:
        rig.nodes[ENC].force_nmt("stopped")
    mark = rig.rec.mark()
    rig.sync()
    assert rig.rec.since(mark, 0x180 + ENC) == []


def test_mapping_rewritten_by_the_master_then_pdos_carry_it(rig):
    remote = rig.remote[IO]
    remote.tpdo.read()
    tpdo = remote.tpdo[1]
    tpdo.clear()
    tpdo.add_variable(0x6401, 3)
    tpdo.add_variable(0x1001)
    tpdo.add_variable(0x6401, 1)
    tpdo.trans_type = 2
    tpdo.enabled = True
    tpdo.save()
    assert rig.nodes[IO].get(0x1A00, 0) == 3
    received = []
    tpdo.add_callback(lambda m: received.append([v.raw for v in m.map]))
    with rig.lock:
        rig.io.set_analog_inputs([-300, 7, 32767])
    rig.nmt(0x01, IO)
    mark = rig.rec.mark()
    for _ in range(4):
        rig.sync()
    frames = rig.rec.wait_for(mark, 0x180 + IO, n=2)
    assert [f[2] for f in frames] == [struct.pack("<hBh", 32767, 0, -300)] * 2  # every 2nd
    deadline = time.monotonic() + 1
    while not received and time.monotonic() < deadline:
        time.sleep(0.01)
    assert received[-1] == [32767, 0, -300]


def test_synchronous_rpdo_takes_effect_at_the_next_sync(rig):
    remote = rig.remote[WHEEL]
    for cw in (0x06, 0x07, 0x0F):
        remote.sdo[0x6040].raw = cw
    rig.nmt(0x01, WHEEL)
    rig.send(0x200 + WHEEL, struct.pack("<Hh", 0x0F, 400))
    with rig.lock:
        assert rig.wheel.torque_command_per_mille() == 0
    rig.sync()
    with rig.lock:
        assert rig.wheel.torque_command_per_mille() == 400
        rig.wheel.set_actuals(399, 123456)
    mark = rig.rec.mark()
    rig.sync()
    frame = rig.rec.wait_for(mark, 0x180 + WHEEL)[0][2]
    status, torque, velocity = struct.unpack("<Hhi", frame)
    assert status & 0x6F == 0x27 and (torque, velocity) == (399, 123456)
    # an RPDO of the wrong length is not processed: EMCY 0x8210
    mark = rig.rec.mark()
    rig.send(0x200 + WHEEL, b"\x0f\x00\x10")
    emcy = rig.rec.wait_for(mark, 0x80 + WHEEL)
    assert emcy and struct.unpack_from("<H", emcy[0][2])[0] == 0x8210
    rig.sync()
    with rig.lock:
        assert rig.wheel.torque_command_per_mille() == 400


def test_segmented_sdo(rig):
    remote = rig.remote[WHEEL]
    assert remote.sdo[0x1008].raw == "SGSRT reaction wheel drive"
    remote.sdo[0x2000].raw = "wheel on rig bay 3"
    assert remote.sdo[0x2000].raw == "wheel on rig bay 3"
    with rig.lock:
        assert rig.nodes[WHEEL].get(0x2000) == "wheel on rig bay 3"


def _abort(fn) -> int:
    with pytest.raises(SdoAbortedError) as exc:
        fn()
    return exc.value.code


def test_every_abort_code(rig):
    sdo = rig.remote[WHEEL].sdo
    assert _abort(lambda: sdo.upload(0x5555, 0)) == 0x06020000
    assert _abort(lambda: sdo.upload(0x1018, 9)) == 0x06090011
    assert _abort(lambda: sdo.download(0x1000, 0, b"\0\0\0\0")) == 0x06010002
    assert _abort(lambda: sdo.upload(0x2001, 0)) == 0x06010001
    assert _abort(lambda: sdo.download(0x1017, 0, b"\x01")) == 0x06070010
    assert _abort(lambda: sdo.download(0x6060, 0, b"\x01")) == 0x06090030  # mode 1 unsupported
    assert _abort(lambda: sdo.download(0x6007, 0, struct.pack("<h", 4))) == 0x06090031
    assert _abort(lambda: sdo.download(0x6007, 0, struct.pack("<h", -1))) == 0x06090032
    assert sdo[0x6060].raw == 10
    sdo.download(0x6060, 0, b"\x09")
    assert sdo[0x6061].raw == 9
    # block transfer is refused with "command specifier not valid"
    assert _abort(lambda: sdo.open(0x1008, 0, "rb", block_transfer=True).read()) == 0x05040001
    # unknown command specifier 7
    answer = rig.raw_sdo(WHEEL, bytes([0xE0, 0x00, 0x10, 0, 0, 0, 0, 0]))
    assert answer[0] == 0x80 and struct.unpack_from("<I", answer, 4)[0] == 0x05040001
    # toggle bit: segmented download of 0x2000, then a first segment with toggle 1
    answer = rig.raw_sdo(WHEEL, bytes([0x21, 0x00, 0x20, 0, 10, 0, 0, 0]))
    assert answer[0] == 0x60
    answer = rig.raw_sdo(WHEEL, bytes([0x10]) + b"abcdefg")
    assert answer[0] == 0x80 and struct.unpack_from("<I", answer, 4)[0] == 0x05030000
    assert struct.unpack_from("<HB", answer, 1) == (0x2000, 0)
    # segment upload with no transfer under way
    answer = rig.raw_sdo(WHEEL, bytes([0x60, 0, 0, 0, 0, 0, 0, 0]))
    assert struct.unpack_from("<I", answer, 4)[0] == 0x05040001
    # PDO mapping: over 64 bits, and an object that cannot be mapped
    tp = sdo[0x1800][1]
    tp.raw = tp.raw | 0x80000000
    sdo[0x1A00][0].raw = 0
    sdo[0x1A00][1].raw = 0x606C0020
    sdo[0x1A00][2].raw = 0x60FF0020
    sdo[0x1A00][3].raw = 0x60410010
    assert _abort(lambda: setattr(sdo[0x1A00][0], "raw", 3)) == 0x06040042
    assert _abort(lambda: setattr(sdo[0x1A00][4], "raw", 0x10000020)) == 0x06040041
    assert _abort(lambda: setattr(sdo[0x1A00][4], "raw", 0x60410020)) == 0x06040041  # length
    # the mapping of a valid PDO cannot be written
    sdo[0x1A00][0].raw = 2
    tp.raw = tp.raw & ~0x80000000
    assert _abort(lambda: setattr(sdo[0x1A00][1], "raw", 0x60410010)) == 0x08000022
    # an abort injected by the virtual rig, once
    with rig.lock:
        rig.nodes[WHEEL].sdo_abort_next(0x1000, 0x08000020)
    assert _abort(lambda: sdo[0x1000].raw) == 0x08000020
    assert sdo[0x1000].raw == 0x00020192


def _heartbeat_from_master(rig: Rig, period_s: float = 0.02):
    return rig.net.send_periodic(0x700 + MASTER_ID, bytes((NmtState.OPERATIONAL,)), period_s)


def test_heartbeat_loss_sets_cia401_outputs_to_error_values(rig):
    remote = rig.remote[IO]
    remote.sdo[0x6444][1].raw = 1234
    remote.sdo[0x6207][1].raw = 0x04
    # 250 ms, the rig's watchdog: a loaded host's stall of the pump is no heartbeat loss
    remote.sdo[0x1016][1].raw = MASTER_ID << 16 | 250
    task = _heartbeat_from_master(rig)
    rig.nmt(0x01, IO)
    rig.send(0x200 + IO, b"\x03")  # both valves open
    rig.send(0x300 + IO, struct.pack("<hh", 5000, -5000))
    rig.sync()
    with rig.lock:
        assert rig.io.digital_outputs() == 0x03
        assert rig.io.analog_outputs() == [5000, -5000]
    time.sleep(0.3)  # heartbeat alive: nothing happens
    assert rig.nodes[IO].state == NmtState.OPERATIONAL
    mark = rig.rec.mark()
    task.stop()
    emcy = rig.rec.wait_for(mark, 0x80 + IO, timeout=2.0)
    assert emcy, "no EMCY on heartbeat loss"
    code, register, vendor = struct.unpack("<HB5s", emcy[0][2])
    assert code == 0x8130 and register & 0x11 == 0x11 and vendor[0] == MASTER_ID
    time.sleep(0.02)
    with rig.lock:
        assert rig.io.digital_outputs() == 0x04  # 0x6206 = 0xFF: every bit to 0x6207
        assert rig.io.analog_outputs() == [1234, 0]
        assert rig.nodes[IO].state == NmtState.PRE_OPERATIONAL  # 0x1029:1 = 0
    assert remote.sdo[0x1001].raw & 0x10
    assert remote.sdo[0x1003][0].raw == 1 and remote.sdo[0x1003][1].raw == 0x8130
    remote.sdo[0x1003][0].raw = 0  # the master clears the error history
    assert remote.sdo[0x1003][0].raw == 0 and remote.sdo[0x1003][1].raw == 0
    assert _abort(lambda: setattr(remote.sdo[0x1003][0], "raw", 2)) == 0x06090030
    # the master's heartbeat comes back: EMCY error reset, register clear
    mark = rig.rec.mark()
    task = _heartbeat_from_master(rig)
    emcy = rig.rec.wait_for(mark, 0x80 + IO, timeout=2.0)
    task.stop()
    assert emcy and emcy[0][2] == b"\x00" * 8
    # NMT stop of an operational module: the outputs go to their error values too
    rig.nmt(0x01, IO)
    rig.send(0x200 + IO, b"\x01")
    rig.sync()
    with rig.lock:
        assert rig.io.digital_outputs() == 0x01
    rig.nmt(0x02, IO)
    with rig.lock:
        assert rig.io.digital_outputs() == 0x04


def test_heartbeat_loss_stops_the_drive_by_its_own_error_behaviour(rig):
    remote = rig.remote[WHEEL]
    remote.sdo[0x1029][1].raw = 2  # stopped
    remote.sdo[0x6007].raw = 2  # disable voltage
    remote.sdo[0x1016][1].raw = MASTER_ID << 16 | 250
    remote.sdo[0x1017].raw = 20
    for cw in (0x06, 0x07, 0x0F):
        remote.sdo[0x6040].raw = cw
    remote.sdo[0x6071].raw = 300
    task = _heartbeat_from_master(rig)
    rig.nmt(0x01, WHEEL)
    rig.sync()
    with rig.lock:
        assert rig.wheel.torque_command_per_mille() == 300
    mark = rig.rec.mark()
    task.stop()
    emcy = rig.rec.wait_for(mark, 0x80 + WHEEL, timeout=2.0)
    assert emcy and struct.unpack_from("<H", emcy[0][2])[0] == 0x8130
    time.sleep(0.05)
    with rig.lock:
        assert rig.nodes[WHEEL].state == NmtState.STOPPED
        assert rig.wheel.state == DriveState.SWITCH_ON_DISABLED
        assert rig.wheel.torque_command_per_mille() == 0
    beats = rig.rec.wait_for(rig.rec.mark(), 0x700 + WHEEL, timeout=0.5)
    assert beats and beats[-1][2] == bytes((NmtState.STOPPED,))


def test_cia402_state_machine_and_fault(rig):
    remote = rig.remote[WHEEL]

    def status() -> int:
        return remote.sdo[0x6041].raw

    assert status() & 0x4F == 0x40  # switch on disabled
    remote.sdo[0x6040].raw = 0x06
    assert status() & 0x6F == 0x21  # ready to switch on
    remote.sdo[0x6040].raw = 0x07
    assert status() & 0x6F == 0x23  # switched on
    remote.sdo[0x6071].raw = 900
    with rig.lock:
        assert rig.wheel.torque_command_per_mille() == 0  # not yet enabled
    remote.sdo[0x6040].raw = 0x0F
    assert status() & 0x6F == 0x27  # operation enabled
    with rig.lock:
        assert rig.wheel.torque_command_per_mille() == 900
    remote.sdo[0x6040].raw = 0x02  # quick stop
    assert status() & 0x6F == 0x07
    with rig.lock:
        assert rig.wheel.torque_command_per_mille() == 0
    remote.sdo[0x6040].raw = 0x0F
    assert status() & 0x6F == 0x27
    remote.sdo[0x6060].raw = 9  # other mode: the CST command is no longer followed
    with rig.lock:
        assert rig.wheel.torque_command_per_mille() == 0
    remote.sdo[0x6060].raw = 10
    rig.nmt(0x01, WHEEL)
    mark = rig.rec.mark()
    with rig.lock:
        rig.wheel.inject_fault(0x2310)
        assert rig.wheel.torque_command_per_mille() == 0
    emcy = rig.rec.wait_for(mark, 0x80 + WHEEL)
    code, register, _ = struct.unpack("<HB5s", emcy[0][2])
    assert code == 0x2310 and register & 0x03 == 0x03
    assert status() & 0x4F == 0x0F  # fault reaction active
    rig.sync()
    assert status() & 0x4F == 0x08  # fault
    assert remote.sdo[0x603F].raw == 0x2310
    remote.sdo[0x6040].raw = 0x0F  # no fault reset: stays in fault
    assert status() & 0x4F == 0x08
    mark = rig.rec.mark()
    remote.sdo[0x6040].raw = 0x80  # fault reset (rising edge of bit 7)
    assert status() & 0x4F == 0x40
    assert rig.rec.wait_for(mark, 0x80 + WHEEL)[0][2][:3] == b"\x00\x00\x00"
    assert remote.sdo[0x603F].raw == 0


def test_reset_communication_aborts_an_enabled_drives_connection(rig):
    remote = rig.remote[ROTOR]
    remote.sdo[0x6007].raw = 3  # quick stop
    for cw in (0x06, 0x07, 0x0F):
        remote.sdo[0x6040].raw = cw
    remote.sdo[0x60FF].raw = 20000
    rig.nmt(0x82, ROTOR)
    with rig.lock:
        assert rig.rotor.state == DriveState.QUICK_STOP_ACTIVE
        assert rig.rotor.target_velocity_raw() == 0
    rig.nmt(0x81, ROTOR)  # reset node: the application restarts disabled
    with rig.lock:
        assert rig.rotor.state == DriveState.SWITCH_ON_DISABLED
        assert rig.nodes[ROTOR].get(0x6007) == 1


def test_rotor_csv_and_encoder_wrap(rig):
    remote = rig.remote[ROTOR]
    assert _abort(lambda: remote.sdo.download(0x6060, 0, b"\x0a")) == 0x06090030  # CSV only
    for cw in (0x06, 0x07, 0x0F):
        remote.sdo[0x6040].raw = cw
    remote.sdo[0x60FF].raw = -25000
    with rig.lock:
        assert rig.rotor.target_velocity_raw() == -25000
        rig.encoder.set_position((1 << 31) + 5)  # beyond INTEGER32: wraps
        assert rig.nodes[ENC].get(0x6004) == -(1 << 31) + 5
    with pytest.raises(ValueError, match="CiA 402"):
        Cia402Drive(rig.nodes[IO], "cst")
    with pytest.raises(ValueError, match="mode: 10 is not supported"):
        Cia402Drive(rig.nodes[ROTOR], "cst")


@pytest.mark.filterwarnings("ignore:The 'warn' method is deprecated:DeprecationWarning")
def test_bad_eds_and_node_id_are_named(tmp_path):
    def send(_can_id: int, _data: bytes) -> None:
        pass

    with pytest.raises(ValueError, match="node_id: 0 is not a CANopen node id"):
        VirtualNode(0, EDS / FILES[WHEEL], send)
    with pytest.raises(FileNotFoundError, match="eds_path: no EDS file"):
        VirtualNode(5, tmp_path / "missing.eds", send)
    broken = tmp_path / "broken.eds"
    broken.write_text("[1000]\nParameterName=Device type\n")
    with pytest.raises(ValueError, match="broken.eds: not a loadable EDS"):
        VirtualNode(5, broken, send)
    text = (EDS / FILES[ENC]).read_text()
    bad_map = tmp_path / "bad_map.eds"
    bad_map.write_text(text.replace("DefaultValue=0x60040020", "DefaultValue=0x70040020"))
    # a default mapping the node cannot carry is the master's to rewrite (it maps every
    # PDO it uses during set-up): the PDO sends nothing until then, the node works
    node = VirtualNode(5, bad_map, send)
    tpdo1 = next(p for p in node._pdos if p.is_tpdo and p.number == 1)
    assert tpdo1.codec is None and "maps 0x7004:00" in (tpdo1.problem or "")


def test_heartbeat_schedule_in_rig_time():
    """Pumped in lockstep (rig time, no thread): beats exactly at the 0x1017 period, and
    a stalled pump gets one beat, not a burst."""
    sent: list[tuple[float, int, bytes]] = []
    now = 0.0
    node = VirtualNode(ENC, EDS / FILES[ENC], lambda c, d: sent.append((now, c, d)))
    node.poll(now)
    assert sent == [(0.0, 0x700 + ENC, b"\x00")]
    node.handle(0x600 + ENC, struct.pack("<BHBH2x", 0x2B, 0x1017, 0, 25), now)
    for k in range(1, 201):  # 1 ms steps
        now = k / 1000
        node.poll(now)
    beats = [t for t, c, d in sent if c == 0x700 + ENC and d == b"\x7f"]
    assert beats == pytest.approx([0.025 * k for k in range(1, 9)])
    now = 0.5  # the pump stalled for 300 ms
    node.poll(now)
    now = 0.501
    node.poll(now)
    assert [t for t, c, d in sent if c == 0x700 + ENC][-1] == 0.5
    assert len([t for t, c, d in sent if c == 0x700 + ENC and t > 0.2]) == 1


def test_sync_start_value_sets_the_tpdo_phase():
    """TPDO type 3 with SYNC start value 2: counted from the SYNC whose counter is 2, so it
    goes out at counters 4, 7, 10 (lockstep, no thread)."""
    sent: list[tuple[int, bytes]] = []
    node = VirtualNode(ENC, EDS / FILES[ENC], lambda c, d: sent.append((c, d)))
    node.poll(0.0)

    def sdo_write(index: int, sub: int, fmt: str, value: int) -> bytes:
        size = struct.calcsize("<" + fmt)
        node.handle(0x600 + ENC, struct.pack("<BHB", 0x23 | (4 - size) << 2, index, sub)
                    + struct.pack("<" + fmt, value).ljust(4, b"\0"), 0.0)
        return sent[-1][1]

    assert sdo_write(0x1800, 2, "B", 3)[0] == 0x60
    assert sdo_write(0x1800, 6, "B", 2)[0] == 0x60
    answer = sdo_write(0x1800, 6, "B", 241)
    assert answer[0] == 0x80 and struct.unpack_from("<I", answer, 4)[0] == 0x06090031
    node.handle(0, bytes((0x01, ENC)), 0.0)
    tx = []
    sent.clear()
    for counter in range(1, 12):
        node.handle(0x80, bytes((counter,)), counter * 0.002)
        tx += [counter for c, _ in sent if c == 0x180 + ENC]
        sent.clear()
    assert tx == [4, 7, 10]
