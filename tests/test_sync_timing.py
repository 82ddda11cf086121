"""The rig process's SYNC timing (bounded memory, exact counts) and the split of the
telemetry frames missing in ticks the loop held into the host's and the harness's."""

from __future__ import annotations

import pytest

from harness.core.loop import RESERVE_FRACTION
from harness.core.session import (
    RIG_HELD_FRACTION,
    STALL_OP_FACTOR,
    STALL_OP_MIN_FRACTION,
    attribute_missing,
)
from rig_models.virtual_rig import SyncTiming


def test_sync_timing_percentiles_and_late_list():
    t = SyncTiming(late_s=0.5e-3, max_late=3)
    for tick in range(1000):
        t.add(tick, 50e-6, 100e-6)
    for tick in range(1000, 1005):  # five SYNCs the host kept back 3 ms
        t.add(tick, 3e-3, 100e-6)
    t.add(1005, 50e-6, 0.6e-3)  # woken in time, answered late
    d = t.to_dict()
    assert d["syncs"] == 1006
    assert d["wake_ms"]["p50"] == pytest.approx(0.06, abs=0.011)  # 10 us bins
    assert d["wake_ms"]["max"] == pytest.approx(3.0)
    assert d["work_ms"]["max"] == pytest.approx(0.6)
    assert d["late_syncs"] == 6  # exact count ...
    assert [row[0] for row in d["late"]] == [1000, 1001, 1002]  # ... bounded list
    assert d["late"][0][:3] == [1000, 3.0, 0.1] and d["late"][0][3] < 0  # CPU ms unknown


def test_sync_timing_keeps_the_longest_operation_of_late_answers():
    t = SyncTiming(late_s=0.5e-3)
    for tick in range(990):
        t.add(tick, 50e-6, 100e-6, 100e-6, 30e-6, "physics step", 0, 0)
    for tick in range(990, 1000):
        t.add(tick, 50e-6, 100e-6, 100e-6, 60e-6, "send HUB_TLM", 0, 0)
    t.add(1000, 50e-6, 1.2e-3, 1.2e-3, 1.1e-3, "physics step", 0, 0)
    d = t.to_dict()
    assert d["longest_op_ms"]["p50"] == pytest.approx(0.04, abs=0.011)
    assert d["longest_op_ms"]["max"] == pytest.approx(1.1)
    assert d["late"] == [[1000, 0.05, 1.2, 1.2, 1.1, "physics step", 0, 0]]


def test_sync_timing_memory_does_not_grow():
    t = SyncTiming(late_s=0.0, max_late=10)
    size = t.wake.nbytes + t.work.nbytes
    for tick in range(50_000):
        t.add(tick, 1.0, 1.0)  # every one late, beyond the bins
    assert len(t.late) == 10 and t.late_count == 50_000
    assert t.wake.nbytes + t.work.nbytes == size
    assert t.to_dict()["wake_ms"]["max"] == pytest.approx(1000.0)


def test_attribute_missing_splits_host_from_harness():
    dt = 2e-3
    held = RIG_HELD_FRACTION * dt * 1e3  # ms of host delay (loop lateness + rig wake-up)
    window = (1 - RESERVE_FRACTION) * dt * 1e3  # ms after the deadline the loop waits
    miss_ticks = [(10, 2, 0.0), (20, 1, 0.0), (30, 3, 0.0), (40, 1, 0.4e-3),
                  (50, 4, 0.7e-3)]
    late = [[10, held + 0.5, 0.1],          # the host woke the rig late: the host's
            [20, 0.1, window],              # woken in time, answered after the window
            [40, 0.1, window - 0.3],        # in time for an on-time tick, not for this one
            [50, held - 0.6, 0.1],          # loop 0.7 ms late + rig 0.4 ms: the host's
            [99, 40.0, 0.1]]                # a late SYNC with nothing missing
    out = attribute_missing(miss_ticks, 11, late, dt)
    assert out["missing_in_ticks_host_delayed"] == 6  # ticks 10 and 50
    assert out["missing_in_ticks_held_by_both"] == 5  # 20, 30 (sent in time), 40
    assert out["missing_rig_answered_after_window"] == 2  # ticks 20 and 40
    assert [row[0] for row in out["rig_answers_after_window_ms"]] == [20, 40]
    # no late SYNC at all: every miss is the harness's, sent in time and not read
    none = attribute_missing(miss_ticks[:4], 7, [], dt)
    assert none["missing_in_ticks_held_by_both"] == 7
    assert none["missing_rig_answered_after_window"] == 0


def test_a_rig_answer_the_host_preempted_is_the_hosts():
    dt = 2e-3
    window = (1 - RESERVE_FRACTION) * dt * 1e3
    miss_ticks = [(10, 3, 0.0), (20, 2, 0.0)]
    late = [[10, 0.09, window, 0.08],     # 1.4 ms of wall time, the thread ran 0.08 ms
            [20, 0.09, window, window]]   # ran the whole time: the rig's own slowness
    out = attribute_missing(miss_ticks, 5, late, dt)
    assert out["missing_in_ticks_rig_preempted"] == 3
    assert out["missing_in_ticks_host_delayed"] == 3
    assert out["missing_in_ticks_held_by_both"] == 2
    assert out["missing_rig_answered_after_window"] == 2
    assert [r[0] for r in out["rig_answers_after_window_ms"]] == [10, 20]


def test_a_fixed_operation_stalled_under_a_running_thread_is_the_hosts():
    """The thread ran the whole time (not preempted), but one operation whose 99th
    percentile is 0.05 ms took 1.1 ms, with no page fault and no context switch: the CPU
    stopped under it (the hypervisor). A page fault, a context switch or an operation only
    a few times its usual cost keeps it the harness's."""
    dt = 2e-3
    window = (1 - RESERVE_FRACTION) * dt * 1e3
    p99 = 0.05e-3
    big = max(STALL_OP_FACTOR * p99, STALL_OP_MIN_FRACTION * dt) * 1e3 + 0.1  # ms
    miss_ticks = [(10, 4, 0.0), (20, 2, 0.0), (30, 1, 0.0), (40, 3, 0.0), (50, 1, 0.0)]
    late = [[10, 0.1, window, window, big, "physics step", 0, 0],       # stalled: host's
            [20, 0.1, window, window, big, "send HUB_TLM", 3, 0],       # it page-faulted
            [30, 0.1, window, window, big, "physics step", 0, 1],       # it switched
            [40, 0.1, window, window, 0.1, "send ACCEL_TLM", 0, 0],     # all ops short
            [50, 0.1, window, window, big, "physics step", -1, -1]]     # not known
    out = attribute_missing(miss_ticks, 11, late, dt, op_p99_s=p99)
    assert out["missing_in_ticks_rig_stalled"] == 4
    assert out["missing_in_ticks_host_delayed"] == 4
    assert out["missing_in_ticks_held_by_both"] == 7
    assert [r[-1] for r in out["rig_answers_after_window_ms"]] == [
        "stalled", "harness", "harness", "harness", "harness"]
    # a run whose operations are all slow (p99 as long as the stall) has no stall
    slow = attribute_missing(miss_ticks[:1], 4, late[:1], dt, op_p99_s=big * 1e-3)
    assert slow["missing_in_ticks_rig_stalled"] == 0


def test_the_rig_process_reports_its_longest_operation(tmp_path):
    """A real rig process over the Unix socket: every answer's longest operation is timed
    and named; the summary carries its percentiles."""
    from harness.core.runs import load_run
    from harness.core.session import execute_run

    run = load_run("slew-rw", {"duration_s": 1.0, "monitor": {"realtime_grace_s": 1.0}})
    res = execute_run(run, out_dir=tmp_path, clock="realtime", show_progress=False)
    timing = res.summary["virtual_rig_timing"]
    op = timing["longest_op_ms"]
    assert 0.0 < op["p50"] <= op["p99"] <= op["max"] <= timing["work_ms"]["max"] + 0.011
    assert "missing_in_ticks_rig_stalled" in res.summary["frames"]
