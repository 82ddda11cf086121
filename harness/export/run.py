"""``export_run``: a run folder to one format (see the package docstring)."""

from __future__ import annotations

import contextlib
import errno
import hashlib
import importlib.util
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from harness.export.source import (
    ExportError,
    OutputFailed,
    channel_blocks,
    channel_index,
    loop_channels,
    read_metadata,
    safe_name,
)
from harness.export.writers import temporary_beside

FORMATS = {"mat": "mat", "parquet": "parquet", "mf4": "mf4", "csv": "csv"}
"""Format name: extension of the main file."""

NEEDS = {"parquet": "pyarrow", "mf4": "asammdf"}
"""The library a format needs beyond the harness's own dependencies (the ``export``
extra)."""

PIP = "pip install 'sgsrt-harness[export]'"


class MissingExtra(ExportError):
    """The format's library is not installed (exit 2; the message names the pip command)."""


def check_extra(fmt: str) -> None:
    lib = NEEDS.get(fmt)
    if lib is not None and importlib.util.find_spec(lib) is None:
        raise MissingExtra(f"--to {fmt} needs {lib}, which is not installed: {PIP} (or pip "
                           f"install {lib})")


def _system_allocator() -> None:
    """Arrow's allocations (the Parquet and CSV writers') from the C library's allocator:
    with Arrow's default, jemalloc, which keeps freed blocks, a Parquet export's peak grew
    from a 200 s run to a 600 s one (+6.4 MB, twice); with this it did not (three pairs:
    253-255 MB and 249-251 MB). docs/benchmarks.md."""
    import pyarrow as pa  # rerun-sdk's dependency: always there

    pa.set_memory_pool(pa.system_memory_pool())


TIME_AXIS = ("every time is the run time, the channels' axis: tick k at k x period; a CAN "
             "frame at its tick (the last SYNC before it) as the recording's bus view places "
             "it (lockstep: the tick's time plus its host-clock offset after its SYNC, kept "
             "inside the tick; real time: its host time stamp minus when tick 0 was due); "
             "host_time_s is the host's own time stamp (POSIX s)")
"""What ``time_s`` means, in the metadata (docs/export.md, "Time")."""


@contextlib.contextmanager
def _readable_rrd(rrd: Path, out: Path) -> Iterator[Path]:
    """``rrd``, or when it was cut short (a killed run) a copy of its complete messages
    in ``out`` (``harness.record.reader`` would copy it to the system's temporary folder:
    an export writes nowhere but ``out``), removed at the end."""
    from harness.record.reader import FILE_HEADER_BYTES, _open, complete_length

    try:
        str(rrd).encode("utf-8")
    except UnicodeEncodeError:
        # a folder name that is not UTF-8: Rerun takes only text paths; the open file's
        # own name in /proc (Linux) reads it as it is
        if not Path("/proc/self/fd").is_dir():
            raise ExportError(f"{rrd}: a path that is not UTF-8, which Rerun cannot open: "
                              "rename the run folder") from None
        try:
            fd = os.open(rrd, os.O_RDONLY)
        except OSError as exc:
            raise ExportError(f"{rrd}: cannot read ({exc.strerror or exc})") from None
        try:
            with _readable_rrd(Path(f"/proc/self/fd/{fd}"), out) as path:
                yield path
        finally:
            os.close(fd)
        return
    try:
        _open(rrd)
        whole = True
    except Exception as exc:  # noqa: BLE001 - Rerun raises various kinds for a bad file
        whole = False
        try:
            end = complete_length(rrd)
            size = rrd.stat().st_size
        except OSError as exc2:
            raise ExportError(f"{rrd}: cannot read ({exc2.strerror or exc2})") from None
        if end >= size or end <= FILE_HEADER_BYTES:
            raise ExportError(f"{rrd}: cannot read ({type(exc).__name__}: "
                              f"{str(exc)[:200]})") from None
    if whole:
        yield rrd
        return
    try:
        tmp = temporary_beside(out / ".run.rrd")
    except OSError as exc:
        raise _output_error(out, exc) from None
    try:
        try:
            with open(rrd, "rb") as src, open(tmp, "wb") as dst:
                left = end
                while left > 0:  # in pieces: memory stays bounded whatever the size
                    piece = src.read(min(left, 1 << 20))
                    if not piece:
                        break
                    dst.write(piece)
                    left -= len(piece)
        except OSError as exc:
            raise _output_error(out, exc) from None
        yield tmp
    finally:
        tmp.unlink(missing_ok=True)


def _output_error(out: Path, exc: OSError) -> ExportError:
    """A failed write into ``out``: exit 2 when the path is what is wrong (too long for
    the file system), else exit 4 (full, read-only, an I/O error)."""
    if exc.errno == errno.ENAMETOOLONG:
        return ExportError(f"--out {out}: a file name or path too long for the file system "
                           f"({exc.strerror})")
    return OutputFailed(f"--out {out}: writing failed ({exc.strerror or exc})")


def _bus_files(files: list[Path]) -> list[dict[str, str]]:
    out = []
    for p in files:
        try:
            digest = hashlib.sha256(p.read_bytes()).hexdigest()
        except OSError as exc:
            raise ExportError(f"{p}: the rig's file cannot be read ({exc.strerror or exc})"
                              ) from None
        out.append({"file": p.name, "path": str(p), "sha256": digest})
    return out


def export_run(run_dir: Path | str, fmt: str, out_dir: Path | str | None = None) -> list[Path]:
    """Export ``run_dir`` to ``fmt`` into ``out_dir`` (default ``<run_dir>/export``); the
    files written. Raises ExportError / MissingExtra / OutputFailed."""
    from harness.export.frames import FramePlacer, frame_blocks, time_base
    from harness.export.writers import WRITERS

    if fmt not in FORMATS:
        raise ExportError(f"--to {fmt}: expected one of {', '.join(FORMATS)}")
    check_extra(fmt)
    run_dir = Path(run_dir)
    try:
        if not run_dir.is_dir():
            raise ExportError(f"{run_dir}: not a directory")
    except OSError as exc:
        raise ExportError(f"{run_dir}: {exc.strerror or exc}") from None
    rrd, blf = run_dir / "run.rrd", run_dir / "can.blf"
    for p in (rrd, blf):
        if p.is_symlink():
            raise ExportError(f"{p}: a link, not the run's own file")
        if not p.is_file():
            raise ExportError(f"{p}: no such file (nothing to export)")
    meta = read_metadata(run_dir)
    tb = time_base(meta, run_dir)
    bus_files = _bus_files(tb.dbc_files + tb.eds_files)
    out = Path(out_dir) if out_dir is not None else run_dir / "export"
    try:
        os.path.abspath(out).encode("utf-8")
    except UnicodeEncodeError:
        raise ExportError(f"--out {out}: a path that is not UTF-8, which the formats' "
                          "writers cannot open: choose another folder") from None
    try:
        if out.exists() and not out.is_dir():
            raise ExportError(f"--out {out}: not a directory")
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        if exc.errno == errno.ENAMETOOLONG:
            raise _output_error(out, exc) from None
        raise OutputFailed(f"--out {out}: cannot create it ({exc.strerror or exc})") from None
    if not out.is_dir():
        raise ExportError(f"--out {out}: not a directory")
    channels = loop_channels()
    base = out / safe_name(run_dir.name)
    extra: dict[str, Any] = {"clock": tb.clock, "period_s": tb.dt_s, "time_axis": TIME_AXIS,
                             "bus_files": bus_files}
    with _readable_rrd(rrd, out) as source:
        # the first pass checks the whole recording before anything is written
        index = channel_index(source, channels)
        placer = FramePlacer(tb, blf)
        _system_allocator()
        try:
            writer = WRITERS[fmt](base, channels, meta, tb.dbc_files + tb.eds_files,
                                  tb.used_frames)
        except OSError as exc:
            raise _output_error(out, exc) from None
        rows = frames = 0
        try:
            for t, cols in channel_blocks(source, channels, index):
                writer.channels(t, cols)
                rows += len(t)
            for f in frame_blocks(blf, placer):
                writer.frames(f)
                frames += len(f.time_s)
            return writer.close({**extra, "host_time_origin_s": placer.host_origin,
                                 "rows": rows, "can_frames": frames})
        except OSError as exc:
            writer.abort()
            raise _output_error(out, exc) from None
        except RecursionError:
            writer.abort()
            raise ExportError(f"{run_dir}: a file nested too deeply to export") from None
        except BaseException:
            writer.abort()
            raise


__all__ = ["FORMATS", "ExportError", "MissingExtra", "OutputFailed", "export_run"]
