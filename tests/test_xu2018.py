"""`harness study xu2018` (paper 003 on the virtual rig): its parts and flat measures."""

from __future__ import annotations

import json
import shutil
from dataclasses import replace
from pathlib import Path

import pytest

from harness.cli import main
from harness.core.runs import load_run
from harness.studies import xu2018


def test_model_and_identify_parts(tmp_path, free_decay_run, monkeypatch):
    asked = []

    def session_free_decay(run, out_dir, show_progress):  # noqa: ANN001, ANN202
        # the identify part's free-decay run: the session's (conftest's free_decay_run, the
        # same run file on the same rig), copied where the study asked for it, not run again
        asked.append((run.name, Path(out_dir)))
        assert run.data == load_run("free-decay").data, "not the run file as it is"
        copy = Path(out_dir) / free_decay_run.run_dir.name
        shutil.copytree(free_decay_run.run_dir, copy)
        return replace(free_decay_run, run_dir=copy)

    monkeypatch.setattr(xu2018, "execute_run", session_free_decay)
    out = xu2018.run_study(("model", "identify"), out_dir=tmp_path)
    assert asked == [("free-decay", tmp_path)]
    m = out["measures"]
    # constrained frequencies within 0.9 % of the paper's, delta_1 within 0.2 %
    for k in (1, 2, 3):
        assert abs(m[f"model_constrained_mode{k}_error_percent"]) < 0.9
    assert abs(m["model_coupling_mode1_error_percent"]) < 0.2
    # the identified modes against the model's, from a free-decay run written to tmp_path
    assert m["identified_mode_count"] == 3
    assert m["identified_worst_omega_error_percent"] < 0.5
    assert m["identified_worst_damping_error_percent"] < 10.0
    assert {md["model_mode"] for md in out["identify"]["modes"]} == {1, 2, 3}
    assert (tmp_path / out["identify"]["run_dir"].split("/")[-1] / "run.rrd").exists()
    assert all(isinstance(v, bool | int | float) for v in m.values())
    assert "cases" not in out and "sweep" not in out


def test_cli_json(tmp_path, capsys):
    assert main(["study", "xu2018", "--only", "model", "--json", "--out", str(tmp_path)]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["measures"]["model_hub_free_mode1_vs_paper_calculated_percent"] == pytest.approx(
        100 * (out["model"]["hub_free_omega_rad_s"][0] / 2.8081 - 1))


@pytest.mark.slow
def test_cases_part_orders_beta(paper_suites):
    """The study's cases part on the nine case runs paper003's suite made (100 s each;
    shared for the session by conftest's paper_suites, so no case runs twice)."""
    def suite_run(run, out_dir):  # noqa: ANN001, ANN202 - the suite's run of this case
        found = sorted(paper_suites.out.glob(f"*/*-{run.name}/summary.json"))
        assert len(found) == 1, f"{run.name}: {found}"
        return json.loads(found[0].read_text()), found[0].parent

    rows, m = xu2018.cases_part(paper_suites.out, execute=suite_run)
    out = {"cases": rows, "measures": m}
    assert len(out["cases"]) == 9
    assert all((Path(r["run_dir"]) / "run.rrd").exists() for r in rows)
    for case in ("case_a", "case_b", "case_c"):
        assert m[f"{case}_worst_beta"] == 1.0  # beta = 1 worst, as in the paper's Table 2
        assert m[f"{case}_beta_1p0_over_largest_other"] > 1.0
    assert m["case_c_best_beta"] == 0.8
    row = next(r for r in out["cases"] if r["case"] == "case-c" and r["beta"] == 1.0)
    assert m["case_c_beta_1p0_over_paper"] == pytest.approx(row["ours_m_s2"] / 0.037)
