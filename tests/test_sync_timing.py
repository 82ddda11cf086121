"""The rig process's SYNC timing (bounded memory, exact counts) and the split of the
telemetry frames missing in ticks the loop held into the host's and the harness's."""

from __future__ import annotations

import pytest

from harness.core.loop import RESERVE_FRACTION
from harness.core.session import RIG_HELD_FRACTION, attribute_missing
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
