"""``CopyingVirtualBus.send_owned``: the other end receives the sender's own message with
the fields ``send``'s copy would have had; any other channel layout takes ``send``."""

from __future__ import annotations

import can

from harness.bus import open_bus, parse_bus

FIELDS = ("arbitration_id", "is_extended_id", "is_remote_frame", "is_error_frame", "channel",
          "dlc", "data", "is_rx", "is_fd", "bitrate_switch", "error_state_indicator")


def _fields(msg: can.Message) -> tuple:
    return tuple(getattr(msg, f) for f in FIELDS)


def _frames() -> list[can.Message]:
    return [can.Message(arbitration_id=0x101, data=b"\x01\x02\x03", is_extended_id=False),
            can.Message(arbitration_id=0x1ABCDE, data=bytes(8), is_extended_id=True),
            can.Message(arbitration_id=0x7FF, data=b"", is_extended_id=False)]


def test_the_other_end_gets_what_send_would_have_given(tmp_path) -> None:
    spec = parse_bus("virtual:owned-test")
    a, b = open_bus(spec), open_bus(spec)
    try:
        for plain, owned in zip(_frames(), _frames(), strict=True):
            a.send(plain)
            got_plain = b.recv(0)
            a.send_owned(owned)
            got_owned = b.recv(0)
            assert got_owned is owned  # no copy
            assert _fields(got_owned) == _fields(got_plain)
            assert got_owned.timestamp >= got_plain.timestamp > 0
            assert a.recv(0) is None  # not to its own end
    finally:
        a.shutdown()
        b.shutdown()


def test_three_ends_get_copies_as_send_gives() -> None:
    spec = parse_bus("virtual:owned-test-3")
    a, b, c = open_bus(spec), open_bus(spec), open_bus(spec)
    try:
        msg = _frames()[0]
        before = _fields(msg) + (msg.timestamp,)
        a.send_owned(msg)
        got_b, got_c = b.recv(0), c.recv(0)
        assert got_b is not msg and got_c is not msg and got_b is not got_c
        assert _fields(got_b) == _fields(got_c)
        assert got_b.is_rx and got_b.channel == "owned-test-3"
        assert _fields(msg) + (msg.timestamp,) == before  # untouched, as send leaves it
    finally:
        for bus in (a, b, c):
            bus.shutdown()
