"""``export_run``: a run folder to one format (see the package docstring)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

from harness.export.source import (
    ExportError,
    OutputFailed,
    channel_blocks,
    frame_blocks,
    loop_channels,
    read_metadata,
    safe_name,
)

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


def export_run(run_dir: Path | str, fmt: str, out_dir: Path | str | None = None) -> list[Path]:
    """Export ``run_dir`` to ``fmt`` into ``out_dir`` (default ``<run_dir>/export``); the
    files written. Raises ExportError / MissingExtra."""
    from harness.export.writers import WRITERS

    if fmt not in FORMATS:
        raise ExportError(f"--to {fmt}: expected one of {', '.join(FORMATS)}")
    check_extra(fmt)
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise ExportError(f"{run_dir}: not a directory")
    rrd, blf = run_dir / "run.rrd", run_dir / "can.blf"
    for p in (rrd, blf):
        if not p.is_file():
            raise ExportError(f"{p}: no such file (nothing to export)")
        if p.is_symlink():
            raise ExportError(f"{p}: a link, not the run's own file")
    meta = read_metadata(run_dir)
    out = Path(out_dir) if out_dir is not None else run_dir / "export"
    if out.exists() and not out.is_dir():
        raise ExportError(f"--out {out}: not a directory")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputFailed(f"--out {out}: cannot create it ({exc.strerror or exc})") from None
    if not out.is_dir():
        raise ExportError(f"--out {out}: not a directory")
    channels = loop_channels()
    _system_allocator()
    base = out / safe_name(run_dir.name)
    writer = WRITERS[fmt](base, channels, meta)
    origin: list[float] = []
    rows = frames = 0
    try:
        for t, cols in channel_blocks(rrd, channels):
            writer.channels(t, cols)
            rows += len(t)
        for f in frame_blocks(blf, origin):
            writer.frames(f)
            frames += len(f.time_s)
        return writer.close({"can_time_origin_s": origin[0] if origin else None,
                             "rows": rows, "can_frames": frames})
    except OSError as exc:
        writer.abort()
        raise OutputFailed(f"--out {out}: writing failed ({exc.strerror or exc})") from None
    except BaseException:
        writer.abort()
        raise


__all__ = ["FORMATS", "ExportError", "MissingExtra", "OutputFailed", "export_run"]
