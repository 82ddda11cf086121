"""The results database: every judged run, suite result, identification and calibration,
with its identity, every criterion's value / limit / margin / verdict and every identified
mode with its 1 sigma.

Embedded by default: an SQLite file, ``history.sqlite`` beside the logs (WAL mode so
readers never block the writer, a busy timeout so parallel writers wait their turn instead
of failing, one short ``BEGIN IMMEDIATE`` transaction per record). A lab's shared server by
one URL (``postgresql://user@host/db``, the ``lab-db`` extra's psycopg): ``--db URL`` or
``$SGSRT_HISTORY_DB``. Both hold the same tables; ``schema_version`` says which layout a
file has, and a newer one than this code knows is refused rather than misread.

A record's ``key`` is its kind and the SHA-256 of the file it came from (verdict.json,
results.json plus the test's name, identify.json, a calibration's results.json): recording
the same result twice (the hook, then an import of the same folder) adds it once.
"""

from __future__ import annotations

import json
import math
import os
import sqlite3
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

SCHEMA_VERSION = 2
"""1: the first layout; 2: ``records.run_sha256`` (the run configuration's hash: a series is
one test on one rig and one run configuration). An older file is migrated when opened
(columns added with their defaults), never refused."""
DB_FILENAME = "history.sqlite"
ENV_URL = "SGSRT_HISTORY_DB"
"""A database URL (postgresql://...) or an SQLite file's path, for every command."""
ENV_OFF = "SGSRT_HISTORY"
"""``off``: record nothing (the hooks do nothing; ``harness history`` still reads)."""
BUSY_TIMEOUT_S = 60.0

_TABLES = [
    """CREATE TABLE IF NOT EXISTS schema_version (version INTEGER NOT NULL)""",
    """CREATE TABLE IF NOT EXISTS records (
        id {pk},
        key TEXT NOT NULL UNIQUE,
        kind TEXT NOT NULL,
        time_utc TEXT NOT NULL,
        recorded_utc TEXT NOT NULL,
        suite TEXT,
        test TEXT NOT NULL,
        verdict TEXT,
        harness_version TEXT,
        commit_sha TEXT,
        rig TEXT,
        rig_sha256 TEXT,
        config_sha256 TEXT,
        run_sha256 TEXT,
        bus TEXT,
        real_rig INTEGER NOT NULL,
        source TEXT,
        extra TEXT)""",
    """CREATE TABLE IF NOT EXISTS criteria (
        record_id BIGINT NOT NULL REFERENCES records(id) ON DELETE CASCADE,
        name TEXT NOT NULL,
        kind TEXT,
        value DOUBLE PRECISION,
        value_text TEXT,
        unit TEXT,
        limits TEXT,
        margin DOUBLE PRECISION,
        verdict TEXT)""",
    """CREATE TABLE IF NOT EXISTS modes (
        record_id BIGINT NOT NULL REFERENCES records(id) ON DELETE CASCADE,
        mode INTEGER NOT NULL,
        omega_rad_s DOUBLE PRECISION NOT NULL,
        sigma_omega_rad_s DOUBLE PRECISION,
        damping_ratio DOUBLE PRECISION,
        sigma_damping DOUBLE PRECISION,
        model_omega_rad_s DOUBLE PRECISION)""",
    """CREATE INDEX IF NOT EXISTS records_test ON records(test, time_utc)""",
    """CREATE INDEX IF NOT EXISTS records_series ON records(test, rig, run_sha256)""",
    """CREATE INDEX IF NOT EXISTS criteria_record ON criteria(record_id)""",
    """CREATE INDEX IF NOT EXISTS modes_record ON modes(record_id)""",
]


class HistoryError(Exception):
    """The database cannot be opened or read (a bad URL, a newer schema, no driver)."""


@dataclass
class Record:
    """One result. ``criteria``: dicts as in verdict.json (name, kind, value, unit, limit,
    margin, verdict); ``modes``: dicts with omega_rad_s, sigma_omega_rad_s, damping_ratio,
    sigma_damping, model_omega_rad_s (the identify JSON's keys)."""

    key: str
    kind: str  # "run" | "suite" | "identify" | "calibrate" (a suite's items: their own kind)
    test: str
    time_utc: str
    verdict: str | None = None
    suite: str | None = None
    harness_version: str | None = None
    commit: str | None = None
    rig: str | None = None
    rig_sha256: str | None = None
    config_sha256: str | None = None
    run_sha256: str | None = None  # the run file's data without its rig reference
    bus: str | None = None
    real_rig: bool = False
    binding: dict[str, Any] | None = None  # each device's binding (kept in ``extra``)
    source: str | None = None
    criteria: list[dict[str, Any]] = field(default_factory=list)
    modes: list[dict[str, Any]] = field(default_factory=list)
    extra: dict[str, Any] = field(default_factory=dict)


def _num(v: Any) -> float | None:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return None
    f = float(v)
    return f if math.isfinite(f) else None


def utc_now() -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())


class HistoryDB:
    """One connection's worth of the database; ``add`` records, the ``query`` methods read."""

    def __init__(self, location: str) -> None:
        self.location = location
        self.is_pg = location.startswith(("postgresql://", "postgres://"))
        if self.is_pg:
            try:
                import psycopg
            except ImportError as exc:
                raise HistoryError(
                    f"{_redact(location)}: PostgreSQL needs psycopg: pip install "
                    "'sgsrt-harness[lab-db]'") from exc
            try:
                self.conn: Any = psycopg.connect(location, connect_timeout=10)
            except psycopg.Error as exc:
                raise HistoryError(f"{_redact(location)}: cannot connect: {exc}") from exc
        else:
            path = Path(location.removeprefix("sqlite:///").removeprefix("sqlite://"))
            try:
                path.parent.mkdir(parents=True, exist_ok=True)
                # autocommit (isolation_level None): transactions are explicit, short
                self.conn = sqlite3.connect(str(path), timeout=BUSY_TIMEOUT_S,
                                            isolation_level=None)
                self.conn.execute(f"PRAGMA busy_timeout = {int(BUSY_TIMEOUT_S * 1000)}")
                self.conn.execute("PRAGMA journal_mode = WAL")
                self.conn.execute("PRAGMA foreign_keys = ON")
            except (sqlite3.Error, OSError) as exc:
                raise HistoryError(f"{path}: cannot open the history database: {exc}") from exc
        self._ensure_schema()

    # ------------------------------------------------------------------ plumbing
    def _sql(self, sql: str) -> str:
        return sql.replace("?", "%s") if self.is_pg else sql

    @contextmanager
    def _write(self) -> Iterator[Any]:
        """One short write transaction (SQLite: BEGIN IMMEDIATE takes the write lock at
        once, so two writers never both read then deadlock on the upgrade)."""
        if self.is_pg:
            with self.conn.transaction():
                yield self.conn.cursor()
            return
        cur = self.conn.cursor()
        cur.execute("BEGIN IMMEDIATE")
        try:
            yield cur
        except BaseException:
            cur.execute("ROLLBACK")
            raise
        cur.execute("COMMIT")

    def _ensure_schema(self) -> None:
        pk = "BIGSERIAL PRIMARY KEY" if self.is_pg else "INTEGER PRIMARY KEY AUTOINCREMENT"
        try:
            with self._write() as cur:
                if self.is_pg:  # two first writers must not both create the tables
                    cur.execute("SELECT pg_advisory_xact_lock(2026112201)")
                for stmt in _TABLES[:4]:  # the tables; indexes once they are migrated
                    cur.execute(stmt.format(pk=pk))
                cur.execute("SELECT version FROM schema_version")
                rows = cur.fetchall()
                version = max((r[0] for r in rows), default=None)
                if version is not None and version > SCHEMA_VERSION:
                    raise HistoryError(
                        f"{_redact(self.location)}: schema version {version} is newer than "
                        f"this harness's {SCHEMA_VERSION}: update the harness")
                if version is not None and version < SCHEMA_VERSION:
                    self._migrate(cur, version)
                for stmt in _TABLES[4:]:
                    cur.execute(stmt.format(pk=pk))
                if version is None:
                    cur.execute(self._sql("INSERT INTO schema_version (version) VALUES (?)"),
                                (SCHEMA_VERSION,))
                elif version < SCHEMA_VERSION:
                    cur.execute(self._sql("UPDATE schema_version SET version = ?"),
                                (SCHEMA_VERSION,))
        except HistoryError:
            raise
        except Exception as exc:  # noqa: BLE001 - sqlite3.Error / psycopg.Error
            raise HistoryError(f"{_redact(self.location)}: {type(exc).__name__}: {exc}") \
                from exc

    def _columns(self, cur: Any, table: str) -> set[str]:
        if self.is_pg:
            cur.execute("SELECT column_name FROM information_schema.columns WHERE "
                        "table_name = %s AND table_schema = current_schema()", (table,))
            return {r[0] for r in cur.fetchall()}
        cur.execute(f"PRAGMA table_info({table})")
        return {r[1] for r in cur.fetchall()}

    def _migrate(self, cur: Any, version: int) -> None:
        """Bring an older layout up to this one in the open transaction: columns added
        with their defaults (records from before keep NULL: a series of their own)."""
        if version < 2 and "run_sha256" not in self._columns(cur, "records"):
            cur.execute("ALTER TABLE records ADD COLUMN run_sha256 TEXT")

    def close(self) -> None:
        self.conn.close()

    def __enter__(self) -> HistoryDB:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ writing
    def add(self, rec: Record) -> int | None:
        """Record ``rec`` in one transaction; its id, or None if its key is already there."""
        with self._write() as cur:
            cur.execute(self._sql(
                "INSERT INTO records (key, kind, time_utc, recorded_utc, suite, test, verdict, "
                "harness_version, commit_sha, rig, rig_sha256, config_sha256, run_sha256, bus, "
                "real_rig, source, extra) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, "
                "?, ?) ON CONFLICT (key) DO NOTHING RETURNING id"),
                (rec.key, rec.kind, rec.time_utc, utc_now(), rec.suite, rec.test, rec.verdict,
                 rec.harness_version, rec.commit, rec.rig, rec.rig_sha256, rec.config_sha256,
                 rec.run_sha256, rec.bus, int(bool(rec.real_rig)), rec.source,
                 json.dumps({**rec.extra, **({"binding": rec.binding} if rec.binding else {})},
                            default=str)))
            row = cur.fetchone()
            if row is None:
                return None
            rid = int(row[0])
            crit = [(rid, str(c.get("name", "")), c.get("kind"), _num(c.get("value")),
                     None if _num(c.get("value")) is not None or c.get("value") is None
                     else json.dumps(c.get("value"), default=str),
                     c.get("unit"), json.dumps(c.get("limit") or {}, default=str),
                     _num(c.get("margin")), c.get("verdict")) for c in rec.criteria]
            if crit:
                cur.executemany(self._sql(
                    "INSERT INTO criteria (record_id, name, kind, value, value_text, unit, "
                    "limits, margin, verdict) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)"), crit)
            modes = [(rid, i + 1, float(m["omega_rad_s"]), _num(m.get("sigma_omega_rad_s")),
                      _num(m.get("damping_ratio")), _num(m.get("sigma_damping")),
                      _num(m.get("model_omega_rad_s")))
                     for i, m in enumerate(rec.modes) if _num(m.get("omega_rad_s")) is not None]
            if modes:
                cur.executemany(self._sql(
                    "INSERT INTO modes (record_id, mode, omega_rad_s, sigma_omega_rad_s, "
                    "damping_ratio, sigma_damping, model_omega_rad_s) "
                    "VALUES (?, ?, ?, ?, ?, ?, ?)"), modes)
        return rid

    # ------------------------------------------------------------------ reading
    def _query(self, sql: str, params: Sequence[Any] = ()) -> list[dict[str, Any]]:
        cur = self.conn.cursor()
        cur.execute(self._sql(sql), tuple(params))
        names = [d[0] for d in cur.description]
        rows = [dict(zip(names, r, strict=True)) for r in cur.fetchall()]
        if self.is_pg:
            self.conn.commit()  # end the read transaction psycopg opened
        return rows

    def count(self, table: str = "records") -> int:
        if table not in ("records", "criteria", "modes"):
            raise ValueError(f"table: expected records, criteria or modes, got {table!r}")
        return int(self._query(f"SELECT COUNT(*) AS n FROM {table}")[0]["n"])

    def records(self, filters: Filters | None = None) -> list[dict[str, Any]]:
        where, params = (filters or Filters()).sql()
        rows = self._query("SELECT * FROM records r" + where + " ORDER BY r.time_utc, r.id",
                           params)
        for r in rows:
            r["real_rig"] = bool(r["real_rig"])
            r["extra"] = json.loads(r["extra"]) if r.get("extra") else {}
        return rows

    def criterion_series(self, test: str, name: str, filters: Filters | None = None
                         ) -> list[dict[str, Any]]:
        """One criterion of one test across runs, oldest first."""
        f = filters or Filters()
        where, params = Filters(**{**f.__dict__, "test": test}).sql()
        return self._query(
            "SELECT r.id, r.time_utc, r.test, r.verdict AS run_verdict, r.rig, r.real_rig, "
            "r.config_sha256, r.run_sha256, r.rig_sha256, r.bus, r.commit_sha, r.source, "
            "c.name, c.value, c.value_text, c.unit, "
            "c.limits, c.margin, c.verdict FROM records r JOIN criteria c ON c.record_id = r.id"
            + where + " AND c.name = ? ORDER BY r.time_utc, r.id", [*params, name])

    def mode_series(self, test: str, mode: int, filters: Filters | None = None
                    ) -> list[dict[str, Any]]:
        """Identified mode ``mode`` (1 = lowest) of one test across runs, oldest first."""
        f = filters or Filters()
        where, params = Filters(**{**f.__dict__, "test": test}).sql()
        return self._query(
            "SELECT r.id, r.time_utc, r.test, r.rig, r.real_rig, r.config_sha256, "
            "r.run_sha256, r.rig_sha256, r.bus, r.source, m.mode, m.omega_rad_s, "
            "m.sigma_omega_rad_s, m.damping_ratio, m.sigma_damping, "
            "m.model_omega_rad_s FROM records r JOIN modes m ON m.record_id = r.id"
            + where + " AND m.mode = ? ORDER BY r.time_utc, r.id", [*params, mode])

    def catalogue(self, filters: Filters | None = None) -> list[dict[str, Any]]:
        """Every series with its run count: a (test, criterion) or (test, mode) on one rig
        (its name, real or virtual) and one run configuration (``run_sha256``; "" for
        records from before it was kept)."""
        where, params = (filters or Filters()).sql()
        key = ("r.test, COALESCE(r.rig, '') AS rig, r.real_rig, "
               "COALESCE(r.run_sha256, '') AS run_sha256")
        group = "r.test, COALESCE(r.rig, ''), r.real_rig, COALESCE(r.run_sha256, '')"
        crit = self._query(
            f"SELECT {key}, c.name AS criterion, c.unit, COUNT(*) AS runs, "
            "MAX(r.time_utc) AS last_utc FROM records r JOIN criteria c ON c.record_id = r.id"
            + where + f" GROUP BY {group}, c.name, c.unit ORDER BY r.test, c.name, "
            "MAX(r.time_utc)", params)
        modes = self._query(
            f"SELECT {key}, m.mode, COUNT(*) AS runs, MAX(r.time_utc) AS last_utc "
            "FROM records r JOIN modes m ON m.record_id = r.id" + where
            + f" GROUP BY {group}, m.mode ORDER BY r.test, m.mode, MAX(r.time_utc)", params)
        out = ([{"series": "criterion", **c} for c in crit]
               + [{"series": "mode", **m} for m in modes])
        for r in out:
            r["real_rig"] = bool(r["real_rig"])
        return out


@dataclass
class Filters:
    """Which records a query sees: a test, a rig (name; "" the records without one), real
    or virtual, a run configuration (``run_sha256``; "" the records without one), a time
    range (``since`` inclusive, ``until`` exclusive: UTC times as the database keeps them,
    ``YYYY-MM-DDTHH:MM:SSZ``; ``harness history`` parses what it is given into this form)."""

    test: str | None = None
    rig: str | None = None
    real: bool | None = None
    since: str | None = None
    until: str | None = None
    kind: str | None = None
    run_sha256: str | None = None

    def sql(self) -> tuple[str, list[Any]]:
        conds, params = ["1 = 1"], []
        for col, val in (("r.test", self.test), ("COALESCE(r.rig, '')", self.rig),
                         ("r.kind", self.kind),
                         ("COALESCE(r.run_sha256, '')", self.run_sha256)):
            if val is not None:
                conds.append(f"{col} = ?")
                params.append(val)
        if self.real is not None:
            conds.append("r.real_rig = ?")
            params.append(int(self.real))
        if self.since:
            conds.append("r.time_utc >= ?")
            params.append(self.since)
        if self.until:
            conds.append("r.time_utc < ?")
            params.append(self.until)
        return " WHERE " + " AND ".join(conds), params


def _redact(url: str) -> str:
    """A URL without its password (error messages must not print it)."""
    if "://" not in url or "@" not in url:
        return url
    scheme, rest = url.split("://", 1)
    creds, host = rest.rsplit("@", 1)
    user = creds.split(":", 1)[0]
    return f"{scheme}://{user}:***@{host}" if ":" in creds else url


def default_location(logs: Path | str = "logs") -> str:
    """``$SGSRT_HISTORY_DB``, else ``history.sqlite`` in the logs folder."""
    return os.environ.get(ENV_URL) or str(Path(logs) / DB_FILENAME)


def open_db(location: str | Path | None = None, logs: Path | str = "logs") -> HistoryDB:
    return HistoryDB(str(location) if location else default_location(logs))


def recording_enabled() -> bool:
    return os.environ.get(ENV_OFF, "").strip().lower() not in ("off", "0", "no", "false")
