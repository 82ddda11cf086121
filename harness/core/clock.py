"""The loop's clocks behind one interface.

- ``LockstepClock``: simulated time; ``wait`` returns at once (each tick the virtual rig
  advances exactly one step), deterministic and as fast as the machine allows.
- ``RealTimeClock``: absolute deadlines t0 + k dt on the monotonic wall clock (no drift from
  accumulated sleeps). It sleeps until shortly before the deadline, then spins for at most
  ``spin_s`` (0.15 ms, never more than a quarter period, so SCHED_FIFO cannot starve the
  machine).
- ``KernelSyncClock``: real time paced by the SYNCs SocketCAN's broadcast manager sends
  (run file ``sync_source: kernel``): each tick starts when its SYNC is read back.
"""

from __future__ import annotations

import contextlib
import gc
import os
import sys
import time
from dataclasses import dataclass, field
from typing import Any

import can

BUS_LOCKSTEP_WAIT_S = 0.5
"""Lockstep over a bus (a virtual rig in its own process, ``harness virtual-rig --lockstep``):
how long a tick waits for the devices' answers at most. Time does not matter in lockstep, so
the wait is long (an emulated machine answers in milliseconds, not in microseconds); a
device that stays silent costs this much a tick until the monitor stops the run."""


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

    def __init__(self, dt_s: float, spin_s: float = 0.00015) -> None:
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


KERNEL_SYNC_WAIT_PERIODS = 20
"""A kernel-sent SYNC that does not come within this many periods (and at least 1 s) stops
the run: the broadcast manager stopped or the interface went down."""


class KernelSyncLost(RuntimeError):
    pass


class KernelSyncClock:
    """Real time paced by SYNCs the kernel sends (SocketCAN's broadcast manager): ``wait``
    returns when the next SYNC is on the bus (its time stamp read back), and the tick's
    deadline is one period after that SYNC. The lateness is how long after the SYNC's
    time stamp the loop started its tick."""

    realtime = True

    def __init__(self, dt_s: float, interface: Any) -> None:
        self.dt_s = dt_s
        self.interface = interface
        self._sync_perf = 0.0

    def start(self) -> None:
        try:
            self.interface.start_kernel_sync(self.dt_s)
        except (OSError, can.CanError) as exc:
            raise KernelSyncLost(f"the kernel's broadcast manager did not start SYNC: "
                                 f"{exc}") from exc

    def wait(self, tick: int) -> float:
        ts = self.interface.wait_kernel_sync(
            tick, max(1.0, KERNEL_SYNC_WAIT_PERIODS * self.dt_s))
        if ts is None:
            raise KernelSyncLost(
                f"no SYNC from the kernel's broadcast manager within "
                f"{max(1.0, KERNEL_SYNC_WAIT_PERIODS * self.dt_s):g} s (tick {tick})")
        late = max(0.0, time.time() - ts)
        self._sync_perf = time.perf_counter() - late
        return late

    def time_left(self, tick: int) -> float:
        """Seconds until the next SYNC is due (one period after this tick's)."""
        return self._sync_perf + self.dt_s - time.perf_counter()


def allowed_cpus() -> list[int]:
    try:
        return sorted(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return list(range(os.cpu_count() or 1))


def choose_cpus(cpu: int = -1) -> tuple[int, int | None]:
    """(the loop's CPU, the rig process's CPU or None): ``cpu`` >= 0 is the loop's; -1 picks
    the last CPU this process may use for the loop and the one before it for the rig (on a
    one-CPU machine the rig gets none)."""
    cpus = allowed_cpus()
    loop = cpu if cpu >= 0 else cpus[-1]
    others = [c for c in cpus if c != loop]
    return loop, (others[-1] if others else None)


@dataclass
class RealTimeSetup:
    """The real-time measures of a run and what the OS granted (recorded in the summary).

    Requested by default in real-time runs (run file ``realtime:`` keys opt out):
    CPU affinity (the loop on one CPU, the rig process on another), SCHED_FIFO at
    ``priority`` (50: above every normal task, below the kernel's own real-time threads
    at 99; the loop never spins a whole period, and the kernel's RT throttling,
    ``kernel.sched_rt_runtime_us``, leaves 5 % of each second to other tasks anyway),
    mlockall (no page faults on the loop's memory) and the cyclic garbage collector off
    (``gc.freeze`` + ``gc.disable``; the loop collects the young generations itself in its
    slack). A measure the OS refuses is a warning, not an error: the run goes on without it.
    ``restore()`` undoes every granted measure (the process may run more than one run)."""

    applied: list[str] = field(default_factory=list)
    refused: list[str] = field(default_factory=list)
    requested: list[str] = field(default_factory=list)

    def apply(self, sched_fifo: bool, priority: int, cpu: int, lock_memory: bool,
              gc_freeze: bool, pin_cpu: bool = True) -> RealTimeSetup:
        self._saved_affinity = None
        self._saved_sched = None
        if pin_cpu and cpu >= -1:
            cpu = choose_cpus(cpu)[0]
            self.requested.append(f"cpu affinity {cpu}")
            try:
                saved = os.sched_getaffinity(0)
                os.sched_setaffinity(0, {cpu})
                self._saved_affinity = saved
                self.applied.append(f"cpu affinity {cpu}")
            except (AttributeError, OSError) as exc:
                self.refused.append(f"cpu affinity {cpu}: {exc}")
        if sched_fifo:
            self.requested.append(f"SCHED_FIFO priority {priority}")
            try:
                saved_sched = (os.sched_getscheduler(0), os.sched_getparam(0))
                os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
                self._saved_sched = saved_sched
                self.applied.append(f"SCHED_FIFO priority {priority}")
            except (AttributeError, OSError) as exc:
                self.refused.append(f"SCHED_FIFO priority {priority}: {exc}")
        if lock_memory:
            self.requested.append("mlockall")
            try:
                import ctypes

                libc = ctypes.CDLL(None, use_errno=True)
                # MCL_CURRENT | MCL_FUTURE | MCL_ONFAULT: a page stays resident once
                # touched. Without ONFAULT every mapping is faulted in whole, reserved
                # thread stacks and allocator arenas included: resident memory grew by
                # 0.5 GB per run (Rerun's threads) in the benchmark.
                flags = "MCL_CURRENT|MCL_FUTURE|MCL_ONFAULT"
                if libc.mlockall(7) != 0:
                    if ctypes.get_errno() != 22:  # EINVAL: a kernel before 4.4
                        raise OSError(ctypes.get_errno(), os.strerror(ctypes.get_errno()))
                    flags = "MCL_CURRENT|MCL_FUTURE"
                    if libc.mlockall(3) != 0:
                        raise OSError(ctypes.get_errno(), os.strerror(ctypes.get_errno()))
                self._libc = libc
                self.applied.append(f"mlockall ({flags})")
            except (AttributeError, OSError) as exc:
                self.refused.append(f"mlockall: {exc}")
        if gc_freeze:
            # collect now, freeze what exists, and keep the cyclic collector out of the loop
            # (its pauses were the largest source of lateness); re-enabled by restore()
            self.requested.append("gc.freeze + gc.disable during the run")
            gc.collect()
            gc.freeze()
            gc.disable()
            self._gc_disabled = True
            self.applied.append("gc.freeze + gc.disable during the run")
        for line in self.refused:
            print(f"harness: WARNING: real-time measure not granted: {line}", file=sys.stderr)
        return self

    @property
    def gc_disabled(self) -> bool:
        return getattr(self, "_gc_disabled", False)

    def to_dict(self) -> dict[str, list[str]]:
        return {"requested": list(self.requested), "applied": list(self.applied),
                "refused": list(self.refused)}

    def restore(self) -> None:
        if getattr(self, "_gc_disabled", False):
            gc.enable()
            gc.unfreeze()
            self._gc_disabled = False
        saved = getattr(self, "_saved_sched", None)
        if saved is not None:
            self._saved_sched = None
            with contextlib.suppress(OSError):
                os.sched_setscheduler(0, saved[0], saved[1])
        libc = getattr(self, "_libc", None)
        if libc is not None:
            self._libc = None
            libc.munlockall()
        aff = getattr(self, "_saved_affinity", None)
        if aff is not None:
            self._saved_affinity = None
            with contextlib.suppress(OSError):
                os.sched_setaffinity(0, aff)
