"""The rig process's SYNC timing names the harness's tick, past the SYNC counter's wrap.

A CANopen SYNC counts 1..240 and the sgsrt SYNC's counter has its signal's range; the rig's
late answers are matched against the loop's missing frames by tick (``attribute_missing``),
so the rig must unwrap the counter: before, on sgsrt-canopen every late answer after tick 239
was filed under tick mod 240 and its missing frames counted as the harness's own."""

from __future__ import annotations

import can
import pytest

from rig_models.rig_file import load_rig
from rig_models.virtual_rig import SyncTiming, VirtualRig


@pytest.mark.parametrize("rig_name", ["sgsrt-canopen", "sgsrt"])
def test_the_rig_counts_syncs_as_the_harness_ticks_past_the_counter_wrap(rig_name):
    cfg = load_rig(rig_name)
    bus = can.Bus(interface="virtual", channel=f"sync-index-{rig_name}")
    rig = VirtualRig(cfg, bus, 0.002)
    sync = rig.binding.sync
    ticks = list(range(700))  # past CANopen's 240; the sgsrt SYNC counts 32 bits
    seen = []
    for tick in ticks:
        rig.handle(can.Message(arbitration_id=sync.key[0], data=sync.encode(tick),
                               is_extended_id=sync.key[1]))
        seen.append(rig.sync_index)
    assert seen == ticks
    bus.shutdown()


def test_a_late_answer_is_kept_under_the_harness_tick():
    t = SyncTiming(late_s=1e-4)
    t.add(3188, 5e-4, 1e-4)
    assert t.to_dict()["late"][0][0] == 3188
