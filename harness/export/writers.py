"""One writer per format, fed blocks: ``channels(t, cols)`` then ``frames(Frames)``, then
``close()``. Each writes into temporary files of its own beside its targets
(``.<target>.<8 random hex>.partial.<ext>``, created exclusively: two exports into one
folder never share one) and renames each onto its target at the end (``os.replace``,
atomic), so an export that fails leaves no half file under the final name (``abort()``
removes its temporary files) and a target is always one export's complete file."""

from __future__ import annotations

import hashlib
import io
import json
import os
import secrets
import shutil
import struct
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from harness.export.frames import Frames, joined
from harness.export.source import Channel, ExportError, printable

ROW_GROUP = 16_384
"""Rows gathered before a Parquet row group or an MDF4 data block is written: large enough
to read back fast (33 s of ticks at 500 Hz), small enough for bounded memory (3 MB of the
loop's 22 float64 columns)."""


def temporary_beside(final: Path) -> Path:
    """A new empty file of this export's own beside ``final``: ``.<name>.<8 random
    hex>.partial<ext>`` (the extension kept last: asammdf would change any other), created
    with O_EXCL (never another export's) and the mode the umask gives a new file."""
    for _ in range(64):
        tmp = final.with_name(f".{final.name}.{secrets.token_hex(4)}.partial{final.suffix}")
        try:
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        except FileExistsError:
            continue
        os.close(fd)
        return tmp
    raise FileExistsError(f"{final.parent}: no free temporary name beside {final.name}")


class Writer:
    ext = ""

    def __init__(self, base: Path, channels: list[Channel], meta: dict[str, Any],
                 bus_files: list[Path] | None = None,
                 bus_frames: set[tuple[tuple[int, bool], str]] | None = None) -> None:
        self.base = base
        self.chs = channels
        self.meta = meta
        self.bus_files = list(bus_files or [])
        """The rig's DBC (and EDS) files: MF4 embeds them."""
        self.bus_frames = set(bus_frames or ())
        """(id, extended) and name of each frame the rig's binding uses."""
        self.partials: dict[Path, Path] = {}
        try:
            self.open()
        except BaseException:
            self.abort()
            raise

    def open(self) -> None:
        """Create the temporary files (``target``) and their writers."""

    def target(self, suffix: str) -> Path:
        final = self.base.with_name(self.base.name + suffix)
        part = temporary_beside(final)
        self.partials[final] = part
        return part

    def channels(self, t: np.ndarray, cols: dict[str, np.ndarray]) -> None:
        raise NotImplementedError

    def frames(self, f: Frames) -> None:
        raise NotImplementedError

    def finish(self) -> None:
        """Write what is buffered and close the temporary files."""

    def close(self, extra: dict[str, Any]) -> list[Path]:
        self.meta = {**self.meta, **extra}
        self.finish()
        out = []
        for final, part in self.partials.items():
            os.replace(part, final)
            out.append(final)
        return out

    def abort(self) -> None:
        for part in self.partials.values():
            part.unlink(missing_ok=True)


def _close_quietly(*writers: Any) -> None:
    for w in writers:
        if w is None:
            continue
        try:
            w.close()
        except Exception:  # noqa: BLE001 - its file is removed anyway
            pass


def _meta_text(meta: dict[str, Any], chs: list[Channel]) -> str:
    from harness.export.source import metadata_json

    return metadata_json(meta, chs, {})


# ------------------------------------------------------------------------------ CSV
class CsvWriter(Writer):
    """``<run>.csv`` (time_s and every channel, SI, the unit in each column's name),
    ``<run>.can.csv`` (the frames: run time, host time, data bytes byte0-byte7, 0 past the
    length), ``<run>.metadata.json``. Written with Arrow's CSV writer (pyarrow comes with
    rerun-sdk): numbers in their shortest form that reads back to the same float64."""

    ext = "csv"
    _ch: Any = None
    _fr: Any = None

    def open(self) -> None:
        import pyarrow as pa
        import pyarrow.csv as pcsv

        self.pa = pa
        self._schema = pa.schema([pa.field("time_s", pa.float64())]
                                 + [pa.field(c.name, pa.float64()) for c in self.chs])
        self._fr_schema = pa.schema(
            [pa.field("time_s", pa.float64()), pa.field("host_time_s", pa.float64()),
             pa.field("can_id", pa.uint32()), pa.field("extended", pa.uint8()),
             pa.field("error_frame", pa.uint8()), pa.field("tx", pa.uint8()),
             pa.field("length", pa.uint8())]
            + [pa.field(f"byte{i}", pa.uint8()) for i in range(8)])
        self._ch = pcsv.CSVWriter(str(self.target(".csv")), self._schema)
        self._fr = pcsv.CSVWriter(str(self.target(".can.csv")), self._fr_schema)
        self._meta = self.target(".metadata.json")

    def channels(self, t: np.ndarray, cols: dict[str, np.ndarray]) -> None:
        arrays = [self.pa.array(t)] + [self.pa.array(cols[c.source]) for c in self.chs]
        self._ch.write_table(self.pa.Table.from_arrays(arrays, schema=self._schema))

    def frames(self, f: Frames) -> None:
        arrays = [f.time_s, f.host_time_s, f.can_id, f.extended.astype(np.uint8),
                  f.error.astype(np.uint8), f.tx.astype(np.uint8), f.length] + [
            np.ascontiguousarray(f.data[:, i]) for i in range(8)]
        self._fr.write_table(self.pa.Table.from_arrays(
            [self.pa.array(a) for a in arrays], schema=self._fr_schema))

    def finish(self) -> None:
        self._ch.close()
        self._fr.close()
        self._meta.write_text(_meta_text(self.meta, self.chs) + "\n")

    def abort(self) -> None:
        _close_quietly(self._ch, self._fr)
        super().abort()


# ------------------------------------------------------------------------------ Parquet
class ParquetWriter(Writer):
    """``<run>.parquet`` (time_s and every channel as float64, each field's unit and source
    in its field metadata, the run's metadata as JSON in the schema's ``sgsrt`` key) and
    ``<run>.can.parquet`` (the frames: run time, host time, direction)."""

    ext = "parquet"
    _w: Any = None
    _fw: Any = None

    def open(self) -> None:
        import pyarrow as pa
        import pyarrow.parquet as pq

        self.pa, self.pq = pa, pq
        fields = [pa.field("time_s", pa.float64(), metadata={"unit": "s", "source": "time"})]
        fields += [pa.field(c.name, pa.float64(), metadata={"unit": c.unit, "source": c.source})
                   for c in self.chs]
        # the summary and verdict are known only at the end: Parquet's footer is written
        # last, so the metadata goes into the schema there (``finish``)
        self._schema = pa.schema(fields)
        self._fr_schema = pa.schema([
            pa.field("time_s", pa.float64(), metadata={
                "unit": "s", "clock": "run time, the channels' time axis"}),
            pa.field("host_time_s", pa.float64(), metadata={
                "unit": "s", "clock": "the host's, POSIX time (can.blf's time stamp)"}),
            pa.field("can_id", pa.uint32()), pa.field("extended", pa.bool_()),
            pa.field("error_frame", pa.bool_()),
            pa.field("tx", pa.bool_(), metadata={"meaning": "sent by the harness (Tx); "
                                                 "false: received (Rx)"}),
            pa.field("length", pa.uint8()), pa.field("data", pa.binary(8))])
        self._path = self.target(".parquet")
        self._w = pq.ParquetWriter(self._path, self._schema)
        self._fr_path = self.target(".can.parquet")
        self._fw = pq.ParquetWriter(self._fr_path, self._fr_schema)
        self._rows: list[Any] = []
        self._n = 0
        self._frows: list[Any] = []
        self._fn = 0

    def channels(self, t: np.ndarray, cols: dict[str, np.ndarray]) -> None:
        arrays = [self.pa.array(t)] + [self.pa.array(cols[c.source]) for c in self.chs]
        self._rows.append(self.pa.Table.from_arrays(arrays, schema=self._schema))
        self._n += len(t)
        if self._n >= ROW_GROUP:
            self._flush()

    def _write_full(self, writer: Any, parts: list[Any], last: bool) -> tuple[list[Any], int]:
        """Whole row groups of ``parts`` written (all of it when ``last``); the rest kept."""
        if not parts:
            return [], 0
        table = self.pa.concat_tables(parts)
        n = len(table) if last else (len(table) // ROW_GROUP) * ROW_GROUP
        if n:
            writer.write_table(table.slice(0, n), row_group_size=ROW_GROUP)
        rest = table.slice(n)
        return ([rest], len(rest)) if len(rest) else ([], 0)

    def _flush(self, last: bool = False) -> None:
        self._rows, self._n = self._write_full(self._w, self._rows, last)

    def frames(self, f: Frames) -> None:
        pa = self.pa
        data = pa.FixedSizeBinaryArray.from_buffers(
            pa.binary(8), len(f.time_s), [None, pa.py_buffer(np.ascontiguousarray(f.data))])
        self._frows.append(pa.Table.from_arrays(
            [pa.array(f.time_s), pa.array(f.host_time_s), pa.array(f.can_id),
             pa.array(f.extended), pa.array(f.error), pa.array(f.tx), pa.array(f.length),
             data], schema=self._fr_schema))
        self._fn += len(f.time_s)
        if self._fn >= ROW_GROUP:
            self._frows, self._fn = self._write_full(self._fw, self._frows, False)

    def finish(self) -> None:
        self._flush(last=True)
        self._frows, self._fn = self._write_full(self._fw, self._frows, True)
        text = _meta_text(self.meta, self.chs).encode()
        self._w.add_key_value_metadata({"sgsrt": text})
        self._fw.add_key_value_metadata({"sgsrt": text})
        self._w.close()
        self._fw.close()

    def abort(self) -> None:
        _close_quietly(self._w, self._fw)
        super().abort()


# ------------------------------------------------------------------------------ MAT
# MAT-file level 5 (uncompressed): a numeric array element is written by hand so that its
# data can be streamed from a spool file; the metadata struct is written by scipy.io
MI_INT8, MI_UINT8, MI_INT32, MI_UINT32, MI_DOUBLE, MI_MATRIX = 1, 2, 5, 6, 9, 14
MX = {np.dtype("<f8"): (6, MI_DOUBLE), np.dtype("u1"): (9, MI_UINT8),
      np.dtype("<u4"): (13, MI_UINT32)}
"""dtype: (mxCLASS, miTYPE) of a numeric array."""
MAT_MAX_BYTES = 2**32 - 1024
"""A level-5 element's size is 32 bits: one variable holds at most 4 GB."""


def _pad8(n: int) -> int:
    return (8 - n % 8) % 8


class _Spool:
    """A column's values appended to a temporary file (its dtype fixed)."""

    def __init__(self, folder: Path, name: str, dtype: str) -> None:
        self.dtype = np.dtype(dtype)
        self.path = folder / f"{len(list(folder.iterdir()))}.bin"
        self.f = open(self.path, "wb")  # noqa: SIM115
        self.n = 0
        self.name = name

    def add(self, x: np.ndarray) -> None:
        np.ascontiguousarray(x, dtype=self.dtype).tofile(self.f)
        self.n += len(x)


CAN_COLUMNS = (("time_s", "<f8"), ("host_time_s", "<f8"), ("id", "<u4"), ("extended", "u1"),
               ("error_frame", "u1"), ("tx", "u1"), ("length", "u1"))
"""The MAT-file's frame variables (``can_<name>``) and their types."""


class MatWriter(Writer):
    """``<run>.mat``: ``time_s`` and one column vector per channel (SI, named
    ``attitude_angle_rad``), the frames as ``can_time_s`` (run time), ``can_host_time_s``,
    ``can_id``, ``can_extended``, ``can_error_frame``, ``can_tx``, ``can_length`` and
    ``can_data`` (n x 8 uint8), and ``metadata`` (a struct: ``channels`` with each
    variable's unit and source, the configuration, summary and verdict as JSON text:
    ``jsondecode(metadata.summary_json)``)."""

    ext = "mat"
    _tmp: Path | None = None
    _spools: list[_Spool]

    def open(self) -> None:
        self._spools = []
        self._path = self.target(".mat")
        self._tmp = Path(tempfile.mkdtemp(prefix=".export-", dir=self.base.parent))
        self._t = self._spool("time_s", "<f8")
        self._cols = {c.source: self._spool(c.ident, "<f8") for c in self.chs}
        self._fr = {k: self._spool(f"can_{k}", d) for k, d in CAN_COLUMNS}
        self._bytes = [self._spool(f"can_data_{i}", "u1") for i in range(8)]

    def _spool(self, name: str, dtype: str) -> _Spool:
        assert self._tmp is not None
        sp = _Spool(self._tmp, name, dtype)
        self._spools.append(sp)
        return sp

    def channels(self, t: np.ndarray, cols: dict[str, np.ndarray]) -> None:
        self._t.add(t)
        for source, sp in self._cols.items():
            sp.add(cols[source])

    def frames(self, f: Frames) -> None:
        for k, x in (("time_s", f.time_s), ("host_time_s", f.host_time_s), ("id", f.can_id),
                     ("extended", f.extended), ("error_frame", f.error), ("tx", f.tx),
                     ("length", f.length)):
            self._fr[k].add(x)
        for i, sp in enumerate(self._bytes):
            sp.add(f.data[:, i])

    def _element(self, out: Any, name: str, spools: list[_Spool]) -> None:
        """A numeric matrix: rows = each spool's length, one column per spool."""
        rows, dtype = spools[0].n, spools[0].dtype
        mx, mi = MX[dtype]
        data = rows * len(spools) * dtype.itemsize
        if data > MAT_MAX_BYTES:
            raise ExportError(f"{self.base.name}.mat: {name} is {data} bytes, beyond the "
                              "4 GB a MAT-file level 5 variable holds; export to parquet or mf4")
        bname = name.encode()
        body = 16 + 16 + 8 + len(bname) + _pad8(len(bname)) + 8 + data + _pad8(data)
        out.write(struct.pack("<II", MI_MATRIX, body))
        out.write(struct.pack("<IIII", MI_UINT32, 8, mx, 0))
        out.write(struct.pack("<IIii", MI_INT32, 8, rows, len(spools)))
        out.write(struct.pack("<II", MI_INT8, len(bname)) + bname + b"\0" * _pad8(len(bname)))
        out.write(struct.pack("<II", mi, data))
        for sp in spools:
            sp.f.close()
            with open(sp.path, "rb") as src:
                shutil.copyfileobj(src, out, 1 << 20)
        out.write(b"\0" * _pad8(data))

    def finish(self) -> None:
        from scipy.io import savemat

        origin = self.meta.get("host_time_origin_s")
        meta = {
            "format": "sgsrt-harness export, MAT-file level 5",
            "run_folder": self.meta.get("run_folder", ""),
            "channels": {c.ident: {"unit": c.unit, "source": c.source, "name": c.name}
                         for c in self.chs},
            "config_json": json.dumps(self.meta.get("config"), default=str),
            "summary_json": json.dumps(self.meta.get("summary"), default=str),
            "verdict_json": json.dumps(self.meta.get("verdict"), default=str),
            "time_axis": str(self.meta.get("time_axis", "")),
            "host_time_origin_s": float(origin) if origin is not None else float("nan"),
            "bus_files_json": json.dumps(self.meta.get("bus_files", [])),
        }
        head = io.BytesIO()
        savemat(head, {"metadata": meta}, long_field_names=True, do_compression=False)
        try:
            with open(self._path, "wb") as out:
                out.write(head.getvalue())
                self._element(out, "time_s", [self._t])
                for sp in self._cols.values():
                    self._element(out, sp.name, [sp])
                for sp in self._fr.values():
                    self._element(out, sp.name, [sp])
                self._element(out, "can_data", self._bytes)
        finally:
            self._cleanup()

    def _cleanup(self) -> None:
        for sp in getattr(self, "_spools", []):
            sp.f.close()
        if self._tmp is not None:
            shutil.rmtree(self._tmp, ignore_errors=True)

    def abort(self) -> None:
        self._cleanup()
        super().abort()


# ------------------------------------------------------------------------------ MDF4
def _bus_attachment(files: list[Path], used: set[tuple[tuple[int, bool], str]] | None = None
                    ) -> tuple[bytes, str, bytes] | None:
    """The DBC the CAN groups reference, for a bus-logging reader to decode the frames by
    (asammdf, CANape): the rig's one DBC, or its DBCs merged into one when it binds several
    (an id two files define: the message the binding uses, ``used`` holding each frame's
    (id, extended) and name; an id neither uses is left out). None when the rig binds no
    DBC or the files cannot be merged (each stays embedded on its own)."""
    dbcs = [p for p in files if p.suffix.lower() == ".dbc"]
    if not dbcs:
        return None
    if len(dbcs) == 1:
        data = dbcs[0].read_bytes()
        return data, dbcs[0].name, hashlib.md5(data).digest()  # noqa: S324 - MDF's checksum
    import cantools

    used = used or set()
    try:
        by_key: dict[tuple[int, bool], list[Any]] = {}
        nodes: dict[str, Any] = {}
        for p in dbcs:
            db = cantools.database.load_file(str(p), database_format="dbc", strict=False)
            for m in db.messages:
                by_key.setdefault((m.frame_id, m.is_extended_frame), []).append(m)
            for n in db.nodes:
                nodes.setdefault(n.name, n)
        merged = cantools.database.can.Database()
        for key, msgs in sorted(by_key.items()):
            if len(msgs) > 1:
                msgs = [m for m in msgs if (key, m.name) in used][:1]
            merged.messages.extend(msgs)
        merged.nodes.extend(nodes.values())
        merged.refresh()
        data = merged.as_dbc_string().encode()
    except Exception:  # noqa: BLE001 - the files stay embedded on their own
        return None
    return data, "rig.dbc", hashlib.md5(data).digest()  # noqa: S324


class Mf4Writer(Writer):
    """``<run>.mf4`` (ASAM MDF 4.10): a channel group ``channels`` (master ``time`` in s,
    every channel with its SI unit, its source in the comment), the frames as bus-logging
    groups ``CAN_DataFrame`` and ``CAN_ErrorFrame`` on the same time axis (the ASAM
    bus-logging layout python-can writes too, each frame's direction in ``.Dir``: 1 Tx,
    sent by the harness, 0 Rx), the rig's DBC referenced by those groups and every DBC or
    EDS file of its binding embedded, each group's host time stamps in a plain group
    beside it, and config.yaml, summary.json and verdict.json as embedded attachments."""

    ext = "mf4"
    DATA = [("CAN_DataFrame.BusChannel", "<u1"), ("CAN_DataFrame.ID", "<u4"),
            ("CAN_DataFrame.IDE", "<u1"), ("CAN_DataFrame.DLC", "<u1"),
            ("CAN_DataFrame.DataLength", "<u1"), ("CAN_DataFrame.DataBytes", "(8,)u1"),
            ("CAN_DataFrame.Dir", "<u1")]
    HOST = {"CAN_DataFrame": "can.data_frame.host_time_s",
            "CAN_ErrorFrame": "can.error_frame.host_time_s"}
    """The plain channel holding a bus group's host time stamps, record for record."""
    _mdf: Any = None

    def open(self) -> None:
        from asammdf import MDF

        self._path = self.target(".mf4")
        # asammdf keeps appended data in a temporary file until it saves: beside the output
        self._mdf = MDF(version="4.10", temporary_folder=str(self.base.parent))
        self._attachment = _bus_attachment(self.bus_files, self.bus_frames)
        self._groups: dict[str, int] = {}
        self._rows: list[tuple[np.ndarray, dict[str, np.ndarray]]] = []
        self._n = 0
        self._frows: list[Frames] = []
        self._fn = 0

    def channels(self, t: np.ndarray, cols: dict[str, np.ndarray]) -> None:
        self._rows.append((t, cols))
        self._n += len(t)
        if self._n >= ROW_GROUP:
            self._flush()

    def _flush(self) -> None:
        from asammdf import Signal

        if not self._rows:
            return
        t = np.concatenate([r[0] for r in self._rows])
        cols = {c.source: np.concatenate([r[1][c.source] for r in self._rows])
                for c in self.chs}
        self._rows, self._n = [], 0
        if "channels" not in self._groups:
            self._groups["channels"] = len(self._mdf.groups)
            self._mdf.append([Signal(cols[c.source], t, name=c.name, unit=c.unit,
                                     comment=f"run.rrd {c.source}") for c in self.chs],
                             acq_name="channels", comment="the loop's channels, one row a tick")
        else:
            self._mdf.extend(self._groups["channels"],
                             [(t, None)] + [(cols[c.source], None) for c in self.chs])

    def _frame_group(self, name: str, rows: np.ndarray, t: np.ndarray,
                     host: np.ndarray) -> None:
        from asammdf import Signal
        from asammdf.blocks.v4_blocks import SourceInformation
        from asammdf.blocks.v4_constants import BUS_TYPE_CAN, SOURCE_BUS

        if name not in self._groups:
            self._groups[name] = len(self._mdf.groups)
            self._mdf.append(Signal(rows, t, name=name, attachment=self._attachment,
                                    source=SourceInformation(source_type=SOURCE_BUS,
                                                             bus_type=BUS_TYPE_CAN)),
                             acq_name="CAN")
            self._groups[self.HOST[name]] = len(self._mdf.groups)
            self._mdf.append(Signal(host, t, name=self.HOST[name], unit="s", comment=(
                f"the host's time stamp (POSIX time, can.blf's) of each {name} record, "
                "record for record; the master is the run time")),
                acq_name="CAN host time")
        else:
            self._mdf.extend(self._groups[name], [(t, None), (rows, None)])
            self._mdf.extend(self._groups[self.HOST[name]], [(t, None), (host, None)])

    def frames(self, f: Frames) -> None:
        self._frows.append(f)
        self._fn += len(f.time_s)
        if self._fn >= ROW_GROUP:
            self._flush_frames()

    def _flush_frames(self) -> None:
        if not self._frows:
            return
        f = joined(self._frows)
        self._frows, self._fn = [], 0
        for name, sel in (("CAN_DataFrame", ~f.error), ("CAN_ErrorFrame", f.error)):
            if not sel.any():
                continue
            dt = np.dtype([(k.replace("CAN_DataFrame", name), v) for k, v in self.DATA])
            rows = np.zeros(int(sel.sum()), dtype=dt)
            rows[f"{name}.ID"] = f.can_id[sel]
            rows[f"{name}.IDE"] = f.extended[sel]
            rows[f"{name}.DLC"] = f.length[sel]
            rows[f"{name}.DataLength"] = f.length[sel]
            rows[f"{name}.DataBytes"] = f.data[sel]
            rows[f"{name}.Dir"] = f.tx[sel]
            self._frame_group(name, rows, f.time_s[sel], f.host_time_s[sel])

    def finish(self) -> None:
        import datetime as _dt

        self._flush()
        self._flush_frames()
        origin = self.meta.get("host_time_origin_s")
        if origin:
            self._mdf.header.start_time = _dt.datetime.fromtimestamp(origin, _dt.UTC)
        self._mdf.header.comment = (
            f"sgsrt-harness export of {self.meta.get('run_folder', '')}: every group's "
            "master is the run time (tick k at k x period); the header's start time is the "
            "host time of run time 0; each CAN frame's host time stamp is in the group "
            "'CAN host time'")
        for name, key in (("config.json", "config"), ("summary.json", "summary"),
                          ("verdict.json", "verdict"), ("channels.json", "channels")):
            doc = self.meta.get(key) if key != "channels" else [
                {"name": c.name, "unit": c.unit, "source": c.source} for c in self.chs]
            self._mdf.attach(json.dumps(doc, indent=2, default=str).encode(), file_name=name,
                             embedded=True, mime="application/json")
        for p in self.bus_files:  # every DBC and EDS file of the rig's binding
            data = p.read_bytes()
            kind = "dbc" if p.suffix.lower() == ".dbc" else "eds"
            self._mdf.attach(data, file_name=p.name, hash_sum=hashlib.md5(data).digest(),  # noqa: S324
                             embedded=True, mime=f"application/x-{kind}",
                             comment=f"the rig's {kind.upper()} file {printable(str(p))}")
        self._mdf.save(self._path, overwrite=True, compression=1)
        self._mdf.close()
        self._mdf = None

    def abort(self) -> None:
        _close_quietly(self._mdf)
        super().abort()


WRITERS: dict[str, type[Writer]] = {"csv": CsvWriter, "parquet": ParquetWriter,
                                    "mat": MatWriter, "mf4": Mf4Writer}
