"""What an export reads from a run folder: the channels in SI, block by block; the CAN
frames, block by block; the metadata. Every file is checked as it is opened and a bad one
is refused naming it (``ExportError``), never a traceback."""

from __future__ import annotations

import json
import math
import re
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np


class ExportError(Exception):
    """The run folder or the output cannot be exported (exit 2); the message names the file."""


class OutputFailed(ExportError):
    """Writing into the output folder failed: full, read-only, an I/O error (exit 4)."""


SI: dict[str, tuple[str, float, str]] = {
    # suffix: (SI suffix, factor to SI, unit text)
    "deg": ("rad", math.pi / 180.0, "rad"),
    "deg_s": ("rad_s", math.pi / 180.0, "rad/s"),
    "ms": ("s", 1e-3, "s"),
    "rad": ("rad", 1.0, "rad"),
    "rad_s": ("rad_s", 1.0, "rad/s"),
    "m_s2": ("m_s2", 1.0, "m/s^2"),
    "n_m": ("n_m", 1.0, "N m"),
    "v": ("v", 1.0, "V"),
    "a": ("a", 1.0, "A"),
    "s": ("s", 1.0, "s"),
    "m": ("m", 1.0, "m"),
    "hz": ("hz", 1.0, "Hz"),
    "kg": ("kg", 1.0, "kg"),
}
"""Unit suffixes of the recorded channels and their SI form; a name without one is a
count or a state, dimensionless (unit "")."""

_SUFFIXES = sorted(SI, key=len, reverse=True)


@dataclass(frozen=True)
class Channel:
    source: str
    """The entity path in run.rrd (``/attitude/angle_deg``)."""
    name: str
    """The exported name, in SI (``attitude.angle_rad``)."""
    unit: str
    """The SI unit as text (``rad``; "" dimensionless)."""
    factor: float
    """SI value = recorded value x factor."""

    @property
    def ident(self) -> str:
        """The name as an identifier (MATLAB variables: ``attitude_angle_rad``)."""
        return self.name.replace(".", "_")


def channel_of(entity: str) -> Channel:
    path = entity.strip("/").split("/")
    last = path[-1]
    for suffix in _SUFFIXES:
        if last == suffix or last.endswith("_" + suffix):
            si, factor, text = SI[suffix]
            path[-1] = last[: len(last) - len(suffix)] + si
            return Channel(entity, ".".join(path), text, factor)
    return Channel(entity, ".".join(path), "", 1.0)


def loop_channels() -> list[Channel]:
    from harness.core.loop import CHANNELS  # the channels the loop records every tick

    return [channel_of(c) for c in CHANNELS]


# ------------------------------------------------------------------------------ metadata
MAX_META_BYTES = 16 * 1024 * 1024
"""config.yaml, summary.json and verdict.json are a few KB; past this they are refused."""


def _json_file(path: Path, required: bool) -> Any:
    if not path.is_file():
        if required:
            raise ExportError(f"{path}: no such file")
        return None
    if path.stat().st_size > MAX_META_BYTES:
        raise ExportError(f"{path}: {path.stat().st_size} bytes, more than a run writes "
                          f"({MAX_META_BYTES} at most)")
    try:
        doc = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, ValueError, RecursionError) as exc:
        raise ExportError(f"{path}: not readable JSON ({type(exc).__name__}: "
                          f"{str(exc)[:120]})") from None
    if not isinstance(doc, dict):
        raise ExportError(f"{path}: expected a JSON object, got a {type(doc).__name__}")
    return doc


def read_metadata(run_dir: Path) -> dict[str, Any]:
    """config.yaml (required: it makes a folder a run folder), summary.json (absent when
    the harness was killed: null), verdict.json (absent when never judged: null)."""
    from rig_models.schema import ConfigError
    from rig_models.yaml_file import load_yaml

    cfg_path = run_dir / "config.yaml"
    if not cfg_path.is_file():
        raise ExportError(f"{cfg_path}: no such file (not a run folder)")
    if cfg_path.stat().st_size > MAX_META_BYTES:
        raise ExportError(f"{cfg_path}: {cfg_path.stat().st_size} bytes, more than a run "
                          "writes")
    try:
        config = load_yaml(cfg_path, "config.yaml")
    except ConfigError as exc:
        raise ExportError(str(exc)) from None
    if not isinstance(config, dict):
        raise ExportError(f"{cfg_path}: expected a mapping, got a {type(config).__name__}")
    summary = _json_file(run_dir / "summary.json", required=False)
    verdict = _json_file(run_dir / "verdict.json", required=False)
    rate = (summary or {}).get("rate_hz")
    if summary is not None and rate is not None and not (
            isinstance(rate, int | float) and not isinstance(rate, bool)
            and math.isfinite(rate) and rate > 0):
        raise ExportError(f"{run_dir / 'summary.json'}: rate_hz: expected a number > 0, got "
                          f"{rate!r}")
    return {"run_folder": run_dir.name, "config": config, "summary": summary,
            "verdict": verdict}


# ------------------------------------------------------------------------------ channels
def _merge(parts: dict[str, list[tuple[np.ndarray, np.ndarray]]], entities: list[str],
           upto: float) -> tuple[np.ndarray, dict[str, np.ndarray]] | None:
    """The rows up to ``upto`` s of every entity's pending blocks, on their union of times
    (a channel without a sample at a time is NaN there; the loop's channels share their
    times, so normally nothing is filled); what lies later stays pending."""
    taken: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for e in entities:
        blocks = parts[e]
        t = np.concatenate([b[0] for b in blocks]) if blocks else np.empty(0)
        x = np.concatenate([b[1] for b in blocks]) if blocks else np.empty(0)
        keep = t <= upto
        taken[e] = (t[keep], x[keep])
        parts[e] = [(t[~keep], x[~keep])] if (~keep).any() else []
    times = [tx[0] for tx in taken.values()]
    if not any(len(t) for t in times):
        return None
    first = times[0]
    if all(len(t) == len(first) and np.array_equal(t, first) for t in times):
        return first, {e: tx[1] for e, tx in taken.items()}
    union = np.unique(np.concatenate(times))
    cols = {}
    for e, (t, x) in taken.items():
        col = np.full(len(union), np.nan)
        if len(t):
            col[np.searchsorted(union, t)] = x
        cols[e] = col
    return union, cols


def channel_blocks(rrd: Path, channels: list[Channel]
                   ) -> Iterator[tuple[np.ndarray, dict[str, np.ndarray]]]:
    """(time s, {entity: values in SI}) blocks of the loop's rows, in time order, read
    chunk by chunk (memory: the few chunks by which one channel runs ahead of another)."""
    from harness.record.reader import iter_chunks, scalar_values

    entities = [c.source for c in channels]
    factor = {c.source: c.factor for c in channels}
    parts: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {e: [] for e in entities}
    last: dict[str, float] = {}
    try:
        for chunk in iter_chunks(rrd, content=entities):
            e = chunk.entity_path
            if e not in parts or chunk.is_static or "time" not in chunk.timeline_names:
                continue
            batch = chunk.to_record_batch()
            if "Scalars:scalars" not in batch.schema.names:
                continue
            t = batch.column("time").cast("int64").to_numpy(zero_copy_only=False) * 1e-9
            if not len(t):
                continue
            if np.any(np.diff(t) < 0) or t[0] < last.get(e, -math.inf):
                raise ExportError(f"{rrd}: {e}: samples not in time order (an edited or "
                                  "merged recording)")
            last[e] = float(t[-1])
            parts[e].append((t, scalar_values(batch.column("Scalars:scalars")) * factor[e]))
            if all(parts[x] for x in entities):
                got = _merge(parts, entities, min(float(parts[x][-1][0][-1]) for x in entities))
                if got is not None:
                    yield got
    except ExportError:
        raise
    except Exception as exc:  # a damaged recording: Rerun raises various kinds
        raise ExportError(f"{rrd}: cannot read ({type(exc).__name__}: {exc})") from None
    got = _merge(parts, entities, math.inf)  # the tail (a run cut short: some may lack it)
    if got is not None:
        yield got


# ------------------------------------------------------------------------------ CAN frames
@dataclass
class Frames:
    """A block of CAN frames: time since the log's first frame (s), id, extended, error
    frame, data length, and the data as 8 bytes a frame (zero past the length)."""

    time_s: np.ndarray
    can_id: np.ndarray
    extended: np.ndarray
    error: np.ndarray
    length: np.ndarray
    data: np.ndarray  # (n, 8) uint8


def frame_blocks(blf: Path, origin: list[float]) -> Iterator[Frames]:
    """can.blf's frames a few containers at a time; ``origin`` (a one-element list, filled
    on the first frame) receives the first frame's absolute time stamp."""
    from harness.record.blf_frames import read_blocks

    try:
        for b in read_blocks(blf):
            if not len(b.timestamp):
                continue
            if not origin:
                origin.append(float(b.timestamp[0]))
            data = b.word.astype("<u8").view(np.uint8).reshape(-1, 8)
            yield Frames(b.timestamp - origin[0], b.arbitration_id.astype(np.uint32),
                         b.is_extended_id.astype(bool), b.is_error_frame.astype(bool),
                         np.minimum(b.length, 8).astype(np.uint8), data)
    except Exception as exc:  # python-can and zlib raise many kinds for a damaged file
        raise ExportError(f"{blf}: cannot read ({type(exc).__name__}: {exc})") from None


FRAME_FIELDS = ("time_s", "can_id", "extended", "error", "length", "data")


def safe_name(name: str) -> str:
    """A run folder's name as a file name: letters, digits, '.', '-', '_' (a hand-made
    folder's name can never write elsewhere)."""
    out = re.sub(r"[^A-Za-z0-9._-]", "_", name).lstrip(".")
    return out or "run"


def metadata_json(meta: Mapping[str, Any], channels: list[Channel], extra: Mapping[str, Any]
                  ) -> str:
    doc = {**meta, **extra, "channels": [
        {"name": c.name, "unit": c.unit, "source": c.source, "factor_to_si": c.factor}
        for c in channels]}
    return json.dumps(doc, indent=2, default=str)
