"""What an export reads from a run folder: the channels in SI, block by block; the CAN
frames, block by block; the metadata. Every file is checked as it is opened and a bad one
is refused naming it (``ExportError``), never a traceback."""

from __future__ import annotations

import hashlib
import json
import math
import os
import re
from array import array
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
MAX_META_DEPTH = 64
"""Their nesting (the harness writes 6 levels at most); a deeper document is refused: the
writers' JSON and MATLAB encoders recurse once a level."""


def nesting(doc: Any) -> int:
    """How deep lists and mappings nest in ``doc`` (a scalar: 0), without recursion, and
    stopping once past ``MAX_META_DEPTH``."""
    deepest = 0
    stack: list[tuple[Any, int]] = [(doc, 0)]
    while stack:
        x, d = stack.pop()
        if isinstance(x, Mapping | list | tuple):
            d += 1
            deepest = max(deepest, d)
            if deepest > MAX_META_DEPTH:
                return deepest
            stack.extend((v, d) for v in (x.values() if isinstance(x, Mapping) else x))
    return deepest


def _check_nesting(path: Path, doc: Any) -> None:
    if nesting(doc) > MAX_META_DEPTH:
        raise ExportError(f"{path}: nested more than {MAX_META_DEPTH} levels deep (the "
                          "harness writes 6 at most): not a file of a run")


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
    _check_nesting(path, doc)
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
    except (OSError, RecursionError) as exc:
        raise ExportError(f"{cfg_path}: not readable ({type(exc).__name__}: "
                          f"{str(exc)[:120]})") from None
    if not isinstance(config, dict):
        raise ExportError(f"{cfg_path}: expected a mapping, got a {type(config).__name__}")
    _check_nesting(cfg_path, config)
    summary = _json_file(run_dir / "summary.json", required=False)
    verdict = _json_file(run_dir / "verdict.json", required=False)
    rate = (summary or {}).get("rate_hz")
    if summary is not None and rate is not None and not (
            isinstance(rate, int | float) and not isinstance(rate, bool)
            and math.isfinite(rate) and rate > 0):
        raise ExportError(f"{run_dir / 'summary.json'}: rate_hz: expected a number > 0, got "
                          f"{rate!r}")
    return {"run_folder": printable(run_dir.name), "config": config, "summary": summary,
            "verdict": verdict}


def printable(text: str) -> str:
    """A file name as text every format can hold (MDF4's XML, MATLAB's UTF-8): bytes that
    are not UTF-8 and control characters written as escapes (``\\xff``)."""
    text = os.fsencode(text).decode("utf-8", "backslashreplace")
    return "".join(c if c.isprintable() else f"\\x{ord(c):02x}" if ord(c) < 256
                   else f"\\u{ord(c):04x}" for c in text)


# ------------------------------------------------------------------------------ channels
def _merge(parts: dict[str, list[tuple[np.ndarray, np.ndarray]]], entities: list[str],
           before: float) -> tuple[np.ndarray, dict[str, np.ndarray]] | None:
    """The rows before ``before`` s of every entity's pending blocks, on their union of
    times (a channel without a sample at a time is NaN there; the loop's channels share
    their times, so normally nothing is filled); what lies later stays pending."""
    taken: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for e in entities:
        blocks = parts[e]
        t = np.concatenate([b[0] for b in blocks]) if blocks else np.empty(0)
        x = np.concatenate([b[1] for b in blocks]) if blocks else np.empty(0)
        keep = t < before
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


def _scalar_chunks(rrd: Path, entities: list[str], values: bool
                   ) -> Iterator[tuple[str, np.ndarray, np.ndarray | None]]:
    """``harness.record.reader.scalar_chunks``, a recording out of time order an
    ExportError."""
    from harness.record.reader import OutOfOrder, scalar_chunks

    try:
        yield from scalar_chunks(rrd, entities, values)
    except OutOfOrder as exc:
        raise ExportError(str(exc)) from exc


def channel_index(rrd: Path, channels: list[Channel]) -> dict[str, np.ndarray]:
    """The first pass: each channel's chunks' first times, in the file's order (8 bytes a
    chunk of 2500 or 500 rows). With it the second pass knows, at every point of the
    file, the earliest time a channel may still bring, so rows before the earliest of
    them are complete and go out: memory is what the file's order makes it (a few blocks
    for the recorder's files), whatever channels a recording lacks in all or part of the
    run. Also checks the whole recording before anything is written."""
    starts: dict[str, array[float]] = {c.source: array("d") for c in channels}
    try:
        for e, t, _ in _scalar_chunks(rrd, [c.source for c in channels], values=False):
            starts[e].append(float(t[0]))
    except ExportError:
        raise
    except Exception as exc:  # a damaged recording: Rerun raises various kinds
        raise ExportError(f"{rrd}: cannot read ({type(exc).__name__}: "
                          f"{str(exc)[:200]})") from None
    return {e: np.frombuffer(a, dtype=np.float64) if len(a) else np.empty(0)
            for e, a in starts.items()}


MAX_HELD_SAMPLES = 1_000_000
"""Samples (all channels) held waiting for a channel that lags in the file's order before
that channel is read ahead on its own (16 MB: the recorder's files lag a block at most)."""


def channel_blocks(rrd: Path, channels: list[Channel],
                   index: Mapping[str, np.ndarray] | None = None
                   ) -> Iterator[tuple[np.ndarray, dict[str, np.ndarray]]]:
    """(time s, {entity: values in SI}) blocks of the loop's rows, in time order, read
    chunk by chunk; ``index`` is ``channel_index``'s first pass (made here when not given).
    Rows go out as soon as no channel can bring an earlier sample: a channel the recording
    lacks (in all or part of the run) is NaN in its rows and holds nothing back. A channel
    whose chunks come late in the file (a merged recording) is read ahead by a second
    reader of its own once ``MAX_HELD_SAMPLES`` wait for it: memory stays bounded whatever
    the layout."""
    entities = [c.source for c in channels]
    factor = {c.source: c.factor for c in channels}
    if index is None:
        index = channel_index(rrd, channels)
    nxt = {e: 0 for e in entities}  # the entity's next chunk in the index
    parts: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {e: [] for e in entities}
    side: dict[str, Iterator[tuple[str, np.ndarray, np.ndarray | None]]] = {}
    held = 0
    done = -math.inf  # the rows before this went out

    def changed() -> ExportError:
        return ExportError(f"{rrd}: changed while it was exported (still being recorded?)")

    def take(e: str, t: np.ndarray, x: np.ndarray | None) -> None:
        nonlocal held
        k = nxt[e]
        if k >= len(index[e]) or float(index[e][k]) != float(t[0]) or x is None:
            raise changed()
        nxt[e] = k + 1
        parts[e].append((t, x * factor[e]))
        held += len(t)

    def blocker() -> str | None:
        """The channel whose next chunk is the earliest still to read."""
        left = [e for e in entities if nxt[e] < len(index[e])]
        return min(left, key=lambda e: float(index[e][nxt[e]])) if left else None

    def flush() -> Iterator[tuple[np.ndarray, dict[str, np.ndarray]]]:
        nonlocal done, held
        b = blocker()
        before = float(index[b][nxt[b]]) if b is not None else math.inf
        if before > done and before != math.inf:
            got = _merge(parts, entities, before)
            done = before
            held = sum(len(p[0]) for ps in parts.values() for p in ps)
            if got is not None:
                yield got

    def read_ahead() -> Iterator[tuple[np.ndarray, dict[str, np.ndarray]]]:
        """One chunk of the channel that holds the rows back, from its own reader."""
        b = blocker()
        if b is None:
            return
        if b not in side:
            it = _scalar_chunks(rrd, [b], values=True)
            for _ in range(nxt[b]):  # its chunks the main reader already gave
                next(it, None)
            side[b] = it
        got = next(side[b], None)
        if got is None:
            raise changed()
        take(*got)
        yield from flush()

    try:
        for e, t, x in _scalar_chunks(rrd, entities, values=True):
            if e in side:
                continue  # read by its own reader
            take(e, t, x)
            yield from flush()
            while held > MAX_HELD_SAMPLES and blocker() is not None:
                yield from read_ahead()
        while any(nxt[e] < len(index[e]) for e in side):
            yield from read_ahead()
    except ExportError:
        raise
    except Exception as exc:  # a damaged recording: Rerun raises various kinds
        raise ExportError(f"{rrd}: cannot read ({type(exc).__name__}: "
                          f"{str(exc)[:200]})") from None
    if any(nxt[e] < len(index[e]) for e in entities):
        raise changed()
    got = _merge(parts, entities, math.inf)  # the tail (a run cut short: some may lack it)
    if got is not None:
        yield got


MAX_NAME = 200
"""The longest base name of an exported file: with the longest ending
(``.metadata.json``) and a temporary file's (``.<name>.<8 random>.partial.json``) it stays
within the 255 bytes a file name may have."""


def safe_name(name: str) -> str:
    """A run folder's name as a file name: letters, digits, '.', '-', '_' (a hand-made
    folder's name can never write elsewhere); a name longer than ``MAX_NAME`` is cut and
    ends in 8 hex digits of its hash (two long names sharing a start stay apart)."""
    out = re.sub(r"[^A-Za-z0-9._-]", "_", name).lstrip(".") or "run"
    if len(out) > MAX_NAME:
        digest = hashlib.sha256(name.encode("utf-8", "surrogateescape")).hexdigest()[:8]
        out = f"{out[:MAX_NAME - 9]}-{digest}"
    return out


def metadata_json(meta: Mapping[str, Any], channels: list[Channel], extra: Mapping[str, Any]
                  ) -> str:
    doc = {**meta, **extra, "channels": [
        {"name": c.name, "unit": c.unit, "source": c.source, "factor_to_si": c.factor}
        for c in channels]}
    return json.dumps(doc, indent=2, default=str)
