"""Readers of a run folder other than the judge (the twin here) go through one validated
loader: a damaged or hand-edited file is refused naming the file and the field (exit 2),
never a traceback, and the work is bounded before it starts."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
import yaml

from harness.cli import main
from harness.core.runs import load_run
from harness.core.session import execute_run
from harness.record.run_folder import RunFolderError, identified_modes, load_run_folder


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("runs")
    return execute_run(load_run("slew-rw", {"duration_s": 3.0}), out_dir=out,
                       show_progress=False).run_dir


def _copy(run_dir: Path, tmp_path: Path, name: str) -> Path:
    return Path(shutil.copytree(run_dir, tmp_path / name))


def _edit_run(d: Path, **changes: object) -> None:
    cfg = yaml.safe_load((d / "config.yaml").read_text())
    cfg["run"].update(changes)
    (d / "config.yaml").write_text(yaml.safe_dump(cfg))


@pytest.mark.parametrize("rate", [0, float("nan"), -5, "fast", 1e9])
def test_a_bad_rate_is_refused_naming_the_field(run_dir, tmp_path, capsys, rate):
    d = _copy(run_dir, tmp_path, "rate")
    _edit_run(d, rate_hz=rate)
    with pytest.raises(RunFolderError, match="run.rate_hz"):
        load_run_folder(d)
    assert main(["twin", str(d)]) == 2
    err = capsys.readouterr().err
    assert "config.yaml: run.rate_hz" in err and "Traceback" not in err


def test_identify_json_of_the_wrong_shape_is_refused(run_dir, tmp_path, capsys):
    d = _copy(run_dir, tmp_path, "ident")
    (d / "identify.json").write_text(json.dumps([{"omega_rad_s": 2.9}]))
    with pytest.raises(RunFolderError, match="identify.json: expected a JSON object"):
        identified_modes(d)
    assert main(["twin", str(d)]) == 2
    assert "identify.json" in capsys.readouterr().err
    (d / "identify.json").write_text(json.dumps({"modes": [{"omega_rad_s": 0}]}))
    assert main(["twin", str(d)]) == 2
    assert "modes[0].omega_rad_s" in capsys.readouterr().err


def test_samples_past_the_runs_end_are_refused_before_work_is_sized(run_dir, tmp_path,
                                                                       capsys):
    """A recording reaching far past the configured end (an edited duration, a far time
    stamp) is not this run's data: refused at once, never allocated tick by tick."""
    d = _copy(run_dir, tmp_path, "far")
    _edit_run(d, duration_s=0.01)  # the 3 s recording now ends ~1.5 s past "the end"
    assert main(["twin", str(d)]) == 2
    err = capsys.readouterr().err
    assert "past the run's end" in err and "run.rrd" in err
    assert main(["twin", str(run_dir)]) == 0  # the untouched folder is read


def _judged(run_dir: Path, tmp_path: Path, name: str) -> Path:
    d = _copy(run_dir, tmp_path, name)
    assert main(["judge", str(d)]) in (0, 1, 4, 5)  # 3 s: the settling is not reached
    return d


def test_an_edited_scatter_cache_is_refused_naming_the_field(run_dir, tmp_path, capsys):
    from harness.history.scatter import CACHE_DIR, cache_key

    d = _judged(run_dir, tmp_path, "cache")
    cfg = yaml.safe_load((d / "config.yaml").read_text())
    logs = tmp_path / "logs"
    cache = logs / CACHE_DIR / f"{cache_key(cfg['run'], cfg['rig'], 3)}.json"
    cache.parent.mkdir(parents=True)
    cache.write_text(json.dumps({"seeds": 3, "criteria": {"final_error": {
        "mean": "0.01", "std": 0.001, "n": 3}}}))
    capsys.readouterr()
    assert main(["history", "scatter", str(d), "--logs", str(logs), "--seeds", "3"]) == 2
    err = capsys.readouterr().err
    assert "criteria.final_error.mean" in err and str(cache.name) in err
    assert "Traceback" not in err


def test_a_30_day_run_is_refused_before_any_virtual_run(run_dir, tmp_path, capsys):
    import time

    d = _judged(run_dir, tmp_path, "long")
    _edit_run(d, duration_s=30 * 24 * 3600.0)
    capsys.readouterr()
    start = time.monotonic()
    assert main(["history", "scatter", str(d), "--logs", str(tmp_path / "logs")]) == 2
    assert time.monotonic() - start < 5.0
    assert "run.duration_s" in capsys.readouterr().err


def test_twin_table_gives_every_value_its_unit(run_dir, capsys):
    assert main(["twin", str(run_dir)]) == 0
    out = capsys.readouterr().out
    angle = next(line for line in out.splitlines() if line.startswith("/attitude/angle_deg"))
    assert angle.count(" deg") == 3 and " s " in angle  # rms, worst, recorded rms; time
    tip = next(line for line in out.splitlines() if line.startswith("/tip/accel_m_s2"))
    assert tip.count("m/s²") == 3


def test_replay_refuses_a_damaged_run_folder_naming_the_file(run_dir, tmp_path, capsys):
    d = _copy(run_dir, tmp_path, "replay")
    (d / "summary.json").write_text(json.dumps([1, 2]))
    capsys.readouterr()
    assert main(["replay", str(d), "--check"]) == 2
    err = capsys.readouterr().err
    assert "summary.json" in err and "expected a JSON object" in err
    d = _copy(run_dir, tmp_path, "replay-rate")
    _edit_run(d, rate_hz=float("nan"))
    assert main(["replay", str(d)]) == 2
    assert "run.rate_hz" in capsys.readouterr().err


def test_the_report_reads_a_run_folder_through_the_loader(run_dir, tmp_path):
    from harness.testing.report import channel_specs, run_plots

    d = _copy(run_dir, tmp_path, "report")
    _edit_run(d, rate_hz=0)
    with pytest.raises(RunFolderError, match="run.rate_hz"):
        channel_specs(d, [])
    plots = run_plots(d, [])  # the report notes it and draws the overview, no traceback
    assert plots and plots[0]["title"] == "no channel criterion: overview"
