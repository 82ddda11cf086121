"""A run folder in open formats (``harness export``): MATLAB .mat, Parquet, ASAM MDF4, CSV.

A run's recording is ``run.rrd`` from a pinned Rerun version, which later Rerun versions
need not open; a lab's archive and its MATLAB and automotive tools need open formats. The
export carries every channel the loop recorded (``harness.core.loop.CHANNELS``: one row a
tick) in SI with its unit (degrees to radians, milliseconds to seconds; the name's unit
suffix follows), the raw CAN frames of ``can.blf``, and the run's configuration
(config.yaml), summary (summary.json) and verdict (verdict.json) as metadata. The decoded
bus view in run.rrd (``/bus/...``) is can.blf decoded for the viewer: the raw frames are
exported instead, which any tool with the rig's DBC or EDS decodes the same way (MDF4
embeds the DBC). Every time is the run's (tick k at k x period): each frame is placed on it
by the bus view's own rules (``frames``), its host time stamp and direction kept beside.

Streaming: run.rrd is read chunk by chunk in two passes (an index of each channel's chunks,
then the rows, each going out once no channel can bring an earlier sample) and can.blf a
few containers at a time; each writer takes blocks (Parquet row groups, MDF4 data blocks,
CSV lines, MAT variables spooled to temporary files beside the output and assembled at the
end), so memory does not grow with the run's length, whatever channels the recording
lacks (``benchmarks/bench_export_memory.py``, ``tests/test_export_trust.py``). Each file is
written to a temporary file of its own in the output folder and renamed when complete;
nothing is written outside the output folder.

May import ``harness.record`` (reading run.rrd and can.blf), ``harness.core.loop`` (the
channel list), ``harness.review.bus`` (the bus view's rules for placing frames on the run's
time), ``drivers.binding`` (the run's SYNC frame and DBC files) and ``rig_models`` (YAML
loading); nothing imports it but ``harness.commands.export``. ``scipy`` (mat, a core
dependency), ``pyarrow`` (parquet) and ``asammdf`` (mf4, the ``export`` extra) are imported
only by their writer.

Public API
----------
``export_run(run_dir, fmt, out_dir=None) -> list[Path]``
    Writes ``<out_dir>/<run folder name>.<ext>`` (and, per format, the CAN frames and the
    metadata beside it); ``out_dir`` defaults to ``<run_dir>/export``. Raises
    ``ExportError`` (a bad run folder, naming the file; exit 2), ``MissingExtra`` (the
    format's library is not installed; the message names the pip command) or
    ``OutputFailed`` (writing into the output folder failed; exit 4).
``FORMATS``: the format names and their file extensions.
"""

from __future__ import annotations

from harness.export.run import FORMATS, ExportError, MissingExtra, OutputFailed, export_run

__all__ = ["FORMATS", "ExportError", "MissingExtra", "OutputFailed", "export_run"]
