"""The output folder's failures: a full, read-only or failing disk, told apart from bugs.

A run writes run.rrd (through Rerun's file sink, in Rerun's own thread), can.blf, and small
JSON files. Any of them can fail once the disk fills or is remounted read-only; the run must
then leave the rig safe at once, end in bounded time with one line naming the folder (exit
4), never claim "completed", and keep what was already written readable. ``OutputError`` is
that failure; ``SpaceGuard`` stops a run *before* the disk is full, keeping ``reserve_bytes``
free for what a run writes after its loop (the recording's last blocks, summary.json,
layout.json, verdict.json); ``write_text_atomic`` never leaves a half-written file.
"""

from __future__ import annotations

import contextlib
import errno
import os
from pathlib import Path

OUTPUT_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EIO, errno.EFBIG,
                           errno.EACCES, errno.EPERM})
"""Errors of writing that say the output folder, not the harness, failed."""

DEFAULT_RESERVE_BYTES = 2 * 1024 * 1024
"""Free space a run keeps for what it writes after the loop. Measured on slew-rw: its
summary, layout and verdict.json take tens of KB; the recording's blocks not yet written at
a stop are at most ``Recorder.flush_every_blocks`` blocks (about 0.5 MB in lockstep); the
CAN log one container (32 KB)."""


class OutputError(RuntimeError):
    """Writing into the output folder failed (full, read-only, quota, I/O error)."""

    def __init__(self, folder: Path | str, reason: str) -> None:
        super().__init__(f"cannot write to the output folder {folder}: {reason}")
        self.folder = Path(folder)
        self.reason = reason


def is_output_failure(exc: BaseException) -> bool:
    """Whether ``exc`` is a failure of the disk (or already an ``OutputError``)."""
    return isinstance(exc, OutputError) or (isinstance(exc, OSError)
                                            and exc.errno in OUTPUT_ERRNOS)


def as_output_error(folder: Path | str, exc: BaseException) -> OutputError:
    if isinstance(exc, OutputError):
        return exc
    reason = os.strerror(exc.errno) if isinstance(exc, OSError) and exc.errno else str(exc)
    return OutputError(folder, reason)


def free_bytes(folder: Path) -> int:
    """Bytes an unprivileged writer may still use on ``folder``'s filesystem (the nearest
    existing ancestor when ``folder`` does not exist yet)."""
    path = Path(folder).absolute()
    while not path.exists() and path != path.parent:
        path = path.parent
    st = os.statvfs(path)
    return st.f_bavail * st.f_frsize


class SpaceGuard:
    """Raises ``OutputError`` once ``folder`` has less than ``reserve_bytes`` free. A
    statvfs call costs microseconds; the recorder checks once per block (1 s at 500 Hz)."""

    def __init__(self, folder: Path, reserve_bytes: int | None = None) -> None:
        self.folder = Path(folder)
        self.reserve_bytes = int(DEFAULT_RESERVE_BYTES if reserve_bytes is None
                                 else reserve_bytes)

    def free(self) -> int:
        try:
            return free_bytes(self.folder)
        except OSError as exc:
            raise as_output_error(self.folder, exc) from exc

    def check(self, need_bytes: int = 0) -> None:
        free = self.free()
        if free < self.reserve_bytes + need_bytes:
            raise OutputError(self.folder, f"only {free / 1024:.0f} KB free, the run keeps "
                              f"{(self.reserve_bytes + need_bytes) / 1024:.0f} KB for its "
                              "last writes; free some space or choose another --out")


def write_text_atomic(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` through a temporary file and a rename: a reader sees the
    old file or the whole new one, never an empty or cut one (a full disk). Raises
    ``OutputError`` (the temporary file removed) when the folder cannot take it."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp")
    try:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()  # never write through a link left in its place
        with open(tmp, "x", encoding="utf-8") as f:
            f.write(text)
            f.flush()
        os.replace(tmp, path)
    except OSError as exc:
        with contextlib.suppress(OSError):
            tmp.unlink()
        if is_output_failure(exc):
            raise as_output_error(path.parent, exc) from exc
        raise


def fresh_output_path(path: Path) -> Path:
    """``path``, made safe to create or truncate: a symbolic link (or any other non-regular
    file) in its place is removed first, so that the write lands in the folder itself and
    never goes through a link placed there to somewhere else (writers open with O_TRUNC and
    follow links). A directory in its place is refused."""
    path = Path(path)
    if path.is_symlink() or (path.exists() and not path.is_file() and not path.is_dir()):
        path.unlink()
    elif path.is_dir():
        raise OutputError(path.parent, f"{path.name} is a directory, not a file")
    return path
