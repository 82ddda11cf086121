"""Nothing moves beyond a limit: a run, a suite's test or a calibration whose planned
motion passes the run's or the rig's limits is refused before its first frame (exit 2, a
sentence naming the limit, no run folder: no can.blf at all)."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import yaml

from harness.core.limits import BeyondLimit, check_run
from harness.core.runs import load_run, run_from_dict
from tests.in_process import harness_in_process


def _run_file(tmp_path: Path, controller: dict, **extra) -> Path:
    data = {"name": "limit-probe", "duration_s": 5.0, "controller": controller, **extra}
    path = tmp_path / "limit-probe.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def _refused(tmp_path: Path, path: Path, *args: str) -> str:
    out = tmp_path / "logs"
    r = harness_in_process("run", str(path), "--out", str(out), "--quiet", *args)
    assert r.returncode == 2, r.stderr
    assert not out.exists() or not any(out.rglob("can.blf")), "a refused run sent frames"
    assert not out.exists() or not any(out.iterdir()), "a refused run left a folder"
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "Traceback" not in r.stderr and "{'" not in r.stderr, r.stderr
    assert "refused before anything was sent" in lines[0]
    return lines[0]


def test_slew_beyond_the_angle_limit_is_refused_before_the_first_frame(tmp_path):
    path = _run_file(tmp_path, {"type": "pd_wheel", "angle_deg": 400.0, "slew_duration_s": 300.0},
                     duration_s=320.0)
    line = _refused(tmp_path, path)
    assert "the hub angle to 400 deg" in line and "limits.max_angle_deg of 180 deg" in line


def test_torque_pulse_beyond_the_wheel_limit_is_refused(tmp_path):
    path = _run_file(tmp_path, {"type": "wheel_pulse", "torque_n_m": -0.1, "width_s": 0.2})
    line = _refused(tmp_path, path)
    assert "wheel torque command to 0.1 N m" in line
    assert "reaction_wheel.max_torque_n_m of 0.065 N m" in line


def test_a_long_pulse_is_refused_at_the_first_limit_it_passes(tmp_path):
    """0.065 N m for 40 s: the wheel reaches 628 rad/s after 15.5 s, the hub 10 deg/s only
    at 40 s: the wheel's limit is named, the hub's counted."""
    path = _run_file(tmp_path, {"type": "wheel_pulse", "torque_n_m": 0.065, "width_s": 40.0,
                                "start_s": 0.0}, duration_s=41.0,
                     limits={"max_angle_deg": 3600.0, "max_rate_deg_s": 9.0})
    line = _refused(tmp_path, path)
    assert "the wheel speed" in line and "reaction_wheel.max_speed_rad_s of 628" in line
    assert "from t = 15.4" in line and "(1 more limit passed too)" in line


def test_valve_couple_beyond_the_rate_limit_is_refused():
    """The valves' 0.1 N m couple for 30 s: 0.2 rad/s, 11.5 deg/s, past 10 deg/s."""
    run = run_from_dict({"name": "valves", "duration_s": 31.0, "actuators": ["thruster_valves"],
                         "controller": {"type": "hold"}})

    class Open:
        def step(self, state):
            from harness.state import RigCommand
            return RigCommand(valve_direction=1 if state.time_s < 30.0 else 0)

    with pytest.raises(BeyondLimit, match=r"the hub rate to 11\.\d+ deg/s, beyond the run's "
                       r"limits\.max_rate_deg_s of 10 deg/s from t = 26\.18 s"):
        check_run(run, Open())


@pytest.mark.parametrize("name", ["slew-rw", "free-decay", "thruster-pd-pwpf", "case-a"])
def test_built_in_runs_are_within_their_limits(name):
    rows = {r["quantity"]: r for r in check_run(load_run(name))}
    assert all(r["planned"] <= r["limit"] for r in rows.values())
    if name == "slew-rw":  # the plan is the slew itself: 20 deg
        assert rows["hub_angle"]["planned"] == pytest.approx(20.0, abs=0.05)
        assert 0 < rows["wheel_speed"]["planned"] < 628 and math.isfinite(
            rows["hub_rate"]["planned"])


def test_calibrate_beyond_the_angle_limit_is_refused_at_once(tmp_path):
    """`harness calibrate --angle-deg 400` excited for 110 s and then faulted at the hub's
    angle limit with a repr for an error line; now refused before the excitation."""
    out = tmp_path / "cal"
    r = harness_in_process("calibrate", "--angle-deg", "400", "--out", str(out))
    assert r.returncode == 2, r.stderr
    assert not out.exists()
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "{'" not in lines[0]
    assert "hub angle to 400 deg, beyond the run's limits.max_angle_deg of 180 deg" in lines[0]


def test_suite_test_beyond_a_limit_is_refused(tmp_path):
    path = _run_file(tmp_path, {"type": "wheel_pulse", "torque_n_m": 0.2, "width_s": 0.1})
    out = tmp_path / "suite"
    r = harness_in_process("test", str(path), "--out", str(out), "--workers", "1")
    assert r.returncode == 2, r.stdout + r.stderr
    assert not any(out.rglob("can.blf"))
    assert "reaction_wheel.max_torque_n_m" in r.stdout + r.stderr


# ------------------------------------------------------------- bounded and stoppable


class _Counting:
    def __init__(self) -> None:
        self.steps = 0

    def step(self, state):
        from harness.state import RigCommand

        self.steps += 1
        return RigCommand()


def test_a_thirty_day_runs_plan_steps_its_horizon_not_its_duration():
    from harness.core.limits import PLAN_HORIZON_S

    run = load_run("slew-rw", {"duration_s": 30 * 86400.0})
    counting = _Counting()
    check_run(run, counting)
    assert counting.steps == round(PLAN_HORIZON_S / run.dt_s) + 1


def test_a_stop_request_ends_the_plan_at_once_with_nothing_sent():
    from harness.core.limits import PLAN_STOP_EVERY, PlanInterrupted

    run = load_run("slew-rw", {"duration_s": 30 * 86400.0})
    counting = _Counting()
    with pytest.raises(PlanInterrupted, match="SIGTERM while the limit plan"):
        check_run(run, counting, should_stop=lambda: "SIGTERM")
    assert counting.steps == PLAN_STOP_EVERY


def test_sigterm_during_the_plan_exits_130_before_the_first_frame(tmp_path):
    """The process: a 30-day OPPF run's plan (seconds of CPU) reports its progress; the
    first SIGTERM then ends it at once (the run has not begun: nothing is open or sent),
    exit 130, no run folder."""
    import os
    import signal
    import subprocess
    import sys
    import time

    root = Path(__file__).resolve().parent.parent
    env = dict(os.environ, PYTHONPATH=str(root))
    proc = subprocess.Popen(
        [sys.executable, "-m", "harness", "run", "thruster-oppf", "--duration-s",
         str(30 * 86400), "--out", str(tmp_path / "logs")],
        stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True, env=env, cwd=tmp_path)
    assert proc.stderr is not None
    seen = ""
    deadline = time.monotonic() + 120
    while "checking the plan" not in seen and time.monotonic() < deadline:
        line = proc.stderr.readline()
        if not line:
            break
        seen += line
    assert "checking the plan" in seen, seen
    proc.send_signal(signal.SIGTERM)
    t0 = time.monotonic()
    rest = proc.communicate(timeout=60)[1]
    assert proc.returncode == 130, seen + rest
    assert time.monotonic() - t0 < 5.0
    assert "before the run began; nothing sent" in rest, rest
    assert not (tmp_path / "logs").exists() or not any((tmp_path / "logs").iterdir())


class _Locked:
    """A plugin-like controller holding a lock: deepcopy cannot copy it."""

    def __init__(self) -> None:
        import threading

        self.lock = threading.Lock()

    def step(self, state):
        from harness.state import RigCommand

        return RigCommand()


def test_a_controller_that_cannot_be_deep_copied_gets_a_fresh_one_for_its_plan():
    import copy

    from harness.core.session import _plan_copy

    run = load_run("slew-rw", {"duration_s": 2.0})
    locked = _Locked()
    with pytest.raises(TypeError):
        copy.deepcopy(locked)
    fresh = _plan_copy(run, locked)
    assert fresh is not locked and callable(fresh.step)
