"""What goes into the results database, from the files a result leaves on disk; the hooks
that record each result as it is written; the import of runs already on disk.

Hooks (one call each where the result is written): ``record_verdict`` (``harness run`` and
``harness judge``, after verdict.json), ``record_suite`` (a suite's report, after
results.json; returns each criterion's recent trend for the report), ``record_identify``
(``harness identify`` of a run directory), ``record_calibration`` (``harness calibrate``).
A hook never fails its command: a database it cannot write is one line on stderr, and the
result's own files are written before it is called (nothing recorded on disk is lost).

Where: ``$SGSRT_HISTORY_DB`` (an SQLite path or a PostgreSQL URL), else ``history.sqlite``
in the logs folder: the parent of a run directory, of a suite's folder, of a calibration's
folder (a run directory inside a suite's folder: the suite folder's parent).
"""

from __future__ import annotations

import datetime as dt
import hashlib
import json
import re
import sys
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import yaml

from harness.history.db import HistoryDB, HistoryError, Record, open_db, recording_enabled

TREND_RUNS = 5
"""Runs a suite report's trend shows (this one and the ones before it)."""

_DIR_TIME = re.compile(r"^(\d{8}T\d{6})(?:\.\d+)?Z")


# ------------------------------------------------------------------------ identity
def sha256_bytes(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def canonical_sha256(obj: Any) -> str:
    """SHA-256 of ``obj`` as canonical JSON (sorted keys): equal data, equal hash, however
    the YAML was laid out."""
    return sha256_bytes(json.dumps(obj, sort_keys=True, default=str).encode())


def time_of(run_dir: Path) -> str:
    """A run's start (UTC, ISO 8601) from its directory name (``<UTC time>-<name>``), else
    the directory's modification time."""
    m = _DIR_TIME.match(run_dir.name)
    if m:
        t = dt.datetime.strptime(m.group(1), "%Y%m%dT%H%M%S")
    else:
        try:
            t = dt.datetime.fromtimestamp(run_dir.stat().st_mtime, dt.UTC).replace(tzinfo=None)
        except OSError:
            t = dt.datetime.now(dt.UTC).replace(tzinfo=None)
    return t.strftime("%Y-%m-%dT%H:%M:%SZ")


def _read_json(path: Path) -> Any:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def _config(run_dir: Path) -> dict[str, Any]:
    try:
        cfg = yaml.safe_load((run_dir / "config.yaml").read_text())
    except (OSError, yaml.YAMLError):
        return {}
    return cfg if isinstance(cfg, dict) else {}


RUN_KEYS_OUTSIDE_SERIES = ("rig", "bus", "description")
"""Run-file keys that do not make another series: which rig file the run named and its bus
(the rig is a series' own key, by name, real or virtual: a rig file edited, or a rig that
ages, stays one series; the default virtual bus is named after the rig) and the prose."""


def run_sha256(run: Mapping[str, Any] | None) -> str | None:
    """The run configuration's hash (config.yaml's ``run``, without
    ``RUN_KEYS_OUTSIDE_SERIES``): a plain run and a suite's item of the same name are one
    series only when their run data (criteria, overrides, duration...) is the same."""
    if not isinstance(run, Mapping):
        return None
    return canonical_sha256({k: v for k, v in run.items() if k not in RUN_KEYS_OUTSIDE_SERIES})


def run_identity(run_dir: Path) -> dict[str, Any]:
    """The identity fields of a run directory: rig, its hash and binding (the resolved rig
    the run used, overrides included: ``rig_models.rig_file.rig_identity``, as summary.json
    says it), the configuration's hash (run and rig, not where the run file lay: an
    unchanged configuration hashes the same), the run configuration's (the series), bus,
    real or virtual."""
    from harness.testing.judge import harness_version, run_rig_identity, source_commit

    cfg = _config(run_dir)
    summary = _read_json(run_dir / "summary.json")
    summary = summary if isinstance(summary, dict) else {}
    rig = cfg.get("rig") if isinstance(cfg.get("rig"), dict) else None
    run = cfg.get("run") if isinstance(cfg.get("run"), dict) else None
    ident = run_rig_identity(cfg, summary)
    bus = ident["bus"]
    mode = summary.get("virtual_rig_mode")
    return {
        "harness_version": harness_version(), "commit": source_commit(),
        "rig": ident["rig"], "rig_sha256": ident["rig_sha256"],
        "binding": ident["binding"] if isinstance(ident["binding"], dict) else None,
        "config_sha256": None if rig is None and run is None else canonical_sha256(
            {"run": run, "rig": rig}),
        "run_sha256": run_sha256(run),
        "bus": bus,
        # the virtual rig runs in the harness's process or its own; "external": the bus
        # is not the virtual one, so the rig answering is the real one (or one elsewhere)
        "real_rig": mode == "external" or (mode is None and bool(bus)
                                           and not str(bus).startswith("virtual")),
        "time_utc": time_of(run_dir),
    }


# ------------------------------------------------------------------------ records
def verdict_record(run_dir: Path, verdict: Mapping[str, Any] | None = None,
                   suite: str | None = None) -> Record | None:
    run_dir = Path(run_dir)
    path = run_dir / "verdict.json"
    if verdict is None:
        verdict = _read_json(path)
        if not isinstance(verdict, dict):
            return None
    raw = path.read_bytes() if path.is_file() else json.dumps(verdict, sort_keys=True).encode()
    ident = run_identity(run_dir)
    test = (verdict.get("identity") or {}).get("run") or run_dir.name
    return Record(key=f"run:{sha256_bytes(raw)}", kind="run", test=str(test),
                  verdict=verdict.get("verdict"), suite=suite, source=str(run_dir),
                  criteria=list(verdict.get("criteria") or []), **ident)


def identify_record(run_dir: Path, ident: Mapping[str, Any], test: str | None = None,
                    suite: str | None = None) -> Record:
    run_dir = Path(run_dir)
    idn = run_identity(run_dir)
    cfg = _config(run_dir)
    name = test or f"identify[{(cfg.get('run') or {}).get('name') or run_dir.name}]"
    raw = json.dumps(ident, sort_keys=True, default=float).encode()
    return Record(key=f"identify:{sha256_bytes(raw)}", kind="identify", test=name,
                  suite=suite, source=str(run_dir), modes=list(ident.get("modes") or []),
                  **idn)


def suite_records(out_dir: Path, doc: Mapping[str, Any]) -> list[Record]:
    """One record per test item of a suite's results (run, identify, probe, study)."""
    out_dir = Path(out_dir)
    suite = ", ".join(s.get("name", "") for s in doc.get("suites") or [])
    base = sha256_bytes(json.dumps({"dir": out_dir.name, "created": doc.get("created_utc"),
                                    "tests": [t.get("nodeid") for t in doc.get("tests") or []]},
                                   sort_keys=True).encode())
    created = str(doc.get("created_utc") or "")
    when = created[:19] + "Z" if created else time_of(out_dir)
    out = []
    for t in doc.get("tests") or []:
        if t.get("verdict") == "SKIPPED":
            continue
        run_dir = out_dir / t["run_dir"] if t.get("run_dir") else None
        if run_dir is not None and run_dir.is_dir():
            ident = run_identity(run_dir)
        else:  # a probe or a study: the rig its document names
            rig = t.get("rig") if isinstance(t.get("rig"), Mapping) else {}
            bus = rig.get("bus") or doc.get("bus")
            ident = {"time_utc": when, "bus": bus, "rig": rig.get("rig"),
                     "rig_sha256": rig.get("rig_sha256"),
                     "binding": rig.get("binding") if isinstance(rig.get("binding"), dict)
                     else None,
                     "real_rig": not str(bus or "virtual").startswith("virtual")}
        kind = t.get("kind") or "run"
        out.append(Record(key=f"suite:{base}:{t.get('nodeid') or t.get('item')}", kind=kind,
                          test=str(t.get("item")), verdict=t.get("verdict"), suite=suite,
                          source=str(run_dir or out_dir), criteria=list(t.get("criteria") or []),
                          modes=list(t.get("modes") or []), **ident))
    return out


def calibration_record(folder: Path, data: Mapping[str, Any]) -> Record:
    """A calibration: its identified modes with their 1 sigma, and the bands the
    recommended shaper was designed for (``harness history drift`` checks the modes against
    them)."""
    folder = Path(folder)
    modes = list(data.get("identified_modes") or [])
    bands = design_bands(folder / "recommended.yaml")
    rig = str(data["rig"]) if data.get("rig") else None
    raw = json.dumps(data, sort_keys=True, default=str).encode()
    return Record(key=f"calibrate:{sha256_bytes(raw)}", kind="calibrate",
                  test=f"calibrate[{rig or folder.name}]", time_utc=time_of(folder),
                  verdict=("PASS" if data.get("target_met") else "FAIL")
                  if "target_met" in data else None,
                  rig=rig, source=str(folder), modes=modes,
                  extra={"recommended": str(folder / "recommended.yaml")
                         if (folder / "recommended.yaml").is_file() else None,
                         "bands": bands})


def design_bands(run_file: Path) -> list[dict[str, float]]:
    """The mode bands a calibrated shaper was designed for (its run file's controller
    ``modes``, widened as ``harness calibrate`` scores them: harness.calibration)."""
    try:
        raw = yaml.safe_load(Path(run_file).read_text())
    except (OSError, yaml.YAMLError):
        return []
    modes = ((raw or {}).get("controller") or {}).get("modes") if isinstance(raw, dict) else None
    if not isinstance(modes, list) or not modes:
        return []
    from harness.calibration.candidates import Mode, bands_of

    try:
        bands = bands_of([Mode(float(m["omega_rad_s"]), float(m["damping_ratio"]),
                               float(m.get("sigma_omega_rad_s", 0.0)),
                               float(m.get("sigma_damping", 0.0))) for m in modes])
    except (KeyError, TypeError, ValueError):
        return []
    return [{"omega_rad_s": b.omega_rad_s, "omega_lo_rad_s": b.omega_lo_rad_s,
             "omega_hi_rad_s": b.omega_hi_rad_s} for b in bands]


# ------------------------------------------------------------------------ hooks
def logs_of(path: Path) -> Path:
    """The logs folder a result's folder sits in (a run inside a suite's folder: the
    suite folder's parent)."""
    parent = Path(path).resolve().parent
    if (parent / "results.json").is_file() or (parent / "report.md").is_file():
        return parent.parent
    return parent


def _add(records: list[Record], logs: Path) -> HistoryDB | None:
    if not recording_enabled() or not records:
        return None
    try:
        db = open_db(logs=logs)
        for r in records:
            db.add(r)
        return db
    except Exception as exc:  # noqa: BLE001 - never the command's failure
        print(f"harness: history: not recorded ({type(exc).__name__}: {exc})",
              file=sys.stderr)
        return None


def _record(make: Any, logs: Any) -> None:
    """Build the records and add them; any failure is one line on stderr, never the
    command's (its own files are already written)."""
    if not recording_enabled():
        return
    try:
        records = make()
        where = logs()
    except Exception as exc:  # noqa: BLE001
        print(f"harness: history: not recorded ({type(exc).__name__}: {exc})", file=sys.stderr)
        return
    db = _add(records, where)
    if db is not None:
        db.close()


def record_verdict(run_dir: Path, verdict: Mapping[str, Any]) -> None:
    def make() -> list[Record]:
        rec = verdict_record(Path(run_dir), verdict)
        return [rec] if rec else []
    _record(make, lambda: logs_of(Path(run_dir)))


def record_identify(run_dir: Path, ident: Mapping[str, Any]) -> None:
    _record(lambda: [identify_record(Path(run_dir), ident)], lambda: logs_of(Path(run_dir)))


def record_calibration(folder: Path, data: Mapping[str, Any]) -> None:
    _record(lambda: [calibration_record(Path(folder), data)],
            lambda: Path(folder).resolve().parent)


def record_suite(out_dir: Path, doc: dict[str, Any]) -> None:
    """Record a suite's tests, then add each criterion's recent values (``trend``: this
    run's and up to TREND_RUNS - 1 before it, same series: test, rig and run configuration)
    to ``doc`` for its report."""
    out_dir = Path(out_dir)
    try:
        records = suite_records(out_dir, doc)
    except Exception as exc:  # noqa: BLE001
        print(f"harness: history: not recorded ({type(exc).__name__}: {exc})", file=sys.stderr)
        return
    db = _add(records, out_dir.resolve().parent)
    if db is None:
        return
    from harness.history.db import Filters

    try:
        for t, rec in zip((t for t in doc.get("tests") or [] if t.get("verdict") != "SKIPPED"),
                          records, strict=True):
            for c in t.get("criteria") or []:
                rows = db.criterion_series(rec.test, str(c.get("name", "")), Filters(
                    rig=rec.rig or "", real=rec.real_rig, run_sha256=rec.run_sha256 or "",
                    until=_after(rec.time_utc)))
                vals = [r["value"] for r in rows if r["value"] is not None][-TREND_RUNS:]
                if len(vals) >= 2:
                    c["trend"] = vals
    except Exception as exc:  # noqa: BLE001 - the report is written without trends
        print(f"harness: history: no trends ({type(exc).__name__}: {exc})", file=sys.stderr)
    finally:
        db.close()


def _after(time_utc: str) -> str:
    """An upper bound just after ``time_utc`` (the runs up to and including it)."""
    return time_utc[:19] + "~"


def trend_text(values: list[float]) -> str:
    """``0.0119 → 0.0121 → 0.0123 (rising)``: the report's trend beside a value."""
    if len(values) < 2:
        return ""
    first, last = values[0], values[-1]
    scale = max(abs(first), abs(last), 1e-300)
    word = "steady" if abs(last - first) <= 1e-3 * scale else (
        "rising" if last > first else "falling")
    return " → ".join(f"{v:.4g}" for v in values) + f" ({word})"


# ------------------------------------------------------------------------ import
def _walk(logs: Path) -> Iterator[tuple[str, Path]]:
    """(kind, folder) of every result under ``logs``: suites (results.json with tests),
    calibrations (results.json with verified candidates), and run directories outside a
    suite's folder (verdict.json; identify.json beside it)."""
    for results in sorted(logs.rglob("results.json")):
        doc = _read_json(results)
        if isinstance(doc, dict) and "tests" in doc:
            yield "suite", results.parent
        elif isinstance(doc, dict) and "identified_modes" in doc:
            yield "calibrate", results.parent
    for verdict in sorted(logs.rglob("verdict.json")):
        run_dir = verdict.parent
        if (run_dir.parent / "results.json").is_file():
            continue  # a suite's run: recorded with its suite
        yield "run", run_dir
        if (run_dir / "identify.json").is_file():
            yield "identify", run_dir


def _records_of(kind: str, folder: Path) -> list[Record]:
    if kind == "suite":
        doc = _read_json(folder / "results.json")
        if not isinstance(doc, dict) or not isinstance(doc.get("tests"), list):
            raise ValueError("results.json: tests: expected a list")
        return suite_records(folder, doc)
    if kind == "calibrate":
        return [calibration_record(folder, _read_json(folder / "results.json"))]
    if kind == "identify":
        ident = _read_json(folder / "identify.json")
        if not isinstance(ident, dict):
            raise ValueError("identify.json: expected an object")
        return [identify_record(folder, ident)]
    if not isinstance(_read_json(folder / "verdict.json"), dict):
        raise ValueError("verdict.json: expected an object")
    rec = verdict_record(folder)
    return [rec] if rec else []


def _database_failure(exc: BaseException) -> bool:
    """The database itself failed (locked past its timeout, a full disk, a lost server):
    the import stops; anything else a record raises is its folder's fault."""
    import sqlite3

    if isinstance(exc, sqlite3.OperationalError):
        return True
    return type(exc).__module__.startswith("psycopg") and type(exc).__name__ in (
        "OperationalError", "InterfaceError")


def import_logs(db: HistoryDB, logs: Path,
                skipped: list[tuple[Path, str]] | None = None) -> dict[str, int]:
    """Record every result under ``logs`` not yet in ``db``: counts added and already
    there, by kind. A folder whose files cannot be read as a result (hand-edited, cut) is
    skipped, named in ``skipped`` with the reason, and the rest is recorded."""
    counts: dict[str, int] = {}
    for kind, folder in _walk(Path(logs)):
        try:
            recs = _records_of(kind, folder)
            added = [db.add(r) is not None for r in recs]
        except Exception as exc:  # noqa: BLE001 - a bad folder is skipped, named
            if _database_failure(exc):
                raise
            if skipped is not None:
                skipped.append((folder, f"{kind}: {type(exc).__name__}: {exc}"[:300]))
            counts[f"{kind} skipped"] = counts.get(f"{kind} skipped", 0) + 1
            continue
        for was_added in added:
            k = f"{kind} {'added' if was_added else 'already recorded'}"
            counts[k] = counts.get(k, 0) + 1
    return counts


__all__ = ["HistoryError", "import_logs", "record_calibration", "record_identify",
           "record_suite", "record_verdict", "trend_text"]
