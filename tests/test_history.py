"""The rig's health over time: the results database, `harness history` (series,
drift alarms with uncertainty, flaky verdicts), the predicted scatter and `harness twin`.

The drift test makes ten short free-decay runs (20 s at 50 Hz, one wheel pulse) on rig
files whose beam.youngs_modulus_pa steps up each "day", identifies mode 1 of each with the
identification API (value and 1 sigma), and checks the alarm against the statistics
computed here: ten short identification runs stand for ten acceptance runs (an acceptance
run costs minutes; the alarm reads the same identified mode either way).
"""

from __future__ import annotations

import json
import math
import multiprocessing as mp
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from in_process import harness_in_process

from harness.cli import main
from harness.core.runs import load_run
from harness.core.session import execute_run
from harness.history import drift
from harness.history.db import SCHEMA_VERSION, Filters, HistoryDB, Record, open_db
from harness.history.record import record_identify
from harness.history.series import analyse, criterion_series, flaky
from harness.testing.work import private_channel
from rig_models.rig_file import RIGS_DIR, load_rig

ENV = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
NOMINAL = yaml.safe_load((RIGS_DIR / "sgsrt.yaml").read_text())


def rig_file(tmp: Path, name: str, **changes: object) -> Path:
    """A copy of rig_models/rigs/sgsrt.yaml with dotted keys changed."""
    data = json.loads(json.dumps(NOMINAL))
    for dotted, v in changes.items():
        *parents, leaf = dotted.split("__")
        d = data
        for p in parents:
            d = d[p]
        d[leaf] = v
    path = tmp / f"{name}.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def decay_run_file(tmp: Path, rig: Path, name: str = "decay-drift",
                   expect: dict | None = None, duration_s: float = 20.0,
                   rate_hz: float = 50.0, torque_n_m: float = 0.06) -> Path:
    raw = {"name": name, "description": "wheel pulse, then free decay", "rig": str(rig),
           "bus": "virtual:sgsrt", "clock": "lockstep", "rate_hz": rate_hz,
           "duration_s": duration_s, "actuators": ["reaction_wheel"],
           "controller": {"type": "wheel_pulse", "torque_n_m": torque_n_m, "start_s": 0.2,
                          "width_s": 1.0}}
    if expect:
        raw["expect"] = expect
    path = tmp / f"{name}-{rig.stem}.yaml"
    path.write_text(yaml.safe_dump(raw, sort_keys=False))
    return path


def run(path: Path, logs: Path) -> Path:
    return execute_run(load_run(str(path)), out_dir=logs, bus=private_channel(),
                       show_progress=False).run_dir


def first_json(text: str) -> dict:
    """The JSON document a command printed (its stderr's progress lines follow it)."""
    return json.JSONDecoder().raw_decode(text[text.index("{"):])[0]


def cli(*args: str, process: bool = False) -> tuple[int, str]:
    """`harness ARGS`: exit code, stdout then stderr; in this process (tests/in_process.py)
    unless ``process`` (a new interpreter: the entry point)."""
    if process:
        proc = subprocess.run([sys.executable, "-m", "harness", *args], capture_output=True,
                              text=True, env=ENV, timeout=300, check=False)
    else:
        proc = harness_in_process(*args)
    return proc.returncode, proc.stdout + proc.stderr


# ----------------------------------------------------------------------------- drift
def test_mode_drift_alarm_fires_on_the_first_run_beyond_the_combined_uncertainty(tmp_path):
    from harness.core.identify import identify_run

    logs = tmp_path / "logs"
    e0 = NOMINAL["beam"]["youngs_modulus_pa"]
    step = 0.01  # +1 % stiffness a day: about +0.5 % in mode 1
    for day in range(10):
        rig = rig_file(tmp_path, f"rig-day{day}", beam__youngs_modulus_pa=e0 * (1 + step * day),
                       noise_seed=100 + day)
        run_dir = run(decay_run_file(tmp_path, rig), logs)
        ident = identify_run(run_dir, n_modes=1)
        record_identify(run_dir, ident)
    with open_db(logs=logs) as db:
        rows = db.mode_series("identify[decay-drift]", 1)
    assert len(rows) == 10
    w = [r["omega_rad_s"] for r in rows]
    s = [r["sigma_omega_rad_s"] for r in rows]
    assert all(x > 0 for x in s)
    assert w[-1] > w[0]  # the beam got stiffer
    # the claim, computed here: the first run whose change from the first exceeds 3 x the
    # combined 1 sigma
    beyond = [i for i in range(1, 10) if abs(w[i] - w[0]) > 3 * math.hypot(s[i], s[0])]
    assert beyond, "the drift never exceeded the combined uncertainty: make the step larger"
    expected = beyond[0]
    assert expected >= 2, f"alarm at run {expected}: the step is too large to test 'not before'"

    page, png = tmp_path / "mode1.html", tmp_path / "mode1.png"
    code, out = cli("history", "show", "identify[decay-drift]", "--mode", "1", "--logs",
                    str(logs), "--json", "--png", str(png), "--page", str(page))
    assert code == 1, out  # an alarm fired
    series = first_json(out)["series"]
    assert len(series) == 1 and series[0]["rig"] == "sgsrt"  # ten rig files, one rig
    doc = series[0]
    changes = [a for a in doc["alarms"] if a["kind"] == "change"]
    assert changes and min(a["index"] for a in changes) == expected
    first = min(changes, key=lambda a: a["index"])
    assert first["time_utc"] == rows[expected]["time_utc"]
    assert "identify[decay-drift] mode 1 on sgsrt" in first["message"]
    assert all(r["sigma"] is not None for r in doc["runs"])  # the plot's error bars
    assert png.stat().st_size > 10_000
    assert "data:image/png;base64," in page.read_text()
    assert "ALARM (change, run" in cli("history", "drift", "--logs", str(logs))[1]


def test_change_alarm_is_the_combined_uncertainty_rule():
    pts = [drift.Point("d0", 10.0, 0.1), drift.Point("d1", 10.3, 0.1),
           drift.Point("d2", 10.5, 0.1), drift.Point("d3", 9.0, 1.0)]
    alarms = drift.change_alarms(pts, "m", "rad/s", k=3.0)
    # 0.3 < 3 x 0.141; 0.5 > 0.424; -1.0 < 3 x 1.005
    assert [a.index for a in alarms] == [2]
    assert math.isclose(alarms[0].sigma, math.hypot(0.1, 0.1))


def test_trend_and_control_rules():
    steady = [drift.Point(f"d{i}", 1.0 + 0.01 * (-1) ** i, None) for i in range(8)]
    assert drift.trend_alarm(steady, "x", "", n_trend=5) is None
    assert drift.control_alarms(steady, "x", "", n_ref=5) == []
    rising = [drift.Point(f"d{i}", 1.0 + 0.1 * i + 0.001 * (-1) ** i, None) for i in range(6)]
    t = drift.trend_alarm(rising, "x", "", n_trend=5)
    assert t is not None and t.change > 0 and t.index == 5
    jump = [*steady[:5], drift.Point("d5", 1.2)]
    assert [a.index for a in drift.control_alarms(jump, "x", "", n_ref=5)] == [5]


# ----------------------------------------------------------------------------- database
def _rec(i: int, writer: int = 0, verdict: str = "PASS", cfg: str = "c1",
         value: float = 1.0) -> Record:
    return Record(key=f"t:{writer}:{i}", kind="run", test="t",
                  time_utc=f"2026-11-{1 + i:02d}T00:00:00Z", verdict=verdict, rig="sgsrt",
                  config_sha256=cfg,
                  criteria=[{"name": "c", "kind": "scalar", "value": value, "unit": "m",
                             "limit": {"max_m": 2.0, "marginal_m": 0.1}, "margin": 2.0 - value,
                             "verdict": verdict}],
                  modes=[{"omega_rad_s": 2.9, "sigma_omega_rad_s": 0.01}])


def _writer(location: str, writer: int, n: int) -> None:
    db = HistoryDB(location)
    for i in range(n):
        db.add(_rec(i, writer))
    db.close()


def many_writers(location: str, writers: int = 6, each: int = 25) -> None:
    ctx = mp.get_context("spawn")
    procs = [ctx.Process(target=_writer, args=(location, w, each)) for w in range(writers)]
    for p in procs:
        p.start()
    for p in procs:
        p.join(120)
        assert p.exitcode == 0


@pytest.mark.slow
def test_parallel_writers_lose_nothing(tmp_path):
    location = str(tmp_path / "history.sqlite")
    many_writers(location, writers=4, each=30)
    with HistoryDB(location) as db:
        assert db.count("records") == 120
        assert db.count("criteria") == 120
        assert db.count("modes") == 120
        assert db.add(_rec(0, 0)) is None  # the same result twice is recorded once
        assert db._query("SELECT version FROM schema_version")[0]["version"] == SCHEMA_VERSION
        assert db._query("PRAGMA journal_mode")[0]["journal_mode"] == "wal"


def test_a_newer_schema_is_refused(tmp_path):
    from harness.history.db import HistoryError

    location = str(tmp_path / "h.sqlite")
    with HistoryDB(location) as db:
        db.conn.execute("UPDATE schema_version SET version = 99")
    with pytest.raises(HistoryError, match="schema version 99"):
        HistoryDB(location)


def test_flaky_is_a_verdict_flip_on_one_configuration(tmp_path):
    with HistoryDB(str(tmp_path / "h.sqlite")) as db:
        for i, (v, cfg) in enumerate([("PASS", "a"), ("FAIL", "a"), ("PASS", "a"),
                                      ("PASS", "b"), ("FAIL", "c")]):
            db.add(_rec(i, verdict=v, cfg=cfg, value=1.0 + 0.01 * i))
        s = criterion_series(db, "t", "c")
        found = flaky(s)
        assert [f["config_sha256"] for f in found] == ["a"]
        assert found[0]["flips"] == 2
        assert s.rows[0]["limits"] == {"max": 2.0, "marginal": 0.1}
        assert len(criterion_series(db, "t", "c", Filters(since="2026-11-03")).rows) == 3
        assert analyse(s).flaky


def test_history_bad_input_is_a_clear_error(tmp_path):
    assert main(["history", "show", "x", "--mode", "1", "--logs", str(tmp_path)]) == 2
    (tmp_path / "history.sqlite").write_text("not a database")
    code, out = cli("history", "list", "--logs", str(tmp_path), process=True)
    assert code == 2 and "Traceback" not in out and "history.sqlite" in out
    code, out = cli("history", "list", "--logs", str(tmp_path), "--since", "yesterday")
    assert code == 2 and "--since" in out


# ----------------------------------------------------------------------------- per rig
TWO_RIGS = {"sgsrt": [1.00, 1.01, 0.99, 1.00, 1.01, 0.50],
            "lab-aging": [0.60, 0.61, 0.59, 0.60, 0.61, 0.10]}
"""A criterion's margin on two rigs recording one test name into one database, their runs
interleaved in time: each rig's last run drops its margin by 0.5."""


def _add_two_rigs(db: HistoryDB) -> None:
    for i in range(6):
        for j, (rig, margins) in enumerate(TWO_RIGS.items()):
            db.add(Record(key=f"{rig}-{i}", kind="run", test="free-decay",
                          time_utc=f"2026-11-{1 + i:02d}T0{j}:00:00Z", verdict="PASS",
                          rig=rig, run_sha256="r1", criteria=[{
                              "name": "residual", "value": 2 - margins[i], "unit": "m_s2",
                              "limit": {"max_m_s2": 2.0}, "margin": margins[i],
                              "verdict": "PASS"}]))


def check_two_rigs_keep_two_series(location: str, where: list[str]) -> None:
    with HistoryDB(location) as db:
        _add_two_rigs(db)
        assert sorted((c["rig"], c["runs"]) for c in db.catalogue()) == [
            ("lab-aging", 6), ("sgsrt", 6)]
    code, out = cli("history", "drift", "--json", *where)
    assert code == 1, out
    found = json.JSONDecoder().raw_decode(out[out.index("["):])[0]
    by_rig = {s["rig"]: s for s in found}
    assert sorted(by_rig) == ["lab-aging", "sgsrt"] and len(found) == 2
    for rig, s in by_rig.items():
        other = next(r for r in TWO_RIGS if r != rig)
        # measured from its own first runs: only its own last run is beyond the limits
        assert [a["index"] for a in s["alarms"] if a["kind"] == "control"] == [5]
        for a in s["alarms"]:
            assert f"on {rig}" in a["message"] and other not in a["message"], a["message"]
            assert a["unit"] == "m/s^2"
    code, out = cli("history", "show", "free-decay", "--criterion", "residual", *where)
    assert code == 1
    assert "free-decay residual on sgsrt" in out and "free-decay residual on lab-aging" in out
    assert "m/s^2" in out and "m_s2" not in out
    code, out = cli("history", "list", *where)
    assert code == 0 and out.index("lab-aging:") < out.index("sgsrt:")


def test_two_rigs_writing_one_test_keep_two_series_each_alarm_naming_its_rig(tmp_path):
    location = str(tmp_path / "history.sqlite")
    check_two_rigs_keep_two_series(location, ["--db", location])


def test_a_plain_run_and_a_suite_item_are_two_series_unless_the_run_file_is_the_same():
    from harness.history.record import run_sha256
    from harness.testing.suite import load_suite

    plain = load_run("slew-rw").data
    case = next(c for c in load_suite("acceptance").cases if c.id == "slew-rw")
    item = load_run(case.run, case.overrides).data
    assert len(item["expect"]) == len(plain["expect"]) + 1  # the suite adds a criterion
    assert run_sha256(item) != run_sha256(plain)
    # the same run data on another rig (its own default bus) and prose: the same run
    # configuration, the rig is the series' own key
    other = load_run("slew-rw", {"rig": "sgsrt-canopen", "description": "again"}).data
    assert other["bus"] == "virtual:sgsrt-canopen"
    assert run_sha256(other) == run_sha256(plain)
    with HistoryDB(":memory:") as db:
        for i, (run, n) in enumerate([(plain, 7), (item, 8), (plain, 7)]):
            db.add(Record(key=f"k{i}", kind="run", test="slew-rw", rig="sgsrt",
                          time_utc=f"2026-11-0{1 + i}T00:00:00Z", run_sha256=run_sha256(run),
                          criteria=[{"name": f"c{j}", "value": 1.0} for j in range(n)]))
        runs = {c["run_sha256"]: c["runs"] for c in db.catalogue() if c["criterion"] == "c0"}
        assert runs == {run_sha256(plain): 2, run_sha256(item): 1}


def write_first_layout(conn: Any, pk: str) -> None:
    """The database as the first layout wrote it (no ``run_sha256``), with one record."""
    from harness.history.db import _TABLES

    for stmt in _TABLES:
        if "records_series" not in stmt:  # an index of the second layout
            conn.execute(stmt.format(pk=pk).replace("        run_sha256 TEXT,\n", ""))
    conn.execute("INSERT INTO schema_version (version) VALUES (1)")
    conn.execute("INSERT INTO records (key, kind, time_utc, recorded_utc, test, rig, "
                 "real_rig) VALUES ('old', 'run', '2026-01-01T00:00:00Z', "
                 "'2026-01-01T00:00:00Z', 't', 'sgsrt', 0)")
    conn.execute("INSERT INTO criteria (record_id, name, value, unit) VALUES "
                 "((SELECT id FROM records WHERE key = 'old'), 'c', 1.0, 'm')")


def check_first_layout_opens_migrated(path: str) -> None:
    with HistoryDB(path) as db:
        assert db._query("SELECT version FROM schema_version")[0]["version"] == SCHEMA_VERSION
        db.add(Record(key="new", kind="run", test="t", rig="sgsrt", run_sha256="abc",
                      time_utc="2026-02-01T00:00:00Z",
                      criteria=[{"name": "c", "value": 2.0, "unit": "m"}]))
        assert sorted(c["run_sha256"] for c in db.catalogue()) == ["", "abc"]
        assert [r["value"] for r in db.criterion_series("t", "c")] == [1.0, 2.0]
    with HistoryDB(path) as db:  # opened again: nothing to migrate
        assert db.count() == 2


def test_a_database_of_the_first_layout_opens_migrated(tmp_path):
    """A history.sqlite written before run configurations were kept: opened, migrated (the
    column added, the version raised), its records kept and readable beside new ones."""
    import sqlite3

    path = tmp_path / "history.sqlite"
    old = sqlite3.connect(path)
    write_first_layout(old, "INTEGER PRIMARY KEY AUTOINCREMENT")
    assert "run_sha256" not in {r[1] for r in old.execute("PRAGMA table_info(records)")}
    old.commit()
    old.close()
    check_first_layout_opens_migrated(str(path))


def test_history_times_are_instants(tmp_path):
    location = str(tmp_path / "history.sqlite")
    with HistoryDB(location) as db:
        for i, t in enumerate(["2025-12-31T23:30:00Z", "2026-01-01T07:30:00Z",
                               "2026-01-01T08:30:00Z", "2026-01-02T00:00:00Z"]):
            db.add(Record(key=f"k{i}", kind="run", test="t", rig="sgsrt", time_utc=t,
                          criteria=[{"name": "c", "value": float(i), "margin": 1.0}]))

    def times(*filters: str) -> list[str]:
        code, out = cli("history", "show", "t", "--criterion", "c", "--json", "--db",
                        location, *filters)
        assert code == 0, out
        return [r["time_utc"][:16] for r in first_json(out)["series"][0]["runs"]]

    assert times("--since", "20260101") == times("--since", "2026-01-01") == [
        "2026-01-01T07:30", "2026-01-01T08:30", "2026-01-02T00:00"]
    # 10:00 at UTC+2 is 08:00 UTC: between the two runs of that morning
    assert times("--since", "2026-01-01T10:00+02:00") == ["2026-01-01T08:30",
                                                          "2026-01-02T00:00"]
    assert times("--until", "2026-01-01T10:00+02:00") == ["2025-12-31T23:30",
                                                          "2026-01-01T07:30"]
    for bad in ("yesterday", "2026-13-01", "2026-01-01T10:00+25:00"):
        code, out = cli("history", "list", "--db", location, "--until", bad)
        assert code == 2 and "--until" in out and "Traceback" not in out
        assert len(out.strip().splitlines()) == 1, out


def test_history_import_skips_and_names_a_bad_folder(tmp_path):
    logs = tmp_path / "logs"
    path = decay_run_file(tmp_path, rig_file(tmp_path, "r"), "imported",
                          {"peak": {"measure": "peak_tip_accel_m_s2", "max_m_s2": 1.0}},
                          duration_s=1.0, rate_hz=100)
    for _ in range(3):
        assert main(["run", str(path), "--out", str(logs), "--quiet"]) == 0
    dirs = sorted(logs.glob("*-imported"))
    # hand-edited: the first run's verdict is a list, the second's identity one too
    (dirs[0] / "verdict.json").write_text("[1, 2]")
    v = json.loads((dirs[1] / "verdict.json").read_text())
    v["identity"] = ["edited"]
    (dirs[1] / "verdict.json").write_text(json.dumps(v))
    db = tmp_path / "fresh.sqlite"
    code, out = cli("history", "import", "--logs", str(logs), "--db", str(db))
    assert code == 0 and "Traceback" not in out, out
    assert f"skipped {dirs[0]}" in out and f"skipped {dirs[1]}" in out
    assert "run added: 1" in out and "run skipped: 2" in out
    with HistoryDB(str(db)) as h:
        assert [r["source"] for r in h.records()] == [str(dirs[2])]


# ----------------------------------------------------------------------------- scatter
def test_a_failure_from_raised_noise_is_beyond_the_predicted_scatter(tmp_path):
    logs = tmp_path / "logs"
    expect = {"tip_noise": {"channel": "/tip/accel_m_s2", "reduce": "rms", "last_s": 1.0,
                            "max_m_s2": 0.0062, "why": "1.25 x the accelerometer's noise"}}
    model = rig_file(tmp_path, "model")
    # the "real rig" runs: one as the model says (another noise draw), one whose
    # accelerometer got noisier; both are described by the model's rig file
    ok = rig_file(tmp_path, "real-ok", noise_seed=77)
    noisy = rig_file(tmp_path, "real-noisy", noise_seed=78,
                     accelerometer__noise_rms_m_s2=0.0075)
    dirs = {}
    for rig in (ok, noisy):
        # the rig at rest (a zero-torque pulse): the tip sees its accelerometer's noise
        d = run(decay_run_file(tmp_path, rig, "quiet", expect, duration_s=2.0, rate_hz=100,
                               torque_n_m=0.0), logs)
        # a run on the real rig records the rig file it was configured with, not the truth
        cfg = yaml.safe_load((d / "config.yaml").read_text())
        cfg["rig"] = load_rig(str(model)).data
        (d / "config.yaml").write_text(yaml.safe_dump(cfg, sort_keys=False))
        assert main(["judge", str(d)]) in (0, 1, 5)
        dirs[rig.stem] = d
    verdict = json.loads((dirs["real-noisy"] / "verdict.json").read_text())
    assert verdict["verdict"] == "FAIL"
    assert json.loads((dirs["real-ok"] / "verdict.json").read_text())["verdict"] == "PASS"
    code, out = cli("history", "scatter", str(dirs["real-noisy"]), "--model-rig", str(model),
                    "--logs", str(logs), "--json")
    assert code == 1, out
    doc = first_json(out)
    row = next(r for r in doc["criteria"] if r["name"] == "tip_noise")
    assert row["scatter"] == "beyond" and row["verdict"] == "FAIL"
    assert "real change" in row["message"]
    cache = Path(doc["prediction"]["cache"])
    assert cache.is_file() and cache.parent == logs / "scatter"
    assert doc["prediction"]["criteria"]["tip_noise"]["n"] == 5
    code, out = cli("history", "scatter", str(dirs["real-ok"]), "--model-rig", str(model),
                    "--logs", str(logs), "--json")
    assert code == 0, out
    doc = first_json(out)
    row = next(r for r in doc["criteria"] if r["name"] == "tip_noise")
    assert row["scatter"] == "within" and abs(row["z"]) <= 3
    assert "predicting" not in out  # the second call read the cache
    # the series shows the failure beyond the scatter (the judge recorded both runs)
    code, out = cli("history", "show", "quiet", "--criterion", "tip_noise", "--logs", str(logs))
    assert "FAIL" in out and "(beyond the predicted scatter)" in out, out
    assert out.count("predicted scatter") == 1  # a passing run is not marked


# ----------------------------------------------------------------------------- twin
def test_twin_residual_finds_the_changed_rig(tmp_path):
    logs = tmp_path / "logs"
    same = run(decay_run_file(tmp_path, rig_file(tmp_path, "same", noise_seed=5)), logs)
    stand_in = rig_file(tmp_path, "stand-in", noise_seed=6,
                        beam__youngs_modulus_pa=NOMINAL["beam"]["youngs_modulus_pa"] * 1.05)
    changed = run(decay_run_file(tmp_path, stand_in), logs)
    out = {}
    for name, d in (("same", same), ("changed", changed)):
        code, text = cli("twin", str(d), "--rig", str(RIGS_DIR / "sgsrt.yaml"), "--json")
        assert code == (0 if name == "same" else 1), text  # the changed rig: an alarm
        out[name] = json.loads(text)
    def ch(which: str, name: str) -> dict:
        return next(c for c in out[which]["channels"] if c["channel"] == name)

    # unchanged: every sensor's residual is its noise (the model explains the rest)
    # (a channel the rig file gives no noise: within the alarm threshold of its resolution)
    for c in out["same"]["channels"]:
        assert c["rms_over_noise"] is not None, c  # every channel is judged
        if c["noise_from"] == "rig file noise":
            assert 0.8 < c["rms_over_noise"] < 1.3, c
        else:
            assert c["rms_over_noise"] < out["same"]["max_ratio"], c
    assert not out["same"]["beyond"]
    # the changed rig: an alarm, its channels worst first
    ratios = [c["rms_over_noise"] for c in out["changed"]["channels"]]
    assert ratios == sorted(ratios, reverse=True)
    assert out["changed"]["beyond"][0] == out["changed"]["channels"][0]["channel"]
    # changed: the piezo strain sensor near the root sees the mismatch first (tens of times
    # its noise), the hub angle too; the tip accelerometer's is near its noise here
    worst = out["changed"]["worst_channel"]
    assert worst == "/piezo/sensor_ch1_v"
    assert ch("changed", worst)["rms_over_noise"] > 10 * ch("same", worst)["rms_over_noise"]
    assert ch("changed", "/attitude/angle_deg")["rms_over_noise"] > 10
    assert 1.0 < ch("changed", worst)["worst_time_s"] < 20.0
    # the streaming pass gives what the whole channels through the twin give
    from harness.history.twin import simulate
    from harness.testing.judge import read_channels

    chans = read_channels(changed / "run.rrd")
    n = len(chans["/tip/accel_m_s2"][0])
    twin = simulate(NOMINAL, 1 / 50.0, n, {k: v for k, (_, v) in chans.items()})
    r = chans["/piezo/sensor_ch1_v"][1] - twin["/piezo/sensor_ch1_v"]
    assert math.isclose(ch("changed", worst)["rms"], float(np.sqrt(np.mean(r ** 2))),
                        rel_tol=1e-9)
    m1 = out["changed"]["identified_modes"][0]
    assert m1["change_percent"] > 1.5  # about +2.5 %: sqrt(1.05)
    code, text = cli("twin", str(changed), "--rig", str(RIGS_DIR / "sgsrt.yaml"))
    assert "largest residual over its noise: /piezo/sensor_ch1_v, worst" in text
    code, text = cli("twin", str(tmp_path), process=True)
    assert code == 2 and "no run.rrd" in text


# ----------------------------------------------------------------------------- hooks
def test_run_and_import_record_each_result_once(tmp_path):
    logs = tmp_path / "logs"
    expect = {"peak": {"measure": "peak_tip_accel_m_s2", "max_m_s2": 1.0}}
    path = decay_run_file(tmp_path, rig_file(tmp_path, "r"), "hooked", expect, duration_s=2.0,
                          rate_hz=100)
    assert main(["run", str(path), "--out", str(logs), "--quiet"]) == 0
    with open_db(logs=logs) as db:
        assert db.count() == 1
        rec = db.records()[0]
        assert rec["test"] == "hooked" and rec["rig"] == "sgsrt" and not rec["real_rig"]
        assert rec["rig_sha256"] and rec["config_sha256"] and rec["commit_sha"]
    # an import of the same folder adds nothing; into a new database it adds the run
    assert main(["history", "import", "--logs", str(logs)]) == 0
    other = tmp_path / "other.sqlite"
    assert main(["history", "import", "--logs", str(logs), "--db", str(other)]) == 0
    with HistoryDB(str(other)) as db:
        assert db.count() == 1 and db.count("criteria") == 1
    with open_db(logs=logs) as db:
        assert db.count() == 1


def test_suite_report_shows_each_criterions_recent_trend(tmp_path):
    out = tmp_path / "out"
    run_file = decay_run_file(tmp_path, rig_file(tmp_path, "r"), "trended",
                              {"peak": {"measure": "peak_tip_accel_m_s2", "max_m_s2": 1.0}},
                              duration_s=2.0, rate_hz=100)
    suite = tmp_path / "trend.yaml"
    suite.write_text(yaml.safe_dump({"name": "trend", "tests": [{"run": str(run_file)}]}))
    for _ in range(2):
        proc = harness_in_process("test", str(suite), "--out", str(out), "--workers", "1")
        assert proc.returncode == 0, proc.stderr[-2000:]
    report = sorted(out.glob("*-trend"))[-1]
    doc = json.loads((report / "results.json").read_text())
    crit = next(c for c in doc["tests"][0]["criteria"] if c["name"] == "peak")
    assert len(crit["trend"]) == 2 and crit["trend"][-1] == crit["value"]
    assert "(recent: " in (report / "report.md").read_text()
    assert "(recent: " in (report / "report.html").read_text()
    with open_db(logs=out) as db:
        assert db.count() == 2


# ----------------------------------------------------------------------------- PostgreSQL
PG_URL = os.environ.get("SGSRT_TEST_PG_URL")


@pytest.fixture
def pg_url() -> str:
    if not PG_URL:
        if os.environ.get("SGSRT_PG_REQUIRED") == "1":
            pytest.fail("SGSRT_PG_REQUIRED=1 but SGSRT_TEST_PG_URL is unset (.ci/run starts "
                        "the server)")
        pytest.skip("no PostgreSQL server: set SGSRT_TEST_PG_URL (.ci/run does)")
    import psycopg

    with psycopg.connect(PG_URL, autocommit=True) as conn:
        for t in ("modes", "criteria", "records", "schema_version"):
            conn.execute(f"DROP TABLE IF EXISTS {t} CASCADE")
    return PG_URL


def test_postgresql_many_writers_and_series(pg_url):
    many_writers(pg_url, writers=4, each=20)
    with HistoryDB(pg_url) as db:
        assert db.is_pg
        assert db.count("records") == 80 and db.count("criteria") == 80
        assert db.add(_rec(0, 0)) is None
        for i, v in enumerate([0.5, 0.5, 0.51, 0.49, 0.5, 1.5]):
            db.add(Record(key=f"pg-series-{i}", kind="run", test="pg",
                          time_utc=f"2026-12-{1 + i:02d}", verdict="PASS",
                          criteria=[{"name": "c", "value": v, "unit": "m",
                                     "limit": {"max_m": 2.0}, "margin": 2 - v,
                                     "verdict": "PASS"}]))
        s = analyse(criterion_series(db, "pg", "c"))
        assert [a.index for a in s.alarms if a.kind == "control"] == [5]  # the margin's chart
    code, out = cli("history", "show", "pg", "--criterion", "c", "--db", pg_url)
    assert code == 1 and "ALARM (control, run 5)" in out


def test_postgresql_two_rigs_keep_two_series(pg_url):
    check_two_rigs_keep_two_series(pg_url, ["--db", pg_url])


def test_postgresql_database_of_the_first_layout_opens_migrated(pg_url):
    import psycopg

    with psycopg.connect(pg_url, autocommit=True) as conn:
        write_first_layout(conn, "BIGSERIAL PRIMARY KEY")
    check_first_layout_opens_migrated(pg_url)


def test_a_mode_leaving_the_calibrated_band_says_to_calibrate_again(tmp_path):
    from harness.history.record import design_bands
    from harness.history.series import Series

    rec = tmp_path / "recommended.yaml"
    rec.write_text(yaml.safe_dump({"controller": {"type": "shaped_wheel_slew", "modes": [
        {"omega_rad_s": 2.9, "damping_ratio": 0.05, "sigma_omega_rad_s": 0.01,
         "sigma_damping": 0.004}]}}))
    bands = design_bands(rec)
    # the band is +-max(3 sigma, 5 %): 5 % of 2.9 rad/s here
    assert math.isclose(bands[0]["omega_hi_rad_s"], 2.9 * 1.05)
    rows = [{"time_utc": f"d{i}", "value": w, "sigma": 0.01, "source": ""}
            for i, w in enumerate([2.9, 3.0, 3.1])]
    s = analyse(Series("mode", "identify[x]", "mode 1", "rad/s", rows), bands=bands,
                designed_by=str(rec))
    band = [a for a in s.alarms if a.kind == "band"]
    assert [a.index for a in band] == [2]  # 3.0 is inside 3.045, 3.1 is not
    assert "run `harness calibrate` again" in band[0].message


def test_a_database_that_cannot_be_written_never_fails_the_command(tmp_path, capsys):
    logs = tmp_path / "logs"
    logs.mkdir()
    (logs / "history.sqlite").mkdir()  # a directory where the file should be
    path = decay_run_file(tmp_path, rig_file(tmp_path, "r"), "unrecorded",
                          {"peak": {"measure": "peak_tip_accel_m_s2", "max_m_s2": 1.0}},
                          duration_s=1.0, rate_hz=100)
    assert main(["run", str(path), "--out", str(logs), "--quiet"]) == 0
    err = capsys.readouterr().err
    assert "history: not recorded" in err and "Traceback" not in err
    assert list(logs.glob("*-unrecorded/verdict.json"))  # the run's own files are there
