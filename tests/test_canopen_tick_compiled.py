"""The CANopen tick: the CANopen path's compiled forms equal the plain forms they replace.

The virtual nodes pack TPDOs through `PdoCodec.packer`, the rig writes telemetry into the
nodes' objects through `CanopenDevices.telemetry_writer`, the harness decodes TPDOs through
`PdoTelemetryMap.decode` (compiled), a node's `poll` returns early until something is due,
and a CiA 402 drive skips a controlword that already left its state unchanged. Each is
checked against the reference computation on the real rig file's bindings, values at and
past the objects' ranges included.
"""

from __future__ import annotations

import random

import can
import pytest

from drivers.canopen_pdo import PdoCodec, PdoEntry
from drivers.dbc import FrameError
from rig_models.canopen.node import NmtState, VirtualNode
from rig_models.canopen.profiles import Cia402Drive, DriveState
from rig_models.canopen.rig_devices import CanopenDevices
from rig_models.rig_file import load_rig
from rig_models.virtual_rig import TELEMETRY_QUANTITIES

CO = load_rig("sgsrt-canopen").binding.canopen


def _extremes(rng: random.Random) -> float:
    return rng.choice([0.0, -0.0, 1e-9, -1e-9, 1.0, -1.0, 0.5, 2.5, 1e6, -1e6, 1e12, -1e12,
                       rng.uniform(-50, 50), rng.uniform(-1, 1), rng.uniform(0, 300)])


def test_packer_is_encode_byte_for_byte_and_error_for_error():
    from canopen.objectdictionary import datatypes as dt

    codecs = [PdoCodec("aligned", [PdoEntry(0x6077, 0, 16, dt.INTEGER16),
                                   PdoEntry(0x606C, 0, 32, dt.INTEGER32),
                                   PdoEntry(0x6041, 0, 16, dt.UNSIGNED16)]),
              PdoCodec("packed", [PdoEntry(0x6200, 1, 1, dt.BOOLEAN),
                                  PdoEntry(0x6401, 1, 12, dt.UNSIGNED16),
                                  PdoEntry(0x6401, 2, 20, dt.INTEGER32)]),
              PdoCodec("real", [PdoEntry(0x7000, 0, 32, dt.REAL32)])]
    rng = random.Random(5)
    for codec in codecs:
        pack = codec.packer()
        for _ in range(300):
            values = []
            for e in codec.entries:
                if e.data_type == dt.REAL32:
                    values.append(rng.uniform(-1e3, 1e3))
                else:
                    values.append(rng.randint(-(1 << e.bit_length), 1 << e.bit_length))
            try:
                want: bytes | str = codec.encode(values)
            except ValueError as exc:
                want = str(exc)
            try:
                got: bytes | str = pack(*values)
            except ValueError as exc:
                got = str(exc)
            assert got == want, (codec.name, values)
        with pytest.raises(ValueError, match="values for"):
            pack(*([0] * (len(codec.entries) + 1)))


def _devices() -> CanopenDevices:
    return CanopenDevices(CO, lambda can_id, data: None)


@pytest.mark.parametrize("device", sorted(TELEMETRY_QUANTITIES))
def test_telemetry_writer_writes_what_write_telemetry_writes(device):
    names = TELEMETRY_QUANTITIES[device]
    a, b = _devices(), _devices()
    node_a, node_b = a.node_of(device), b.node_of(device)
    if node_a is None:
        pytest.skip(f"{device} has no CANopen node on sgsrt-canopen")
    write = b.telemetry_writer(device, names)
    rng = random.Random(device)
    for _ in range(400):
        values = [_extremes(rng) if rng.random() < 0.7 else float(rng.randint(0, 3))
                  for _ in names]
        a.write_telemetry(device, dict(zip(names, values, strict=True)))
        write(*values)
        assert node_a.values == node_b.values, values
        for key, v in node_a.values.items():  # the types too: an int object stays int
            assert type(node_b.values[key]) is type(v), key


def test_compiled_pdo_decoder_is_the_reference_dictcomp():
    rng = random.Random(1)
    checked = 0
    for node in CO.nodes.values():
        for maps in node.telemetry.values():
            for q in maps:
                assert q.conv.si_function() is not None
    for tmap in (m for maps in load_rig("sgsrt-canopen").binding.telemetry.values()
                 for m in maps):
        codec = tmap.codec
        for _ in range(200):
            data = bytes(rng.randrange(256) for _ in range(codec.length))
            raw = codec.decode_raw(data)
            want = {q: conv(raw[i]) for q, i, conv in tmap._f}
            got = tmap.decode(data)
            assert got == want and list(got) == list(want), (tmap.device, data.hex())
            checked += 1
        with pytest.raises(FrameError, match=r"\d+ bytes"):
            tmap.decode(bytes(codec.length + 1))
    assert checked >= 1000


class _Sent:
    def __init__(self) -> None:
        self.frames: list[tuple[float, int, bytes]] = []
        self.now = 0.0

    def __call__(self, can_id: int, data: bytes) -> None:
        self.frames.append((self.now, can_id, bytes(data)))


def _pumped(node: VirtualNode, sent: _Sent, step_s: float, until_s: float,
            master_hb_until_s: float) -> list[tuple[float, int, bytes]]:
    """A lockstep pump: poll every step; the master's heartbeat every 50 ms from 0.1 s (the
    consumer is polled before it has seen one) until ``master_hb_until_s``, then silence
    (the node's consumer must time out)."""
    t = 0.0
    k = 0
    while t < until_s:
        sent.now = t
        if 0.1 <= t < master_hb_until_s and k % 25 == 0:
            node.handle(0x701, b"\x05", t)
        node.poll(t)
        k += 1
        t = k * step_s
    return sent.frames


@pytest.mark.parametrize("producer_ms", [30, 0])
def test_poll_early_return_keeps_heartbeat_and_consumer_timing(producer_ms):
    from drivers.binding.canopen import EMCY_BASE

    sent = _Sent()
    node = VirtualNode(2, CO.nodes[2].eds, sent)
    node.poll(0.0)
    node.set(0x1017, 0, producer_ms)  # 0: no heartbeat of its own, only the consumer
    node.set(0x1016, 1, (1 << 16) | 120)  # consumer of node 1, 120 ms
    node._reconfigure()
    node._hb_next = producer_ms / 1000.0 if producer_ms else None
    node.handle(0, bytes((1, 2)), 0.0)  # start
    frames = _pumped(node, sent, 0.002, 1.0, master_hb_until_s=0.5)
    hb = [t for t, cid, d in frames if cid == 0x702 and d != b"\x00"]  # not the boot-up
    if producer_ms:
        assert len(hb) >= 30
        assert all(abs((b - a) - 0.03) < 0.0021 for a, b in zip(hb, hb[1:], strict=False))
    else:
        assert hb == []
    emcy = [t for t, cid, d in frames if cid == EMCY_BASE + 2 and d[:2] == b"\x30\x81"]
    # the master's last heartbeat at 0.45 s (every 25th step of 2 ms): timeout 120 ms later
    assert emcy and 0.45 + 0.12 - 1e-9 <= emcy[0] <= 0.45 + 0.12 + 0.0021, emcy
    assert node.state == NmtState.PRE_OPERATIONAL


def test_a_repeated_fault_reset_controlword_goes_on_through_the_state_machine():
    # 0x86 (fault reset + shutdown): FAULT -> switch on disabled on its rising edge, then
    # the same word again is a shutdown -> ready to switch on: a skip of "the same word
    # again" must not swallow it
    node = VirtualNode(2, CO.nodes[2].eds, lambda can_id, data: None)
    node.poll(0.0)
    drive = Cia402Drive(node, 10)
    node.handle(0, bytes((1, 2)), 0.0)
    for cw in (0x06, 0x07, 0x0F):
        node._master_write((0x6040, 0), cw)
    assert drive.state == DriveState.OPERATION_ENABLED
    node._master_write((0x6040, 0), 0x0F)  # the same word: nothing changes
    assert drive.state == DriveState.OPERATION_ENABLED
    drive.inject_fault()
    node.handle(0x80, b"\x01", 0.002)  # a SYNC: fault reaction -> fault
    assert drive.state == DriveState.FAULT
    node._master_write((0x6040, 0), 0x0F)
    assert drive.state == DriveState.FAULT
    node._master_write((0x6040, 0), 0x86)
    assert drive.state == DriveState.SWITCH_ON_DISABLED
    node._master_write((0x6040, 0), 0x86)
    assert drive.state == DriveState.READY_TO_SWITCH_ON
    assert drive.statusword & 0x6F == 0x21  # ready to switch on, published
    node._master_write((0x6040, 0), 0x86)
    assert drive.state == DriveState.READY_TO_SWITCH_ON


def test_a_run_without_faults_sends_the_nodes_frames_straight_and_counts_them():
    from rig_models.virtual_rig import VirtualRig

    bus = can.Bus(interface="virtual", channel="co-tick-compiled", receive_own_messages=False)
    listener = can.Bus(interface="virtual", channel="co-tick-compiled")
    try:
        rig = VirtualRig(load_rig("sgsrt-canopen"), bus, 0.002)
        booted = [listener.recv(0.5) for _ in range(4)]
        assert sorted(m.arbitration_id for m in booted) == [0x702, 0x703, 0x704, 0x705]
        assert rig.counters.frames_out == 4
    finally:
        bus.shutdown()
        listener.shutdown()


def test_compiled_command_encoder_is_encode_byte_for_byte():
    from drivers.binding.quantities import COMMANDS

    rng = random.Random(3)
    checked = 0
    for maps in load_rig("sgsrt-canopen").binding.commands.values():
        for cmap in maps:
            names = tuple(COMMANDS[cmap.device])
            encode = cmap.encoder(names)
            for _ in range(300):
                values = [_extremes(rng) if rng.random() < 0.6 else float(rng.randint(0, 2))
                          for _ in names]
                assert encode(*values, rng.randrange(256)) == cmap.encode(
                    dict(zip(names, values, strict=True))), (cmap.device, values)
                checked += 1
    assert checked >= 900
