"""tools/trace_rig/trace.py's reading of a kernel trace: on the excerpt docs/realtime.md
quotes (the rig's answer to SYNC 337, 5.139 ms), the CPU's periodic tick inside the answer
came about 1.03 ms after it was due; an answer with a timer on time is not called a stall."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

spec = importlib.util.spec_from_file_location(
    "trace_rig", Path(__file__).resolve().parent.parent / "tools" / "trace_rig" / "trace.py")
trace = importlib.util.module_from_spec(spec)
spec.loader.exec_module(trace)

WAKE = "hrtimer_expire_entry: hrtimer=000000003db8b2fe function=hrtimer_wakeup now={}"
TICK = "hrtimer_expire_entry: hrtimer=00000000e13a3f48 function=tick_nohz_handler now={}"
EXCERPT = f"""\
          python-19904   [000] d.h.. 23715.735753: {TICK.format(23715744007492)}
          python-19904   [000] ...1. 23715.735809: tracing_mark_write: RIG E 333 0.073
          python-19904   [000] ...1. 23715.737736: tracing_mark_write: RIG S
          python-19904   [000] ...1. 23715.737792: tracing_mark_write: RIG E 334 0.052
          python-19904   [000] d.h.. 23715.739753: {TICK.format(23715748007848)}
          python-19904   [000] ...1. 23715.741739: tracing_mark_write: RIG S
          python-18057   [001] d..2. 23715.741740: sched_switch: prev_comm=python
          python-19904   [000] ...1. 23715.741791: tracing_mark_write: RIG E 336 0.049
          python-19904   [000] d.h.. 23715.743753: {TICK.format(23715752008054)}
          python-19904   [000] ...1. 23715.743779: tracing_mark_write: RIG S
          python-19904   [000] d.h.. 23715.748788: {WAKE.format(23715757042213)}
          python-19904   [000] d.h.. 23715.748809: {TICK.format(23715757042213)}
          python-19904   [000] d..3. 23715.748886: sched_waking: comm=python pid=18057
          python-19904   [000] ...1. 23715.748925: tracing_mark_write: RIG E 337 5.139
""".splitlines()


def test_the_stalled_answer_shows_its_tick_late():
    r = trace.analyse(EXCERPT, 19904, 337)
    assert r["cpu"] == 0
    assert r["end_s"] - r["start_s"] == pytest.approx(5.146e-3, abs=1e-6)
    ticks = [ms for fn, ms in r["timers"] if fn == "tick_nohz_handler"]
    assert ticks == [pytest.approx(1.034, abs=0.001)]
    assert all(e["cpu"] == "000" for e in r["events"])  # CPU 1's events are left out
    assert r["events"][0]["what"].endswith("RIG S") and "RIG E 337" in r["events"][-1]["what"]


def test_a_timer_on_time_is_not_late():
    lines = EXCERPT[:9] + [
        "          python-19904   [000] ...1. 23715.743779: tracing_mark_write: RIG S",
        "          python-19904   [000] d.h.. 23715.747760: " + TICK.format(23715756008100),
        "          python-19904   [000] ...1. 23715.747900: tracing_mark_write: RIG E 337 4.1"]
    r = trace.analyse(lines, 19904, 337)
    assert [round(ms, 3) for _, ms in r["timers"]] == [0.0]
