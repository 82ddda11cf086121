"""`harness export RUN_DIR --to mat|parquet|mf4|csv [--out DIR]`: a run in open formats.

Every channel the loop recorded (one row a tick) in SI with its unit (degrees to radians,
milliseconds to seconds, the name's unit suffix following: ``attitude.angle_rad``), the raw
CAN frames of can.blf, and the run's configuration, summary and verdict as metadata:

  mat      <run>.mat: a column vector per channel (``attitude_angle_rad``), ``time_s``, the
           frames (``can_time_s``, ``can_id``, ``can_data`` n x 8, ...), ``metadata``
           (units, sources; configuration, summary and verdict as JSON text); scipy.io
  parquet  <run>.parquet (units and sources in the field metadata, the run's metadata in
           the key ``sgsrt``) and <run>.can.parquet; pyarrow
  mf4      <run>.mf4, ASAM MDF 4.10: group ``channels`` with units, the frames as CAN
           bus-logging groups (CAN_DataFrame, CAN_ErrorFrame), the metadata as embedded
           attachments; asammdf
  csv      <run>.csv, <run>.can.csv (data bytes byte0-byte7) and <run>.metadata.json

Streams run.rrd and can.blf block by block: memory does not grow with the run's length.
Writes into --out (default RUN_DIR/export), each file complete or not at all.

Example:
  harness export logs/20261123T101010.000000Z-slew-rw --to mf4 --out /tmp/slew

Exit 0, 2 bad input (not a run folder, a damaged file named, the format's library not
installed: pip install 'sgsrt-harness[export]'), 4 the output folder failed. See
docs/export.md.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("export", help="a run in open formats: MATLAB .mat, Parquet, MDF4, CSV",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("run_dir", type=Path, help="a recorded run directory")
    p.add_argument("--to", required=True, choices=("mat", "parquet", "mf4", "csv"),
                   help="the format")
    p.add_argument("--out", type=Path, help="output folder (default: RUN_DIR/export)")
    p.set_defaults(func=cmd_export)


def cmd_export(args: argparse.Namespace) -> int:
    from harness.export import ExportError, OutputFailed, export_run

    try:
        paths = export_run(args.run_dir, args.to, args.out)
    except ExportError as exc:
        print(f"harness export: {exc}", file=sys.stderr)
        return 4 if isinstance(exc, OutputFailed) else 2
    for p in paths:
        print(p)
    return 0
