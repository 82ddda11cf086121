"""Adding to a finished recording (run.rrd) without rewriting what it holds, e.g. the verdict
once the run is judged, so that a reviewer who opens run.rrd alone sees it.

An .rrd is a file header (12 bytes: ``RRF2``, version, options) and a sequence of messages,
each a 16-byte header (kind, length; little-endian u64) and its payload. Ours are written
without a footer (harness.record.recording), so the messages run to the end of the file: a
second stream is appended as its messages alone (its own file header dropped), and Rerun's
readers (the viewer, ``rerun.chunk.RrdReader``) read both as one recording. A file that
ends with a footer (Rerun's default; ``RrdReader`` then lists only the stores its manifest
names) or whose last message is cut short (a SIGKILL during a write) is left as it is:
``append_stream`` returns False.

Replacing what was appended before: Rerun cannot delete logged data, so the caller keeps the
size of the file before its first append (``recorded_bytes``), and ``truncate_to`` cuts the
file back to it, after checking that a message boundary is there: the run's own bytes are
never rewritten (their SHA-256, ``sha256_prefix``, stays the run's identity).
"""

from __future__ import annotations

import hashlib
import os
import struct
from collections.abc import Callable
from pathlib import Path

import rerun as rr
import rerun.blueprint as rrb

from harness.record.recording import close_stream
from harness.record.streams import save_with_blueprint, sweep_orphans

FILE_HEADER = 12
MESSAGE_HEADER = 16
END_OF_STREAM = 0

Writer = Callable[[rr.RecordingStream], None]


def _scan(path: Path) -> tuple[str, int]:
    """How the messages of ``path`` end, and where: ``("open", size)`` (at the end of the
    file: no footer), ``("closed", offset of the end-of-stream message)`` (then the footer),
    ``("cut", offset of the incomplete message)`` or ``("bad", 0)`` (not an RRD file)."""
    size = path.stat().st_size
    with path.open("rb") as f:
        if f.read(4) != b"RRF2":
            return "bad", 0
        pos = FILE_HEADER
        while pos + MESSAGE_HEADER <= size:
            f.seek(pos)
            kind, length = struct.unpack("<QQ", f.read(MESSAGE_HEADER))
            if kind == END_OF_STREAM:
                return "closed", pos
            if pos + MESSAGE_HEADER + length > size:
                return "cut", pos
            pos += MESSAGE_HEADER + length
        return ("open", pos) if pos == size else ("cut", pos)


def stream_end(path: Path) -> str:
    """``"open"``, ``"closed"``, ``"cut"`` or ``"bad"`` (``_scan``)."""
    return _scan(path)[0]


def _write_stream(path: Path, application_id: str, recording_id: str, write: Writer,
                  blueprint: rrb.Blueprint | None) -> None:
    rec = rr.RecordingStream(application_id, recording_id=recording_id)
    save_with_blueprint(rec, path, blueprint, write_footer=False)
    try:
        write(rec)
    finally:
        try:
            close_stream(rec, path)
        finally:
            del rec
            sweep_orphans()  # the stream dropped: its threads end


def append_stream(path: Path, application_id: str, recording_id: str, write: Writer,
                  blueprint: rrb.Blueprint | None = None) -> bool:
    """What ``write`` logs (and ``blueprint``, made the default) appended to the recording
    ``path`` as part of the same recording; False (file untouched) when the file is cut
    short, ends with a footer or is not an RRD file."""
    if stream_end(path) != "open":
        return False
    part = path.with_name(f".{path.name}.append")
    try:
        _write_stream(part, application_id, recording_id, write, blueprint)
        data = part.read_bytes()
        with path.open("ab") as f:
            f.write(data[FILE_HEADER:])
            f.flush()
            os.fsync(f.fileno())
    finally:
        part.unlink(missing_ok=True)
    return True


def is_boundary(path: Path, offset: int) -> bool:
    """Whether a message of ``path`` starts (or the file ends) at ``offset``."""
    size = path.stat().st_size
    if offset > size:
        return False
    with path.open("rb") as f:
        if f.read(4) != b"RRF2":
            return False
        pos = FILE_HEADER
        while pos < offset and pos + MESSAGE_HEADER <= size:
            f.seek(pos)
            kind, length = struct.unpack("<QQ", f.read(MESSAGE_HEADER))
            if kind == END_OF_STREAM:
                return False
            pos += MESSAGE_HEADER + length
        return pos == offset


def truncate_to(path: Path, offset: int) -> bool:
    """Cut ``path`` back to ``offset`` (what was appended after it is dropped); False
    (untouched) when no message boundary is there."""
    if not is_boundary(path, offset):
        return False
    if offset < path.stat().st_size:
        os.truncate(path, offset)
    return True


def sha256_prefix(path: Path, offset: int | None = None) -> str | None:
    """SHA-256 of the first ``offset`` bytes of ``path`` (all of it when None)."""
    if not path.is_file():
        return None
    h = hashlib.sha256()
    left = path.stat().st_size if offset is None else offset
    with path.open("rb") as f:
        while left > 0:
            block = f.read(min(1 << 20, left))
            if not block:
                break
            h.update(block)
            left -= len(block)
    return h.hexdigest()
