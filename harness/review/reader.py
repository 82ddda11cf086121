"""Reading back what a reviewer sees: the events, text documents and layouts of an .rrd
(Rerun 0.41 ``rerun.chunk.RrdReader``), for tests and ``tools/make_screenshots``."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from harness.record.reader import RrdReader, iter_chunks


@dataclass(frozen=True)
class Event:
    entity: str
    time_s: float
    level: str
    text: str


def _first(x: object) -> object:
    return x[0] if isinstance(x, list) and x else x


def read_events(rrd: Path) -> list[Event]:
    """Every TextLog under ``/events`` with its time (s), by time."""
    out: list[Event] = []
    for chunk in iter_chunks(rrd, content="/events/**"):
        if not chunk.entity_path.startswith("/events"):
            continue
        batch = chunk.to_record_batch()
        if "TextLog:text" not in batch.schema.names:
            continue
        times = (batch.column("time").cast("int64").to_pylist()
                 if "time" in batch.schema.names else [0] * batch.num_rows)
        levels = (batch.column("TextLog:level").to_pylist()
                  if "TextLog:level" in batch.schema.names else [None] * batch.num_rows)
        for t, lv, tx in zip(times, levels, batch.column("TextLog:text").to_pylist(),
                             strict=True):
            out.append(Event(chunk.entity_path, (t or 0) * 1e-9, str(_first(lv) or ""),
                             str(_first(tx))))
    return sorted(out, key=lambda e: e.time_s)


def read_text(rrd: Path, entity: str) -> str | None:
    """The (last) TextDocument at ``entity``, or None."""
    text = None
    for chunk in iter_chunks(rrd, content=[entity]):
        if chunk.entity_path != entity:
            continue
        batch = chunk.to_record_batch()
        if "TextDocument:text" in batch.schema.names:
            text = str(_first(batch.column("TextDocument:text").to_pylist()[-1]))
    return text


def read_series_names(rrd: Path, points: bool = False) -> dict[str, list[str]]:
    """entity -> the legend's names of its series: the static ``SeriesLines:names`` of the
    plotted channels, or with ``points`` the (last) ``SeriesPoints:names`` of the markers."""
    column = "SeriesPoints:names" if points else "SeriesLines:names"
    out: dict[str, list[str]] = {}
    for chunk in iter_chunks(rrd):
        if not (chunk.is_static or points):
            continue
        batch = chunk.to_record_batch()
        if column in batch.schema.names:
            names = batch.column(column).to_pylist()[-1]
            out[chunk.entity_path] = [str(n) for n in (names or [])]
    return out


def read_series_styles(rrd: Path) -> dict[str, dict[str, object]]:
    """entity -> its static ``SeriesLines`` components (``names``, ``colors``,
    ``aggregation_policy`` as Rerun's enum number, ``interpolation_mode``), last logged."""
    out: dict[str, dict[str, object]] = {}
    for chunk in iter_chunks(rrd):
        if not chunk.is_static:
            continue
        batch = chunk.to_record_batch()
        cols = [c for c in batch.schema.names if c.startswith("SeriesLines:")]
        if cols:
            style = out.setdefault(chunk.entity_path, {})
            for c in cols:
                style[c.split(":", 1)[1]] = _first(batch.column(c).to_pylist()[-1])
    return out


def entities(rrd: Path) -> set[str]:
    """Every entity path with data in the recording."""
    return {c.entity_path for c in iter_chunks(rrd)}


@dataclass(frozen=True)
class SavedView:
    name: str
    kind: str
    origin: str
    contents: tuple[str, ...]
    defaults: tuple[tuple[str, object], ...] = ()
    """The view's component defaults (``SeriesLines:aggregation_policy`` -> its value)."""


def read_blueprints(rrd: Path) -> list[list[SavedView]]:
    """The views of each blueprint stored in the file, in the order they were written."""
    reader = RrdReader(rrd)
    out: list[list[SavedView]] = []
    for store in reader.blueprints():
        views: dict[str, dict[str, object]] = {}
        for chunk in iter(reader.stream(store=store)):
            path = chunk.entity_path
            if not path.startswith("/view/"):
                continue
            parts = path.split("/")
            vid = parts[2]
            batch = chunk.to_record_batch()
            names = batch.schema.names
            v = views.setdefault(vid, {})
            if len(parts) > 3 and parts[3] == "defaults":
                d = v.setdefault("defaults", {})
                for col in names:
                    if ":" in col and not col.startswith("rerun."):
                        d[col] = _first(batch.column(col).to_pylist()[-1])
                continue
            if "ViewBlueprint:display_name" in names:
                v["name"] = _first(batch.column("ViewBlueprint:display_name").to_pylist()[-1])
            if "ViewBlueprint:class_identifier" in names:
                v["kind"] = _first(
                    batch.column("ViewBlueprint:class_identifier").to_pylist()[-1])
            if "ViewBlueprint:space_origin" in names:
                v["origin"] = _first(batch.column("ViewBlueprint:space_origin").to_pylist()[-1])
            if "ViewContents:query" in names:
                v["contents"] = tuple(batch.column("ViewContents:query").to_pylist()[-1])
        out.append([SavedView(str(v.get("name", "")), str(v.get("kind", "")),
                              str(v.get("origin", "")), tuple(v.get("contents", ())),  # type: ignore[arg-type]
                              tuple(sorted(v.get("defaults", {}).items())))  # type: ignore[attr-defined]
                    for v in views.values() if "kind" in v or "name" in v])
    return out
