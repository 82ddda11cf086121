"""The verdict layer on real (short) runs: `harness run` judges at the end, `harness judge`
re-judges offline to the same verdict.json, exit codes, baselines, faults, refused criteria,
and `harness logs`' verdict column."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import pytest
import yaml

from harness.cli import main
from harness.core.runs import RUNS_DIR, load_run
from harness.testing import judge_run

DURATION_S = 4.0


def run_file(tmp_path: Path, expect: object, name: str = "t", **over: object) -> Path:
    """A copy of the built-in slew-rw, shortened, with ``expect`` as its criteria."""
    raw = yaml.safe_load((RUNS_DIR / "slew-rw.yaml").read_text())
    raw.update(name=name, duration_s=DURATION_S, expect=expect, **over)
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(raw, sort_keys=False))
    return path


def run(path: Path, out: Path, *extra: str) -> tuple[int, Path | None]:
    code = main(["run", str(path), "--out", str(out), "--quiet", *extra])
    dirs = sorted(p for p in out.iterdir() if p.is_dir()) if out.is_dir() else []
    return code, (dirs[-1] if dirs else None)


def verdict_of(run_dir: Path) -> dict:
    return json.loads((run_dir / "verdict.json").read_text())


TORQUE = {"measure": "max_wheel_torque_cmd_n_m"}


def test_tightened_limits_fail_marginal_and_pass_with_exit_codes(tmp_path, capsys):
    # 4 s into the 20 deg slew the wheel has been commanded 0.036 N m at most
    out = tmp_path / "logs"
    code, d = run(run_file(tmp_path, {"torque": {**TORQUE, "max_n_m": 0.065}}, "ok"), out)
    assert code == 0 and verdict_of(d)["verdict"] == "PASS"
    code, d = run(run_file(tmp_path, {"torque": {**TORQUE, "max_n_m": 0.04,
                                                 "marginal_n_m": 0.01}}, "marg"), out)
    assert code == 5 and verdict_of(d)["verdict"] == "MARGINAL"
    capsys.readouterr()
    code, d = run(run_file(tmp_path, {"torque": {**TORQUE, "max_n_m": 0.03}}, "tight"), out)
    assert code == 1
    v = verdict_of(d)
    assert v["verdict"] == "FAIL"
    [c] = v["criteria"]
    assert c["name"] == "torque" and c["limit"] == {"max_n_m": 0.03}
    assert 0.03 < c["value"] < 0.065 and c["margin"] < 0 and c["unit"] == "n_m"
    assert 1.0 < c["worst_time_s"] <= DURATION_S  # the commanded peak's sample, from run.rrd
    err = capsys.readouterr().err
    assert "VERDICT FAIL (exit 1)" in err and "torque" in err
    # units as people write them (N m), the limit's key as the run file writes it
    assert f"{c['value']:.4g} N m" in c["message"] and f"{c['value']:.4g} n_m" not in err
    assert "max_n_m 0.03" in err


@pytest.fixture(scope="module")
def judged_run(tmp_path_factory):
    """One short slew judged at the end of `harness run` with every form a run can check
    by itself (baseline: tested below)."""
    tmp = tmp_path_factory.mktemp("judged")
    expect = {
        "final_error": {"measure": "final_angle_error_deg", "max_abs_deg": 0.1},
        "no_overruns": {"measure": "overruns", "max_count": 0},
        "torque": {"channel": "/wheel/torque_cmd_n_m", "max_abs_n_m": 0.065},
        "accel_rms": {"channel": "/tip/accel_m_s2", "reduce": "rms", "max_m_s2": 0.05,
                      "last_s": 2.0},
        "still_at_start": {"settles": "/attitude/angle_deg", "band_deg": 0.01, "within_s": 0.5,
                           "stays_s": 0.5},
        "safe": {"left_safe": True},
    }
    code, d = run(run_file(tmp, expect, "judged"), tmp / "logs")
    return code, d


def test_judged_at_the_end_and_offline_give_the_same_verdict(judged_run, capsys):
    code, d = judged_run
    assert code == 0
    first = (d / "verdict.json").read_text()
    v = json.loads(first)
    assert v["verdict"] == "PASS" and len(v["criteria"]) == 6
    ident = v["identity"]
    assert ident["recording_id"] == d.name and ident["rig"] == "sgsrt"
    assert ident["bus"] == "virtual:sgsrt" and len(ident["run_rrd_sha256"]) == 64
    assert len(ident["can_blf_sha256"]) == 64 and len(ident["config_sha256"]) == 64
    assert ident["harness_version"] and ident["commit"]
    assert (d / "verdict.rrd").stat().st_size > 0
    assert main(["judge", str(d)]) == 0
    assert (d / "verdict.json").read_text() == first
    assert "VERDICT PASS" in capsys.readouterr().out
    assert judge_run(d).to_dict() == v


def test_verdict_rrd_holds_the_document_and_violation_events(judged_run, tmp_path):
    from rerun.chunk import RrdReader

    _, d = judged_run
    copy = tmp_path / d.name
    shutil.copytree(d, copy)
    expect = tmp_path / "strict.yaml"
    expect.write_text(yaml.safe_dump({"expect": {"torque": {
        "channel": "/wheel/torque_cmd_n_m", "max_abs_n_m": 0.02}}}))
    assert main(["judge", str(copy), "--expect", str(expect), "--write"]) == 1
    entities = {c.entity_path for c in RrdReader(copy / "verdict.rrd").stream().to_chunks()}
    assert {"/run/verdict", "/events/verdict"} <= entities
    v = verdict_of(copy)
    assert v["identity"]["criteria_from"] == "strict.yaml"
    assert v["criteria"][0]["worst_time_s"] > 1.0


def test_baseline_against_itself_passes_and_a_changed_gain_fails(judged_run, tmp_path,
                                                                  capsys):
    _, base = judged_run
    same = tmp_path / "same.yaml"
    crit = {"baseline": str(base), "channel": "/attitude/error_deg", "tol_deg": 0.0005,
            "max_shift_s": 0.01}
    same.write_text(yaml.safe_dump({"expect": {"angle": crit}}))
    copy = tmp_path / "copy"
    shutil.copytree(base, copy)
    assert main(["judge", str(copy), "--expect", str(same), "--write"]) == 0
    assert verdict_of(copy)["criteria"][0]["value"] == 0.0
    # the same slew with the PD's bandwidth changed, judged against the baseline by its
    # run file, whose baseline path is relative to the run file
    rel = os.path.relpath(base, tmp_path)
    assert not Path(rel).is_absolute()
    raw = yaml.safe_load((RUNS_DIR / "slew-rw.yaml").read_text())
    path = run_file(tmp_path, {"angle": dict(crit, baseline=str(rel))}, "gain",
                    controller=dict(raw["controller"], bandwidth_rad_s=1.0))
    capsys.readouterr()
    code, d = run(path, tmp_path / "logs")
    assert code == 1
    [c] = verdict_of(d)["criteria"]
    assert c["verdict"] == "FAIL" and "/attitude/error_deg" in c["message"]
    assert c["worst_time_s"] is not None and f"t = {c['worst_time_s']:.3f} s" in c["message"]
    assert c["value"] > 0.0005


def test_fault_expected_passes_and_unexpected_fault_is_error(tmp_path):
    faults = [{"kind": "silent_sensor", "at_s": 1.0, "device": "hub_sensor"}]
    expect = {"detected": {"fault": "hub_sensor", "kind": "silent", "within_ticks": 4},
              "safe": {"left_safe": True}}
    code, d = run(run_file(tmp_path, expect, "expected", faults=faults), tmp_path / "a")
    v = verdict_of(d)
    assert code == 0 and v["verdict"] == "PASS", v["reason"]
    assert v["criteria"][0]["value"] <= 4
    code, d = run(run_file(tmp_path, None, "unexpected", faults=faults), tmp_path / "b")
    v = verdict_of(d)
    assert code == 3 and v["verdict"] == "ERROR" and "did not expect" in v["reason"]
    # expecting another kind: the expectation fails and the fault is still unexpected
    other = {"detected": {"fault": "hub_sensor", "kind": "stuck"}}
    assert main(["judge", str(d), "--expect", str(_expect_file(tmp_path, other)),
                 "--write"]) == 3


def _expect_file(tmp_path: Path, expect: dict) -> Path:
    p = tmp_path / "expect.yaml"
    p.write_text(yaml.safe_dump({"expect": expect}))
    return p


def _edit_summary(d: Path, **changes: object) -> None:
    s = json.loads((d / "summary.json").read_text())
    s.update(changes)
    (d / "summary.json").write_text(json.dumps(s))


def test_error_verdicts_and_judge_exit_codes(judged_run, tmp_path, capsys):
    _, base = judged_run

    def copy(name: str) -> Path:
        return Path(shutil.copytree(base, tmp_path / name))

    d = copy("raised")
    _edit_summary(d, stopped_by="error", error="ZeroDivisionError: x (tick 12)")
    assert main(["judge", str(d)]) == 4
    assert "the run raised: ZeroDivisionError" in verdict_of(d)["reason"]
    d = copy("interrupted")
    _edit_summary(d, stopped_by="interrupted")
    assert main(["judge", str(d)]) == 130
    d = copy("overruns")  # a real-time budget not held: the bench, not the controller
    _edit_summary(d, overruns=7)
    assert main(["judge", str(d)]) == 6
    c = next(c for c in verdict_of(d)["criteria"] if c["name"] == "no_overruns")
    assert c["verdict"] == "INCONCLUSIVE" and "real-time budget" in c["message"]
    assert verdict_of(d)["verdict"] == "INCONCLUSIVE"
    d = copy("killed")
    (d / "summary.json").unlink()
    assert main(["judge", str(d)]) == 4
    assert "no summary.json" in (d / "verdict.json").read_text()
    d = copy("no-rrd")
    (d / "run.rrd").unlink()
    assert main(["judge", str(d)]) == 4
    capsys.readouterr()
    assert main(["judge", str(tmp_path / "nope")]) == 2
    bad = _expect_file(tmp_path, {"x": {"measure": "final_angle_error_deg", "max": 1}})
    assert main(["judge", str(base), "--expect", str(bad), "--write"]) == 2
    assert "expect.x.max: missing unit" in capsys.readouterr().err


def test_bad_criteria_refused_before_anything_is_sent(tmp_path, capsys):
    out = tmp_path / "logs"
    path = run_file(tmp_path, {"e": {"measure": "final_angle_error_deg", "max_abs_s": 1}},
                    "bad")
    assert main(["run", str(path), "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "run file bad.yaml: expect.e.max_abs_s: final_angle_error_deg is in deg" in err
    assert not out.exists()
    path = run_file(tmp_path, {"b": {"baseline": "../missing", "channel": "/attitude/angle_deg",
                                     "tol_deg": 0.1}}, "nobase")
    assert main(["run", str(path), "--out", str(out), "--quiet"]) == 2
    assert "expect.b.baseline: baseline" in capsys.readouterr().err
    # a variant's bad criterion refuses the whole run file before its first variant runs
    ok = {"e": {"measure": "final_angle_error_deg", "max_abs_deg": 0.1}}
    path = run_file(tmp_path, ok, "variants", variants={
        "a": {"duration_s": 1.0}, "b": {"expect": {"e": {"min_deg": 1, "max_deg": 0}}}})
    assert main(["run", str(path), "--out", str(out), "--quiet"]) == 2
    assert "expect.e.min_deg: min 1 > max 0" in capsys.readouterr().err
    assert not out.exists()


def test_variants_and_rig_override_criteria(tmp_path):
    expect = {"e": {"measure": "final_angle_error_deg", "max_abs_deg": 0.1},
              "o": {"measure": "overruns", "max_count": 0}}
    path = run_file(tmp_path, expect, "v")
    run_v = load_run(str(path), {"expect": {"e": {"max_abs_deg": 0.2}, "o": None}})
    assert run_v.data["expect"] == {"e": {"measure": "final_angle_error_deg",
                                          "max_abs_deg": 0.2}, "o": None}
    # a rig file (here through rig_overrides) tightens a limit by criterion name
    path = run_file(tmp_path, {"torque": {**TORQUE, "max_n_m": 0.065}}, "rigover",
                    rig_overrides={"expect_overrides": {"torque": {"max_n_m": 0.03}}})
    code, d = run(path, tmp_path / "logs")
    assert code == 1 and verdict_of(d)["criteria"][0]["limit"] == {"max_n_m": 0.03}
    with pytest.raises(Exception, match=r"expect_overrides\.torque\.measure: only limits"):
        load_run(str(run_file(tmp_path, {"torque": {**TORQUE, "max_n_m": 0.065}}, "rigbad",
                              rig_overrides={"expect_overrides": {"torque": {
                                  "measure": "overruns"}}})))


def test_logs_shows_verdicts_and_lists_failures(judged_run, tmp_path, capsys):
    _, base = judged_run
    logs = tmp_path / "logs"
    logs.mkdir()
    ok = Path(shutil.copytree(base, logs / "20260101T000000.000000Z-ok"))
    bad = Path(shutil.copytree(base, logs / "20260101T000001.000000Z-bad"))
    assert main(["judge", str(bad), "--expect", str(_expect_file(tmp_path, {
        "t": {"channel": "/wheel/torque_cmd_n_m", "max_abs_n_m": 0.01}})), "--write"]) == 1
    nov = Path(shutil.copytree(base, logs / "20260101T000002.000000Z-unjudged"))
    (nov / "verdict.json").unlink()
    killed = logs / "20260101T000003.000000Z-killed"
    killed.mkdir()
    (killed / "config.yaml").write_text("run: {}\n")
    capsys.readouterr()
    assert main(["logs", "--logs", str(logs), "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert [r.get("verdict") for r in rows] == ["PASS", "FAIL", None, None]
    assert main(["logs", "--logs", str(logs)]) == 0
    out = capsys.readouterr().out
    assert "verdict" in out and "PASS" in out and "FAIL" in out
    assert main(["logs", "--logs", str(logs), "--failed"]) == 0
    out = capsys.readouterr().out
    assert bad.name in out and killed.name in out
    assert ok.name not in out and nov.name not in out


def test_dry_run_judges_only_the_safe_state(tmp_path):
    """A dry run commands nothing: the run's criteria would judge a slew that never
    happened, so only left_safe and the run's own checks are judged."""
    expect = {"moved": {"measure": "final_angle_deg", "min_deg": 0.1},
              "safe": {"left_safe": True}}
    code, d = run(run_file(tmp_path, expect, "dry"), tmp_path / "logs", "--dry-run")
    v = verdict_of(d)
    assert code == 0 and [c["name"] for c in v["criteria"]
                          if c["verdict"] != "NOT JUDGED"] == ["safe"]
    # the others are listed, not dropped: NOT JUDGED with why
    assert all("dry run" in c["message"] for c in v["criteria"]
               if c["verdict"] == "NOT JUDGED")
    assert v["reason"].startswith("dry run")
    assert main(["judge", str(d), "--expect", str(_expect_file(tmp_path, expect)),
                 "--write"]) == 0


def test_every_built_in_run_states_its_criteria():
    """Every built-in run file (and variant) has an expect: section, checked, with a why."""
    from harness.core.runs import list_runs
    from harness.testing import parse_criteria

    for name, _ in list_runs():
        r = load_run(name)
        runs = [r] + [load_run(name, dict(v)) for v in (r.data["variants"] or {}).values()]
        for x in runs:
            crits = parse_criteria(x.data["expect"], name)
            assert len(crits) >= 4, name
            assert all(c.why for c in crits), name
            assert any(c.kind == "left_safe" for c in crits), name


def test_built_in_slew_passes_and_a_tightened_copy_fails_or_is_marginal(slew_result, tmp_path,
                                                                        capsys):
    """The full built-in slew-rw judged by its own criteria, then by copies of its run file
    with one limit tightened beyond what the slew needs (its profile alone peaks at 0.052 N
    m), and with a marginal band the measured peak (0.0532 N m) falls in."""
    d = Path(shutil.copytree(slew_result.run_dir, tmp_path / slew_result.run_dir.name))
    assert main(["judge", str(d)]) == 0, capsys.readouterr().out
    raw = yaml.safe_load((RUNS_DIR / "slew-rw.yaml").read_text())
    tight = tmp_path / "tight.yaml"
    raw["expect"]["wheel_torque"]["max_n_m"] = 0.04
    tight.write_text(yaml.safe_dump(raw))
    capsys.readouterr()
    assert main(["judge", str(d), "--expect", str(tight), "--write"]) == 1
    out = capsys.readouterr().out
    v = verdict_of(d)
    [c] = [c for c in v["criteria"] if c["verdict"] != "PASS"]
    assert c["name"] == "wheel_torque" and c["limit"] == {"max_n_m": 0.04}
    assert c["value"] == pytest.approx(0.0532, abs=5e-4)
    assert v["reason"].startswith("wheel_torque: max_wheel_torque_cmd_n_m = 0.05")
    assert "outside max_n_m 0.04" in out and "VERDICT FAIL (exit 1)" in out
    raw["expect"]["wheel_torque"].update(max_n_m=0.065, marginal_n_m=0.013)
    tight.write_text(yaml.safe_dump(raw))
    assert main(["judge", str(d), "--expect", str(tight), "--write"]) == 5
    assert verdict_of(d)["verdict"] == "MARGINAL"


def test_fault_test_reusing_a_run_file_is_judged_on_its_fault(tmp_path):
    """slew-rw's own criteria (a clean bus, settling) plus a fault expectation: the run
    stops at the fault by design, so only the fault and the safe state are judged."""
    raw = yaml.safe_load((RUNS_DIR / "slew-rw.yaml").read_text())
    expect = dict(raw["expect"], detected={"fault": "accelerometer", "kind": "malformed frame",
                                           "within_ticks": 1})
    faults = [{"kind": "wrong_length", "at_s": 1.0, "device": "accelerometer"}]
    code, d = run(run_file(tmp_path, expect, "fault-test", faults=faults), tmp_path / "logs")
    v = verdict_of(d)
    assert code == 0, v["reason"]
    assert sorted(c["name"] for c in v["criteria"]
                  if c["verdict"] != "NOT JUDGED") == ["detected", "safe"]
    # the slew's own criteria are listed NOT JUDGED with why, never dropped without a word
    skipped = [c for c in v["criteria"] if c["verdict"] == "NOT JUDGED"]
    assert skipped and all("fault test" in c["message"] for c in skipped)
    assert v["reason"].startswith("fault test")


def test_a_criterion_that_applies_to_a_stopped_run_is_judged_in_a_fault_test(tmp_path):
    """A channel criterion with applies_to_stopped: true in a fault test is judged, and its
    FAIL fails the test (it was dropped without a word: 'all 2 criteria passed')."""
    expect = {"detected": {"fault": "accelerometer", "kind": "malformed frame",
                           "within_ticks": 1},
              "quiet_tip": {"channel": "/tip/accel_m_s2", "max_abs_m_s2": 1e-6,
                            "applies_to_stopped": True},
              "safe": {"left_safe": True}}
    faults = [{"kind": "wrong_length", "at_s": 1.0, "device": "accelerometer"}]
    code, d = run(run_file(tmp_path, expect, "fault-test-stopped", faults=faults),
                  tmp_path / "logs")
    v = verdict_of(d)
    by_name = {c["name"]: c["verdict"] for c in v["criteria"]}
    assert by_name["quiet_tip"] == "FAIL" and v["verdict"] == "FAIL" and code == 1, by_name
