"""The host's floor: a bare loop at the rate, with the harness's clock and real-time measures,
doing ``work_s`` of busy work a tick (what cyclictest measures, from Python)."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from harness.core.clock import RealTimeClock, RealTimeSetup
from harness.core.streaming import LatencyHistogram
from harness.realtime import DEFAULT_WORK_S


@dataclass
class Measures:
    """The real-time measures to request (the harness's defaults; see RealTimeSetup)."""

    sched_fifo: bool = True
    priority: int = 50
    pin_cpu: bool = True
    cpu: int = -1
    lock_memory: bool = True
    gc_freeze: bool = True


@dataclass
class FloorResult:
    rate_hz: float
    ticks: int = 0
    overruns: int = 0
    # runs of consecutive overrun ticks: one host stall of 100 ms makes about 50 overruns
    # (the ticks behind it run late), one episode
    overrun_episodes: int = 0
    lateness: LatencyHistogram = field(default_factory=LatencyHistogram)
    work: LatencyHistogram = field(default_factory=LatencyHistogram)
    measures: dict[str, list[str]] = field(default_factory=dict)
    wall_s: float = 0.0

    @property
    def overrun_percent(self) -> float:
        return 100.0 * self.overruns / self.ticks if self.ticks else 0.0

    def to_dict(self) -> dict[str, Any]:
        return {"rate_hz": self.rate_hz, "ticks": self.ticks, "overruns": self.overruns,
                "overrun_episodes": self.overrun_episodes,
                "overrun_percent": self.overrun_percent,
                "lateness_ms": self.lateness.percentiles_ms(),
                "work_ms": self.work.percentiles_ms(), "measures": self.measures,
                "wall_s": round(self.wall_s, 3)}


def run_floor(rate_hz: float, duration_s: float, work_s: float = DEFAULT_WORK_S,
              measures: Measures | None = None, result: FloorResult | None = None,
              should_stop: Callable[[], bool] | None = None) -> FloorResult:
    """Run the bare loop; ``result`` (filled in place) lets a caller accumulate blocks."""
    m = measures or Measures()
    dt = 1.0 / rate_hz
    res = result if result is not None else FloorResult(rate_hz)
    n = int(round(duration_s * rate_hz))
    perf = time.perf_counter
    clock = RealTimeClock(dt)
    setup = RealTimeSetup().apply(m.sched_fifo, m.priority, m.cpu, m.lock_memory,
                                  m.gc_freeze, m.pin_cpu)
    res.measures = setup.to_dict()
    wall0 = perf()
    try:
        clock.start()
        prev_over = False
        for tick in range(n):
            if should_stop is not None and should_stop():
                break
            lateness = clock.wait(tick)
            t0 = perf()
            while perf() - t0 < work_s:  # the tick's work (busy, like the harness's)
                pass
            res.work.add(perf() - t0)
            if clock.time_left(tick) < 0:
                res.overruns += 1
                if not prev_over:
                    res.overrun_episodes += 1
                prev_over = True
            else:
                prev_over = False
            res.lateness.add(lateness)
            res.ticks += 1
    finally:
        res.wall_s += perf() - wall0
        setup.restore()
    return res
