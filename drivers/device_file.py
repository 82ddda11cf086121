"""Reading a device file a vendor or a person wrote (EDS, DCF, DBC), bounded.

A 40 MB EDS took gigabytes and never finished parsing; a FIFO named as a file blocked the
harness on its ``open`` forever; a path too long for the file system ended in a traceback.
``read_device_file`` opens without blocking, refuses anything but a regular file, refuses a
file over ``MAX_DEVICE_FILE_BYTES`` before reading it, and reads at most that much: every
problem a ``DeviceFileError`` whose message names the file. Pure standard library (the
binding and the virtual rig's nodes both read their files through it).
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

MAX_DEVICE_FILE_BYTES = 4 * 1024 * 1024
"""The largest EDS, DCF or DBC file: real ones are far smaller (a servo drive's EDS with its
vendor objects about 200 KB, a whole vehicle's DBC about 400 KB)."""

_KINDS = ((stat.S_ISFIFO, "a FIFO"), (stat.S_ISDIR, "a directory"),
          (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
          (stat.S_ISSOCK, "a socket"))


class DeviceFileError(ValueError):
    """A device file cannot be read as one (special file, too big, unreadable)."""


def kind_of(mode: int) -> str:
    return next((name for test, name in _KINDS if test(mode)), "not a regular file")


def read_device_file(path: str | Path, limit: int = MAX_DEVICE_FILE_BYTES) -> bytes:
    """The bytes of ``path`` if it is a regular file of at most ``limit`` bytes."""
    name = Path(path).name or str(path)
    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_NOCTTY", 0)
    try:
        fd = os.open(path, flags)
    except (OSError, ValueError) as exc:
        why = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
        raise DeviceFileError(f"{_short(name)}: cannot read: {why}") from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise DeviceFileError(f"{_short(name)}: {kind_of(st.st_mode)}, not a regular "
                                  "file")
        if st.st_size > limit:
            raise DeviceFileError(f"{_short(name)}: {st.st_size / 2**20:.1f} MiB, more than "
                                  f"the {limit / 2**20:g} MiB a device file may have")
        chunks = []
        got = 0
        while got <= limit:
            chunk = os.read(fd, min(1 << 20, limit + 1 - got))
            if not chunk:
                break
            chunks.append(chunk)
            got += len(chunk)
        if got > limit:  # it grew since its size was read
            raise DeviceFileError(f"{_short(name)}: more than the {limit / 2**20:g} MiB a "
                                  "device file may have")
        return b"".join(chunks)
    except OSError as exc:
        raise DeviceFileError(f"{_short(name)}: cannot read: {exc.strerror or exc}") from None
    finally:
        os.close(fd)


def read_text(path: str | Path, encodings: tuple[str, ...] = ("utf-8", "cp1252", "latin-1")
              ) -> str:
    """``read_device_file`` decoded with the first encoding that fits (vendors' files are
    ASCII, UTF-8 or Windows-1252; Latin-1 decodes anything)."""
    data = read_device_file(path)
    for enc in encodings:
        try:
            return data.decode(enc)
        except UnicodeDecodeError:
            continue
    return data.decode("latin-1")


def _short(name: str, keep: int = 80) -> str:
    """A file name for a message: a very long one is cut in the middle."""
    return name if len(name) <= keep else f"{name[:keep // 2]}...{name[-keep // 2:]}"
