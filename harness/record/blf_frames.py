"""A run's CAN log read back fast: the frames of a BLF file as python-can's ``BLFReader``
gives them, field for field, without a ``can.Message`` and a ``Decimal`` per frame.

Every run's review decodes its whole can.blf after the run (the bus view, the left-safe
judge): python-can's reader costs about as much per frame as the run's own tick spent on
it (a Decimal timestamp and a Message per frame), a quarter of a lockstep run's CPU (issue
23). The log this harness writes is containers of CAN_MESSAGE objects of one size; such a
container is parsed with numpy in one pass. Any other object (error frames, CAN FD, another
writer's log) goes through python-can's own parser for that container, so what comes out is
always what ``BLFReader`` gives: ``tests/test_blf_frames.py`` compares them on real runs,
faults with error frames included.

Memory is one container (and a partial object carried into the next), whatever the log's
length, and bounded whatever the file says: an object larger than ``MAX_OBJECT_BYTES``, a
container that inflates past ``MAX_CONTAINER_BYTES`` (a 1 MB zlib bomb inflated to
gigabytes) or a partial object carried past that size is refused (``BLFParseError`` naming
the size) before it is read or inflated further.
"""

from __future__ import annotations

import zlib
from collections.abc import Iterator
from itertools import repeat
from pathlib import Path
from typing import NamedTuple

import numpy as np
from can.io import blf as _blf

# a CAN_MESSAGE (or CAN_MESSAGE2) object with a version 1 header: 16 bytes base header,
# 16 bytes v1 header, 16 bytes message (channel, flags, dlc, id, 8 data bytes)
_OBJ_BYTES = 48
_MSG = np.dtype([("sig", "S4"), ("header_size", "<u2"), ("header_version", "<u2"),
                 ("obj_size", "<u4"), ("obj_type", "<u4"), ("flags", "<u4"),
                 ("client", "<u2"), ("obj_version", "<u2"), ("timestamp", "<u8"),
                 ("channel", "<u2"), ("msg_flags", "u1"), ("dlc", "u1"), ("can_id", "<u4"),
                 ("data", "S8")])
assert _MSG.itemsize == _OBJ_BYTES

MAX_CONTAINER_BYTES = 16 * 1024 * 1024
"""The most a container may inflate to: python-can writes containers of 128 KiB."""

MAX_OBJECT_BYTES = MAX_CONTAINER_BYTES + 4096
"""The largest object (a compressed container is smaller than what it inflates to)."""
_EXACT_NS = 1 << 53  # integer nanoseconds a float64 holds exactly (about 104 days)


class Frame(NamedTuple):
    """One frame of the log: ``can.Message``'s fields that the review reads, in the order
    ``read_frames`` yields them (as plain tuples: unpack them, a tuple a frame is what
    makes the reader cheap)."""

    timestamp: float
    arbitration_id: int
    is_extended_id: bool
    is_remote_frame: bool
    is_error_frame: bool
    is_rx: bool
    dlc: int
    data: bytes
    channel: int


def frame_tuple(m: object) -> tuple:  # type: ignore[type-arg]
    """A ``can.Message`` as ``read_frames`` gives a frame (``Frame``'s fields, in order)."""
    return (float(m.timestamp), m.arbitration_id, m.is_extended_id,  # type: ignore[attr-defined]
                 m.is_remote_frame, m.is_error_frame, m.is_rx, m.dlc,  # type: ignore[attr-defined]
                 bytes(m.data), m.channel)  # type: ignore[attr-defined]


class _Fallback(_blf.BLFReader):
    """python-can's container parser on its own (no file): the tail and position state."""

    def __init__(self, start_timestamp: float) -> None:  # noqa: D107 - no file to open
        self.start_timestamp = start_timestamp
        self._tail = b""
        self._pos = 0


def _containers(path: str | Path
                ) -> Iterator[tuple[tuple[np.ndarray, np.ndarray] | None, list[tuple]]]:  # type: ignore[type-arg]
    """Per container: (its CAN messages as one numpy array, []) on the fast path, or
    (None, its frames as tuples from python-can's parser)."""
    with open(path, "rb") as f:
        head = f.read(_blf.FILE_HEADER_STRUCT.size)
        header = _blf.FILE_HEADER_STRUCT.unpack(head)
        if header[0] != b"LOGG":
            raise _blf.BLFParseError("Unexpected file format")
        start = _blf.systemtime_to_timestamp(header[14:22])
        f.read(header[1] - _blf.FILE_HEADER_STRUCT.size)
        slow = _Fallback(start)
        base = _blf.OBJ_HEADER_BASE_STRUCT
        while True:
            raw = f.read(base.size)
            if not raw:
                return
            signature, _, _, obj_size, obj_type = base.unpack(raw)
            if signature != b"LOBJ":
                raise _blf.BLFParseError()
            if obj_size > MAX_OBJECT_BYTES:
                raise _blf.BLFParseError(f"an object of {obj_size} bytes at byte "
                                         f"{f.tell() - base.size}, more than the "
                                         f"{MAX_OBJECT_BYTES} a log object may have")
            obj = f.read(obj_size - base.size)
            f.read(obj_size % 4)
            if obj_type != _blf.LOG_CONTAINER:
                continue
            method, _ = _blf.LOG_CONTAINER_STRUCT.unpack_from(obj)
            body = obj[_blf.LOG_CONTAINER_STRUCT.size:]
            if method == _blf.NO_COMPRESSION:
                data = body
            elif method == _blf.ZLIB_DEFLATE:
                inflate = zlib.decompressobj()
                data = inflate.decompress(body, MAX_CONTAINER_BYTES + 1)
                if len(data) > MAX_CONTAINER_BYTES:
                    raise _blf.BLFParseError(f"a container that inflates past "
                                             f"{MAX_CONTAINER_BYTES} bytes (a zlib bomb?)")
            else:
                continue  # python-can warns and skips an unknown compression
            if len(slow._tail) > MAX_CONTAINER_BYTES:
                raise _blf.BLFParseError(f"a partial object of {len(slow._tail)} bytes "
                                         "carried across containers")
            if slow._tail:
                data = slow._tail + data
                slow._tail = b""
            n = len(data) // _OBJ_BYTES
            objs = np.frombuffer(data, dtype=_MSG, count=n) if n else None
            if (objs is not None and bool(np.all(objs["sig"] == b"LOBJ"))
                    and bool(np.all(objs["obj_size"] == _OBJ_BYTES))
                    and bool(np.all(objs["header_version"] == 1))
                    and bool(np.all((objs["obj_type"] == _blf.CAN_MESSAGE)
                                    | (objs["obj_type"] == _blf.CAN_MESSAGE2)))
                    and bool(np.all(objs["flags"] == objs["flags"][0]))
                    and int(objs["timestamp"].max()) < _EXACT_NS):
                slow._tail = data[n * _OBJ_BYTES:]
                yield _with_times(objs, start), []
                continue
            # python-can's own parse of this container (and its tail), as BLFReader does
            slow._tail = b""
            yield None, [frame_tuple(m) for m in slow._parse_container(data)]


def _with_times(objs: np.ndarray, start: float) -> tuple[np.ndarray, np.ndarray]:
    """The objects and their timestamps in seconds, as BLFReader computes them: float(
    Decimal(ts) * factor) + start; with the integer exact in a float64, IEEE division by
    1e9 (or 1e5) is that correctly rounded decimal product."""
    divisor = 1e5 if int(objs["flags"][0]) == _blf.TIME_TEN_MICS else 1e9
    return objs, objs["timestamp"].astype(np.float64) / divisor + start


def read_frames(path: str | Path) -> Iterator[tuple]:  # type: ignore[type-arg]
    """The frames of the BLF file at ``path`` in file order, each a tuple of ``Frame``'s
    fields in its order (see the module docstring)."""
    for fast, frames in _containers(path):
        if fast is not None:
            yield from _vectorised(*fast)
        else:
            yield from frames


class FrameBlock(NamedTuple):
    """A run of frames as arrays (``read_blocks``): the review's vectorised decoders."""

    timestamp: np.ndarray  # float64, s
    arbitration_id: np.ndarray  # int64
    is_extended_id: np.ndarray  # bool
    is_error_frame: np.ndarray  # bool
    length: np.ndarray  # int64: len(data)
    word: np.ndarray  # uint64: the first 8 data bytes, little-endian, past len(data) zero


def read_blocks(path: str | Path, min_frames: int = 8192) -> Iterator[FrameBlock]:
    """The frames of ``path`` as ``read_frames`` gives them, as arrays of at least
    ``min_frames`` frames (but the last), a few containers at a time (memory: bounded by
    ``min_frames`` and one container, whatever the log's length)."""
    parts: list[FrameBlock] = []
    held = 0
    for part in _container_blocks(path):
        parts.append(part)
        held += len(part.timestamp)
        if held >= min_frames:
            yield _joined(parts)
            parts, held = [], 0
    if parts:
        yield _joined(parts)


def _joined(parts: list[FrameBlock]) -> FrameBlock:
    if len(parts) == 1:
        return parts[0]
    return FrameBlock(*(np.concatenate(field) for field in zip(*parts, strict=True)))


def _container_blocks(path: str | Path) -> Iterator[FrameBlock]:
    for fast, frames in _containers(path):
        if fast is not None:
            objs, ts = fast
            can_id = objs["can_id"].astype(np.int64)
            length = np.minimum(objs["dlc"], 8).astype(np.int64)
            word = np.frombuffer(objs.tobytes(), dtype="<u8")[5::_OBJ_BYTES // 8].copy()
            keep = np.where(length >= 8, np.uint64(0xFFFFFFFFFFFFFFFF),
                            (np.uint64(1) << (8 * length).astype(np.uint64)) - np.uint64(1))
            yield FrameBlock(ts, can_id & 0x1FFFFFFF, (can_id & _blf.CAN_MSG_EXT) != 0,
                             np.zeros(len(objs), dtype=bool), length, word & keep)
        elif frames:
            yield FrameBlock(
                np.array([f[0] for f in frames], dtype=np.float64),
                np.array([f[1] for f in frames], dtype=np.int64),
                np.array([f[2] for f in frames], dtype=bool),
                np.array([f[4] for f in frames], dtype=bool),
                np.array([len(f[7]) for f in frames], dtype=np.int64),
                np.array([int.from_bytes(f[7][:8], "little") for f in frames],
                         dtype=np.uint64))


def _vectorised(objs: np.ndarray, times: np.ndarray) -> Iterator[tuple]:  # type: ignore[type-arg]
    """The frames of a container of CAN_MESSAGE objects with one time unit (one numpy pass)."""
    ts = times.tolist()
    can_id = objs["can_id"]
    ids = (can_id & 0x1FFFFFFF).tolist()
    ext = ((can_id & _blf.CAN_MSG_EXT) != 0).tolist()
    flags = objs["msg_flags"]
    remote = ((flags & _blf.REMOTE_FLAG) != 0).tolist()
    rx = ((flags & _blf.DIR) == 0).tolist()
    dlcs = objs["dlc"].tolist()
    channels = (objs["channel"].astype(np.int64) - 1).tolist()
    # numpy's S8 drops trailing zero bytes: the payloads from the raw bytes instead;
    # Message(data=can_data[:dlc]) with a dlc over 8 keeps the 8 bytes there are
    raw = objs.tobytes()
    ends = np.minimum(objs["dlc"], 8).tolist()
    datas = [raw[k:k + e] for k, e in zip(range(40, len(raw), _OBJ_BYTES), ends, strict=True)]
    return zip(ts, ids, ext, remote, repeat(False), rx, dlcs, datas, channels, strict=False)
