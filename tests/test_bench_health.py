"""The bench's own health in a real-time run's verdict: timing criteria from the run file's
``realtime:`` limits, INCONCLUSIVE (exit 6) when the bench did not hold its time, with whose
the lost time was (host, harness, device); lockstep runs get none of it."""

from __future__ import annotations

import json
import os
import signal
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from harness.cli import main
from harness.core import session
from harness.core.runs import RUNS_DIR, load_run
from harness.core.session import execute_run
from harness.testing import judge_run
from harness.testing.bench import Episodes, attribute, describe
from harness.testing.outcome import EXIT, EXIT_ORDER, exit_code

BENCH = ("bench_overruns", "bench_lateness", "bench_telemetry")


def _run_file(tmp_path: Path, realtime: dict | None = None, duration_s: float = 2.0) -> Path:
    """slew-rw, short, judged on the rig left safe only (a 2 s slew cannot settle): what is
    left to decide the verdict is the bench's timing."""
    raw = yaml.safe_load((RUNS_DIR / "slew-rw.yaml").read_text())
    raw.pop("variants", None)
    raw.update(name="bench-health", duration_s=duration_s,
               expect={"safe": {"left_safe": True}},
               monitor={"realtime_grace_s": 1.0})  # a stalled rig is not a silent sensor here
    if realtime:
        raw["realtime"] = realtime
    path = tmp_path / "bench-health.yaml"
    path.write_text(yaml.safe_dump(raw))
    return path


def _rt(tmp_path: Path, run_file: Path, **kw):
    res = execute_run(load_run(str(run_file)), out_dir=tmp_path / "logs", clock="realtime",
                      show_progress=False, **kw)
    v = judge_run(res.run_dir)
    return res, v


def _by_name(v) -> dict:
    return {c.name: c for c in v.criteria}


# ------------------------------------------------------------------------------ pure
def test_overrun_episodes_are_whoever_began_them():
    dt = 2.0
    ep = Episodes(dt, 0.5 * dt)
    n = 40
    late, work = np.zeros(n), np.full(n, 0.2)
    work[5] = 30.0                       # a tick's own work past 15 deadlines: the harness's
    late[6:20] = np.linspace(28.0, 1.0, 14)   # ... the ticks behind it catch up
    late[30] = 9.0                       # the loop woke 9 ms late: the host's
    late[31:35] = [7.2, 5.4, 3.6, 1.8]
    t = np.arange(n) * dt * 1e-3
    # fed in two blocks cut inside the first episode
    ep.feed(t[:10], late[:10], work[:10])
    ep.feed(t[10:], late[10:], work[10:])
    assert ep.episodes == {"host": 1, "harness": 1}
    # late + work > the period: ticks 5-18 (tick 19 starts 1.0 ms late, done in time), 30-33
    assert ep.overruns["harness"] == 14 and ep.overruns["host"] == 4
    assert ep.worst["harness"] == (30.0, pytest.approx(0.010))
    assert ep.worst["host"] == (9.0, pytest.approx(0.060))


def test_frames_missing_in_held_ticks_split_host_device_harness():
    summary = {"frames": {"missing_in_ticks_on_time": 10, "missing_in_ticks_host_delayed": 6,
                          "missing_rig_answered_after_window": 3},
               "virtual_rig_timing": {"syncs": 1}}
    assert attribute(summary, None)["frames"] == {"host": 6, "device": 3, "harness": 1}
    # without the rig's own timing (a rig as a thread, the lab's rig) no split is possible
    del summary["virtual_rig_timing"]
    a = attribute(summary, None)
    assert a["frames"] == {"host": 6, "device or harness": 4}
    assert describe(a).startswith("time lost by host: 6 telemetry frames")


def test_inconclusive_has_its_own_exit_code_and_never_hides_a_fail():
    assert EXIT["INCONCLUSIVE"] == 6 and 6 not in (0, 1, 2, 3, 4, 5, 130)
    rec = [{"verdict": "PASS"}, {"verdict": "MARGINAL"}, {"verdict": "INCONCLUSIVE"}]
    assert exit_code(rec) == 6  # worse than a pass
    assert exit_code([*rec, {"verdict": "FAIL"}]) == 1  # another test's FAIL stays seen
    assert EXIT_ORDER.index(1) < EXIT_ORDER.index(6) < EXIT_ORDER.index(5)


def test_lockstep_runs_get_no_timing_criteria(tmp_path):
    res = execute_run(load_run(str(_run_file(tmp_path))), out_dir=tmp_path, clock="lockstep",
                      show_progress=False)
    v = judge_run(res.run_dir)
    assert not set(BENCH) & set(_by_name(v)) and v.verdict == "PASS"


def test_bad_limit_in_the_run_file_is_refused(tmp_path):
    from rig_models.schema import ConfigError

    with pytest.raises(ConfigError, match="realtime.max_overruns_percent"):
        load_run(str(_run_file(tmp_path, {"max_overruns_percent": -1})))


# ------------------------------------------------------------------------------ real time
@pytest.mark.slow
def test_clean_realtime_run_passes_with_its_timing_criteria_shown(tmp_path):
    # this machine is shared (2 CPUs, other work beside the tests): the limits are generous
    # and stated, a clean 2 s run keeps well inside them (measured 0-0.3 % overruns)
    # and stated; still, a host stall of tens of ms (seen here: 41 ms p99 in one 2 s run
    # with the load at 6) is exactly what the criteria must not pass, so a stalled try is
    # repeated, up to three
    path = _run_file(tmp_path, {"max_overruns_percent": 10.0,
                                "max_lateness_p99_period_percent": 100.0,
                                "max_missing_held_percent": 10.0})
    reasons = []
    for attempt in range(3):
        res, v = _rt(tmp_path / str(attempt), path)
        c = _by_name(v)
        assert set(BENCH) <= set(c)
        if v.verdict == "PASS":
            break
        assert v.verdict == "INCONCLUSIVE", v.reason
        reasons.append(v.reason)
    assert v.verdict == "PASS", reasons
    assert c["bench_overruns"].limit == {"max_percent": 10.0}
    assert c["bench_lateness"].limit == {"max_percent": 100.0}
    # shown where people read them: the printed block and verdict.json
    from harness.testing import format_block

    block = format_block(v)
    for name in BENCH:
        assert name in block
    assert all(c[n].why for n in BENCH)


class _StallingController:
    """The run's controller whose step stalls once: the harness's own work past many
    deadlines."""

    def __init__(self, inner, at_tick: int, stall_s: float) -> None:
        self._inner, self._at, self._stall_s, self._n = inner, at_tick, stall_s, 0

    def step(self, state):
        self._n += 1
        if self._n == self._at:
            time.sleep(self._stall_s)
        return self._inner.step(state)

    def __getattr__(self, name):
        if name.startswith("_"):  # copy's probes (__deepcopy__, ...) on a half-built copy
            raise AttributeError(name)
        return getattr(self._inner, name)


@pytest.mark.slow
def test_a_stalled_loop_is_inconclusive_and_the_harness_s(tmp_path, monkeypatch):
    real = session.build_controller
    monkeypatch.setattr(session, "build_controller",
                        lambda run: _StallingController(real(run), 500, 0.6))
    res, v = _rt(tmp_path, _run_file(tmp_path))  # the default limits
    assert v.verdict == "INCONCLUSIVE" and v.exit_code == 6, v.reason
    assert _by_name(v)["bench_overruns"].verdict == "INCONCLUSIVE"
    ov = v.extra["bench"]["overruns"]
    assert ov["ticks"]["harness"] >= 250  # 0.6 s of 2 ms ticks, and the catching up
    w = ov["worst_first_tick"]["harness"]
    assert w["ms"] >= 550 and w["time_s"] == pytest.approx(499 * 0.002, abs=0.01)
    assert "time lost by harness:" in v.reason and "a tick's work took" in v.reason
    # verdict.json and harness judge say the same, exit 6
    assert main(["judge", str(res.run_dir)]) == 6
    doc = json.loads((res.run_dir / "verdict.json").read_text())
    assert doc["verdict"] == "INCONCLUSIVE" and doc["bench"]["overruns"]["ticks"]["harness"]


def _rig_pid() -> int:
    for task in Path("/proc/self/task").iterdir():
        for pid in (task / "children").read_text().split():
            cmd = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ")
            if b"virtual-rig" in cmd or b"virtual_rig" in cmd:
                return int(pid)
    raise AssertionError("no rig process")


@pytest.mark.slow
def test_a_stalled_rig_process_is_inconclusive_and_the_host_s(tmp_path):
    state = {"ticks": 0, "stopped": False}

    def stop_the_rig_once() -> str | None:
        state["ticks"] += 1
        if state["ticks"] == 500 and not state["stopped"]:  # t = 1 s: the OS stops the rig
            pid = _rig_pid()
            os.kill(pid, signal.SIGSTOP)
            state["stopped"] = True
            threading.Timer(0.4, os.kill, (pid, signal.SIGCONT)).start()
        return None

    res, v = _rt(tmp_path, _run_file(tmp_path), should_stop=stop_the_rig_once)
    assert state["stopped"]
    assert v.verdict == "INCONCLUSIVE" and v.exit_code == 6, v.reason
    assert _by_name(v)["bench_telemetry"].verdict == "INCONCLUSIVE"
    frames = v.extra["bench"]["frames"]
    # 0.4 s of about 4.4 frames a tick at 500 Hz, the rig woken late for every one of them
    assert frames["host"] >= 500 and frames["host"] > 5 * (frames["device"] + frames["harness"])
    assert "time lost by host:" in v.reason


@pytest.mark.slow
def test_an_inconclusive_suite_test_in_junit_results_and_reports(tmp_path):
    """A suite's real-time test the bench cannot hold (a lateness limit of 0 % of the period:
    no loop starts every tick exactly on its deadline) is INCONCLUSIVE everywhere a suite's
    result goes: exit 6, JUnit <skipped> with the reason, results.json, report.md and
    report.html; beside it a FAIL of another test is not hidden (exit 1)."""
    import xml.etree.ElementTree as ET

    from in_process import harness_in_process

    run = _run_file(tmp_path, duration_s=1.0)
    suite = tmp_path / "bench.yaml"
    suite.write_text(yaml.safe_dump({"name": "bench", "tests": [
        {"run": str(run), "name": "held-to-nothing",
         "set": {"clock": "realtime", "realtime": {"max_lateness_p99_period_percent": 0.0}}},
    ]}))
    junit = tmp_path / "junit.xml"
    r = harness_in_process("test", str(suite), "--out", str(tmp_path / "out"),
                           "--junit", str(junit), "--workers", "1")
    assert r.returncode == 6, r.stderr
    case = ET.parse(junit).getroot().find(".//testcase")
    skipped = case.find("skipped")
    assert skipped is not None and case.find("failure") is None and case.find("error") is None
    assert skipped.get("message").startswith("INCONCLUSIVE: the bench did not hold real time")
    assert "time lost by" in skipped.get("message")  # whose: host, harness or device
    (out,) = [p for p in (tmp_path / "out").iterdir() if p.name.endswith("-bench")]
    doc = json.loads((out / "results.json").read_text())
    assert doc["verdict"] == "INCONCLUSIVE"
    assert doc["tests"][0]["verdict"] == "INCONCLUSIVE"
    assert "INCONCLUSIVE" in (out / "report.md").read_text()
    assert "INCONCLUSIVE" in (out / "report.html").read_text()
    # with a failing test beside it, the suite's verdict and exit are the FAIL's
    suite.write_text(yaml.safe_dump({"name": "bench", "tests": [
        {"run": str(run), "name": "held-to-nothing",
         "set": {"clock": "realtime", "realtime": {"max_lateness_p99_period_percent": 0.0}}},
        {"run": str(run), "name": "fails",
         "expect": {"never": {"measure": "ticks", "max_count": 0}}},
    ]}))
    r = harness_in_process("test", str(suite), "--out", str(tmp_path / "out2"),
                           "--workers", "1")
    assert r.returncode == 1, r.stderr
    (out2,) = [p for p in (tmp_path / "out2").iterdir() if p.name.endswith("-bench")]
    doc = json.loads((out2 / "results.json").read_text())
    assert doc["verdict"] == "FAIL"
    assert {t["verdict"] for t in doc["tests"]} == {"INCONCLUSIVE", "FAIL"}
