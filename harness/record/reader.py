"""Reading a run's recording back (Rerun 0.41 ``rerun.chunk.RrdReader``)."""

from __future__ import annotations

import os
import struct
import tempfile
import warnings
import weakref
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
from rerun.chunk import RrdReader as _RrdReader

FILE_HEADER_BYTES = 12
"""An RRD stream starts with ``RRF2``, the encoder's version (4 bytes) and its options (4)."""
MESSAGE_HEADER_BYTES = 16
"""Each message: its kind and its payload's length, two little-endian u64, then the payload."""
MESSAGE_KINDS = (0, 1, 2, 3)
"""End, SetStoreInfo, ArrowMsg, BlueprintActivationCommand (rerun 0.41's re_log_encoding)."""


def complete_length(path: Path) -> int:
    """Bytes of ``path`` up to the end of its last complete message: the whole file unless
    it was cut (a full disk, power loss, a SIGKILL mid-write). Reads 16 bytes a message."""
    path = Path(path)
    size = path.stat().st_size
    end = 0
    with open(path, "rb") as f:
        pos = 0
        while pos < size:
            f.seek(pos)
            head = f.read(MESSAGE_HEADER_BYTES)
            if head[:4] == b"RRF2":  # a stream's header (a file may hold several streams)
                if len(head) < FILE_HEADER_BYTES:
                    break
                pos += FILE_HEADER_BYTES
                end = pos
                continue
            if len(head) < MESSAGE_HEADER_BYTES:
                break
            kind, length = struct.unpack("<QQ", head)
            if kind not in MESSAGE_KINDS or pos + MESSAGE_HEADER_BYTES + length > size:
                break  # cut inside this message (or bytes that are not a message)
            pos += MESSAGE_HEADER_BYTES + length
            end = pos
    return end


def _open(path: Path) -> _RrdReader:
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="RRD file has no footer")
        reader = _RrdReader(path)
        reader._internal.store_entries()  # Rerun's whole-file scan: raises on a cut file
    return reader


def RrdReader(path: Path) -> _RrdReader:  # noqa: N802 - stands in for the class
    """Rerun's reader, without its warning on files written with no footer (ours are, on
    purpose: harness.record.recording). A file cut at any byte (a full disk, power loss)
    is read to its last complete message: Rerun refuses such a file as a whole, so its
    complete part is copied to a temporary file (outside the run folder, removed with the
    reader)."""
    path = Path(path)
    try:
        return _open(path)
    except (RuntimeError, ValueError) as exc:
        if not path.is_file():
            raise
        end = complete_length(path)
        if end >= path.stat().st_size:
            raise
        if end <= FILE_HEADER_BYTES:
            raise ValueError(f"{path}: no complete message (the file was cut at byte "
                             f"{path.stat().st_size})") from exc
        return _open_prefix(path, end)


def _open_prefix(path: Path, end: int) -> _RrdReader:
    fd, tmp_name = tempfile.mkstemp(prefix="sgsrt-cut-", suffix=".rrd")
    tmp = Path(tmp_name)
    try:
        with open(path, "rb") as src, os.fdopen(fd, "wb") as dst:
            left = end
            while left > 0:  # in pieces: memory stays bounded whatever the file's size
                piece = src.read(min(left, 1 << 20))
                if not piece:
                    break
                dst.write(piece)
                left -= len(piece)
        reader = _open(tmp)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    # Rerun keeps the file open while a stream reads it: removing the name is safe
    weakref.finalize(reader, tmp.unlink, missing_ok=True)
    return reader


def iter_chunks(rrd: Path, content: list[str] | str | None = None,
                drop: list[str] | str | None = None, store: object = None) -> object:
    """The recording's chunks one at a time, never the whole file in memory
    (``stream().to_chunks()`` materialises every chunk: a 200 s run's judge took 200 MB
    more than a 20 s run's). ``content``: keep only these entity path filters (an exact
    path, or ``/a/**`` for a subtree); ``drop``: leave these out. A cut file gives every
    complete chunk (``RrdReader``)."""
    reader = RrdReader(rrd)
    stream = reader.stream(store=store) if store is not None else reader.stream()
    if content is not None:
        stream = stream.filter(content=content)
    if drop is not None:
        stream = stream.drop(content=drop)
    return _iterate(reader, stream)


def _iterate(reader: _RrdReader, stream: object) -> Iterator[object]:
    # holds the reader (and a cut file's temporary copy) until the last chunk is read
    yield from iter(stream)  # type: ignore[call-overload]
    del reader


def scalar_values(column: Any) -> np.ndarray:
    """A chunk's ``Scalars:scalars`` column (a list per row) as one float per row: each
    row's first value, NaN for a null or empty row. The usual column, one value in every
    row, is taken as arrow's flat values (no Python object a row: a 100 s run's channels
    are five million rows)."""
    if column.null_count == 0 and hasattr(column, "value_lengths"):
        lengths = column.value_lengths().to_numpy(zero_copy_only=False)
        if len(lengths) and lengths.min() == 1 and lengths.max() == 1:
            return column.flatten().to_numpy(zero_copy_only=False).astype(float)
    return _first_of_each_row(column)


def _first_of_each_row(column: Any) -> np.ndarray:
    return np.array([(x[0] if x else np.nan) if isinstance(x, list)
                     else (np.nan if x is None else x) for x in column.to_pylist()],
                    dtype=float)


def read_scalar_channel(rrd: Path, entity: str) -> tuple[np.ndarray, np.ndarray]:
    """(time s, values) of a scalar channel recorded on the ``time`` timeline."""
    times: list[np.ndarray] = []
    values: list[np.ndarray] = []
    for chunk in iter_chunks(rrd, content=[entity]):
        if chunk.entity_path != entity or chunk.is_static or "time" not in chunk.timeline_names:
            continue
        batch = chunk.to_record_batch()
        t = batch.column("time").cast("int64").to_numpy(zero_copy_only=False) * 1e-9
        v = scalar_values(batch.column("Scalars:scalars"))
        times.append(t)
        values.append(v)
    if not times:
        raise ValueError(f"{rrd}: no scalar channel {entity!r} on the 'time' timeline")
    t = np.concatenate(times)
    v = np.concatenate(values)
    order = np.argsort(t, kind="stable")
    return t[order], v[order]


def read_scalar_channels(rrd: Path, entities: list[str] | None = None
                         ) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """(time s, values) of every scalar channel on the ``time`` timeline (or of
    ``entities``), read in one pass over the file."""
    parts: dict[str, tuple[list[np.ndarray], list[np.ndarray]]] = {}
    wanted = None if entities is None else set(entities)
    # the decoded bus (/bus/..., ten times the loop's rows) only when asked for by name
    chunks = iter_chunks(rrd, content=sorted(wanted)) if wanted is not None \
        else iter_chunks(rrd, drop="/bus/**")
    for chunk in chunks:
        path = chunk.entity_path
        if (wanted is not None and path not in wanted) or chunk.is_static \
                or "time" not in chunk.timeline_names:
            continue
        batch = chunk.to_record_batch()
        if "Scalars:scalars" not in batch.schema.names:
            continue
        t = batch.column("time").cast("int64").to_numpy(zero_copy_only=False) * 1e-9
        v = scalar_values(batch.column("Scalars:scalars"))
        ts, vs = parts.setdefault(path, ([], []))
        ts.append(t)
        vs.append(v)
    out = {}
    for path, (ts, vs) in parts.items():
        t = np.concatenate(ts)
        v = np.concatenate(vs)
        order = np.argsort(t, kind="stable")
        out[path] = (t[order], v[order])
    if wanted is not None and (missing := wanted - set(out)):
        raise ValueError(f"{rrd}: no scalar channel {sorted(missing)} on the 'time' timeline")
    return out


class RecordedColumns:
    """A run's whole recorded channels read back from its run.rrd: ``time_s``, ``rows`` and
    ``column(channel)`` (what ``Recorder`` offered when it kept the whole run in memory)."""

    def __init__(self, rrd: Path) -> None:
        self.path = rrd
        self._channels = read_scalar_channels(rrd)
        if not self._channels:
            raise ValueError(f"{rrd}: no scalar channels on the 'time' timeline")
        # the loop's rows; decoded bus frames (/bus/...) are logged per frame, not per row
        # (a wheel run's safe command at the end is one frame more than the loop's rows)
        rows = {k: tv for k, tv in self._channels.items() if not k.startswith("/bus/")}
        longest = max((rows or self._channels).values(), key=lambda tv: len(tv[0]))
        self.time_s = longest[0]
        self.rows = len(self.time_s)

    def column(self, channel: str) -> np.ndarray:
        try:
            t, v = self._channels[channel]
        except KeyError:
            raise ValueError(f"{self.path}: no scalar channel {channel!r}") from None
        if len(t) != self.rows:
            raise ValueError(f"{self.path}: {channel} has {len(t)} rows, time has {self.rows}")
        return v


class OutOfOrder(ValueError):
    """A channel's samples are not in time order (an edited or merged recording)."""


def scalar_chunks(rrd: Path, entities: list[str], values: bool = True
                  ) -> Iterator[tuple[str, np.ndarray, np.ndarray | None]]:
    """(entity, times s, values or None) of each non-empty chunk of scalar channels on the
    ``time`` timeline, in the file's order (``values`` False: the times only, the values
    not decoded). OutOfOrder (a ValueError) when an entity's samples are not in time order
    (an edited or merged recording): a reader that streams them block by block relies on
    that order."""
    wanted = set(entities)
    last: dict[str, float] = {}
    for chunk in iter_chunks(rrd, content=list(entities)):
        e = chunk.entity_path
        if e not in wanted or chunk.is_static or "time" not in chunk.timeline_names:
            continue
        batch = chunk.to_record_batch()
        if "Scalars:scalars" not in batch.schema.names:
            continue
        t = batch.column("time").cast("int64").to_numpy(zero_copy_only=False) * 1e-9
        if not len(t):
            continue
        if np.any(np.diff(t) < 0) or t[0] < last.get(e, -np.inf):
            raise OutOfOrder(f"{rrd}: {e}: samples not in time order (an edited or merged "
                             "recording)")
        last[e] = float(t[-1])
        yield e, t, (scalar_values(batch.column("Scalars:scalars")) if values else None)


def aligned_scalar_blocks(rrd: Path, entities: list[str]
                          ) -> Iterator[tuple[np.ndarray, dict[str, np.ndarray]]]:
    """(time s, {entity: values}) blocks of scalar channels sampled at the same times (the
    loop's channels), in time order, read chunk by chunk: a block goes out as soon as every
    channel has brought its samples up to its end, so what is held is the chunks by which
    one channel runs ahead of another in the file (a block or two for the recorder's
    files), never the whole record. ValueError when a channel is missing, a channel's
    samples are not in time order, or the channels' times differ."""
    wanted = list(dict.fromkeys(entities))
    pending: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {e: [] for e in wanted}
    rows = {e: 0 for e in wanted}
    last = {e: -np.inf for e in wanted}

    def take(upto: float) -> tuple[np.ndarray, dict[str, np.ndarray]] | None:
        out: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        for e in wanted:
            t = np.concatenate([p[0] for p in pending[e]]) if pending[e] else np.empty(0)
            v = np.concatenate([p[1] for p in pending[e]]) if pending[e] else np.empty(0)
            k = int(np.searchsorted(t, upto, side="right"))
            out[e] = (t[:k], v[:k])
            pending[e] = [(t[k:], v[k:])] if k < len(t) else []
        t0 = out[wanted[0]][0]
        for e in wanted[1:]:
            if not np.array_equal(out[e][0], t0):
                raise ValueError(f"{rrd}: {e} and {wanted[0]} are not sampled at the same "
                                 "times")
        if not len(t0):
            return None
        return t0, {e: tv[1] for e, tv in out.items()}

    for e, t, v in scalar_chunks(rrd, wanted):
        assert v is not None
        last[e] = float(t[-1])
        rows[e] += len(t)
        pending[e].append((t, v))
        upto = min(last.values())
        if upto > -np.inf:
            got = take(upto)
            if got is not None:
                yield got
    if missing := [e for e in wanted if not rows[e]]:
        raise ValueError(f"{rrd}: no scalar channel {missing} on the 'time' timeline")
    if any(pending[e] for e in wanted):
        first = wanted[0]
        other = next(e for e in wanted if rows[e] != rows[first]) \
            if any(rows[e] != rows[first] for e in wanted) else wanted[-1]
        raise ValueError(f"{other} has {rows[other]} rows, {first} {rows[first]}")
