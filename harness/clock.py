"""The loop's two clocks behind one interface.

- ``LockstepClock``: simulated time; ``wait`` returns at once (each tick the virtual rig
  advances exactly one step), deterministic and as fast as the machine allows.
- ``RealTimeClock``: absolute deadlines t0 + k dt on the monotonic wall clock (no drift from
  accumulated sleeps). It sleeps until shortly before the deadline, then spins for at most
  ``spin_s`` (never a whole period, so SCHED_FIFO cannot starve the machine).
"""

from __future__ import annotations

import gc
import os
import sys
import time
from dataclasses import dataclass, field


class LockstepClock:
    realtime = False

    def __init__(self, dt_s: float) -> None:
        self.dt_s = dt_s

    def start(self) -> None:
        pass

    def wait(self, tick: int) -> float:
        """Block until tick's deadline; return the lateness in seconds (0 in lockstep)."""
        return 0.0

    def time_left(self, tick: int) -> float:
        return float("inf")


class RealTimeClock:
    realtime = True

    def __init__(self, dt_s: float, spin_s: float = 0.0003) -> None:
        self.dt_s = dt_s
        self.spin_s = min(spin_s, 0.25 * dt_s)
        self.t0 = 0.0

    def start(self) -> None:
        self.t0 = time.perf_counter() + self.dt_s

    def deadline(self, tick: int) -> float:
        return self.t0 + tick * self.dt_s

    def wait(self, tick: int) -> float:
        target = self.deadline(tick)
        now = time.perf_counter()
        if target - now > self.spin_s:
            time.sleep(target - now - self.spin_s)
        while (now := time.perf_counter()) < target:
            pass
        return now - target

    def time_left(self, tick: int) -> float:
        """Seconds until the next tick's deadline."""
        return self.deadline(tick + 1) - time.perf_counter()


@dataclass
class RealTimeSetup:
    """Opt-in real-time measures and what the OS granted (recorded in the summary)."""

    applied: list[str] = field(default_factory=list)
    refused: list[str] = field(default_factory=list)

    def apply(self, sched_fifo: bool, priority: int, cpu: int, lock_memory: bool,
              gc_freeze: bool) -> RealTimeSetup:
        if cpu >= 0:
            try:
                os.sched_setaffinity(0, {cpu})
                self.applied.append(f"cpu affinity {cpu}")
            except (AttributeError, OSError) as exc:
                self.refused.append(f"cpu affinity {cpu}: {exc}")
        if sched_fifo:
            try:
                os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
                self.applied.append(f"SCHED_FIFO priority {priority}")
            except (AttributeError, OSError) as exc:
                self.refused.append(f"SCHED_FIFO: {exc}")
        if lock_memory:
            try:
                import ctypes

                libc = ctypes.CDLL(None, use_errno=True)
                if libc.mlockall(3) != 0:  # MCL_CURRENT | MCL_FUTURE
                    raise OSError(ctypes.get_errno(), os.strerror(ctypes.get_errno()))
                self.applied.append("mlockall")
            except (AttributeError, OSError) as exc:
                self.refused.append(f"mlockall: {exc}")
        if gc_freeze:
            # collect now, freeze what exists, and keep the cyclic collector out of the loop
            # (its pauses were the largest source of lateness); re-enabled by restore()
            gc.collect()
            gc.freeze()
            gc.disable()
            self._gc_disabled = True
            self.applied.append("gc.freeze + gc.disable during the run")
        for line in self.refused:
            print(f"harness: real-time measure not granted: {line}", file=sys.stderr)
        return self

    def restore(self) -> None:
        if getattr(self, "_gc_disabled", False):
            gc.enable()
            gc.unfreeze()
            self._gc_disabled = False
