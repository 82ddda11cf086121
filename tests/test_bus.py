"""The in-process bus: interoperable with python-can's own virtual bus, same semantics."""

from __future__ import annotations

import can
import pytest

from harness.bus import BusSpecError, CopyingVirtualBus, open_bus, parse_bus


def _frame(i: int) -> can.Message:
    return can.Message(arbitration_id=0x200 + i, data=bytes([i] * 8), is_extended_id=False)


def test_fast_bus_and_python_can_virtual_bus_see_each_other_in_order():
    fast = CopyingVirtualBus(channel="interop")
    plain = can.Bus(interface="virtual", channel="interop")
    try:
        for i in range(5):
            fast.send(_frame(i))
        got = [plain.recv(0.5) for _ in range(5)]
        assert [m.arbitration_id for m in got] == [0x200 + i for i in range(5)]
        assert all(m.is_rx and m.channel == "interop" for m in got)
        assert got[3].data == bytes([3] * 8)
        plain.send(_frame(7))
        msg = fast.recv(0)
        assert msg is not None and msg.arbitration_id == 0x207 and msg.is_rx
        assert fast.recv(0) is None  # empty: non-blocking, no exception
        assert plain.recv(0) is None  # a bus does not hear itself
    finally:
        fast.shutdown()
        plain.shutdown()


def test_sender_keeps_its_message_and_receivers_get_copies():
    a = CopyingVirtualBus(channel="copies")
    b = CopyingVirtualBus(channel="copies")
    try:
        msg = _frame(1)
        msg.is_rx = False
        a.send(msg)
        got = b.recv(0)
        assert got is not msg and got.data == msg.data
        assert not msg.is_rx
    finally:
        a.shutdown()
        b.shutdown()


def test_filters_and_blocking_timeouts_use_python_cans_path():
    a = CopyingVirtualBus(channel="filters")
    b = CopyingVirtualBus(channel="filters", can_filters=[{"can_id": 0x201, "can_mask": 0x7FF}])
    try:
        a.send(_frame(0))
        a.send(_frame(1))
        got = b.recv(0.1)  # python-can's loop skips the filtered 0x200
        assert got is not None and got.arbitration_id == 0x201
        assert b.recv(0.01) is None
    finally:
        a.shutdown()
        b.shutdown()


def test_closed_bus_refuses_and_udp_multicast_is_refused():
    bus = open_bus(parse_bus("virtual:closed"))
    bus.shutdown()
    with pytest.raises(can.CanOperationError):
        bus.recv(0)
    with pytest.raises(BusSpecError, match="udp_multicast"):
        parse_bus("udp_multicast:224.0.0.1")


def test_only_the_benign_socketcand_split_warning_is_dropped():
    import logging

    from harness.bus import _BenignSplitFilter

    f = _BenignSplitFilter()

    def rec(msg: str) -> logging.LogRecord:
        return logging.LogRecord("can.interfaces.socketcand.socketcand", logging.WARNING,
                                 __file__, 1, msg, None, None)

    assert not f.filter(rec("Got incomplete message => waiting for more data"))
    assert f.filter(rec("Incomplete message exceeds 200 chars => Discarding"))
    assert f.filter(rec("Invalid Frame: < frame 123 >"))
