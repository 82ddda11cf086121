"""The CAN log packs frames in bulk: the file is byte for byte what python-can's
own BLF writer makes of the same frames."""

from __future__ import annotations

from pathlib import Path

import can
from can.util import channel2int

from harness.record.can_log import CONTAINER_BYTES, CanLog, read_can_log


def _frames() -> list[can.Message]:
    out = []
    for k in range(3000):  # several containers
        ts = 1_700_000_000.123456 + k * 0.0004
        kind = k % 9
        if kind == 5:
            out.append(can.Message(arbitration_id=0x080, is_error_frame=True, data=bytes(8),
                                   timestamp=ts, channel="sgsrt"))
        elif kind == 7:
            out.append(can.Message(arbitration_id=0x1ABCDE, is_extended_id=True, is_fd=True,
                                   data=bytes(range(12)), timestamp=ts, channel="can1",
                                   is_rx=False))
        else:
            out.append(can.Message(
                arbitration_id=(0x100 + k) & 0x7FF, is_extended_id=kind == 1,
                is_remote_frame=kind == 2, data=b"" if kind == 2 else bytes([k & 0xFF] * (k % 9)),
                dlc=3 if kind == 2 else None, timestamp=ts, is_rx=kind != 3,
                channel=("sgsrt", 0, "vcan2", None, 70000)[k % 5]))
    return out


def _python_can_file(path: Path, frames: list[can.Message]) -> None:
    writer = can.BLFWriter(str(path), compression_level=1, max_container_size=CONTAINER_BYTES)
    for msg in frames:
        n = channel2int(msg.channel) if msg.channel is not None else None
        msg = can.Message(**{**{s: getattr(msg, s) for s in (
            "timestamp", "arbitration_id", "is_extended_id", "is_remote_frame",
            "is_error_frame", "dlc", "data", "is_fd", "is_rx")},
            "channel": msg.channel if n is not None and 0 <= n < 65535 else None})
        writer.on_message_received(msg)
    writer.stop()


def test_bulk_packed_log_is_what_python_can_writes(tmp_path):
    frames = _frames()
    ref = tmp_path / "ref.blf"
    _python_can_file(ref, frames)
    log = CanLog(tmp_path / "ours.blf", flush_every_s=1e9)  # python-can never flushes early
    for k, msg in enumerate(frames):
        log.log(msg)
        if k % 37 == 0:
            log.drain()
    log.close()
    assert (tmp_path / "ours.blf").read_bytes() == ref.read_bytes()
    back = read_can_log(tmp_path / "ours.blf")
    assert len(back) == len(frames)
    assert [(m.arbitration_id, bytes(m.data)) for m in back] == [
        (m.arbitration_id, bytes(m.data)) for m in frames]
