"""One run from start to finish: checks, bus, virtual rig, loop, recording, summary.

Every run writes ``<out>/<UTC time>-<run name>/`` with ``run.rrd``, ``can.blf`` (raw CAN),
``config.yaml`` (the resolved run and rig) and ``summary.json``. The recording and the CAN
log are closed on every exit path.
"""

from __future__ import annotations

import contextlib
import copy
import datetime as dt
import json
import math
import shutil
import sys
import threading
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from drivers.dbc import load_protocol
from harness.bus import BusSpec, open_bus, parse_bus
from harness.bus.load import binding_bus_load, compute_bus_load
from harness.bus.rig_interface import RigInterface
from harness.bus.rig_process import EXIT_WAIT_S, RigProcess, RigProcessError, RigProcessExited
from harness.core.clock import (
    KernelSyncClock,
    LockstepClock,
    RealTimeClock,
    RealTimeSetup,
    choose_cpus,
)
from harness.core.limits import BeyondLimit, check_run
from harness.core.loop import (
    CHANNELS,
    HELD_FRACTION,
    RESERVE_FRACTION,
    ControllerError,
    LoopStats,
    run_loop,
)
from harness.core.monitor import FaultMonitor, MonitorWarning
from harness.core.paths import safe_child, safe_name
from harness.core.periodic import steady_state_amplitude
from harness.core.runs import (
    RunConfig,
    build_controller,
    controller_summary,
    controller_type,
)
from harness.core.streaming import RunningSummary
from harness.core.wire_timing import WireTiming
from harness.record.can_log import CanLog
from harness.record.output import (
    OutputError,
    SpaceGuard,
    as_output_error,
    is_output_failure,
    write_text_atomic,
)
from harness.record.reader import RecordedColumns
from harness.record.recording import Recorder
from harness.review.annotations import ReviewAnnotator
from harness.review.bus import write_bus
from harness.review.events import log_event
from harness.review.layouts import PlotStats, layout_for_run, write_layout_file
from harness.sequences.runner import SequenceRunner
from rig_models.faults import FaultSpec
from rig_models.rig_file import load_rig, rig_identity
from rig_models.schema import ConfigError
from rig_models.virtual_rig import VirtualRig

COMMAND_FRAMES = {
    "reaction_wheel": "WHEEL_CMD",
    "thruster_valves": "VALVE_CMD",
    "piezo_amplifier": "PIEZO_CMD",
    "disturbance_rotor": "ROTOR_CMD",
}


class RunRefused(RuntimeError):
    """The run was refused before anything was sent (bus load, limits, a bus that does not
    open): no run directory is left behind."""


@dataclass
class RunResult:
    run_dir: Path
    summary: dict[str, Any]
    stats: LoopStats
    recorder: Recorder
    virtual_rig: VirtualRig | None

    def columns(self) -> RecordedColumns:
        """The whole run's channels, read back from run.rrd (the recorder keeps only a
        tail in memory)."""
        cached = getattr(self, "_columns", None)
        if cached is None:
            cached = RecordedColumns(self.run_dir / "run.rrd")
            object.__setattr__(self, "_columns", cached)
        return cached


def bus_load_of(run: RunConfig):  # noqa: ANN201 - BusLoad
    if run.rig.binding.is_sgsrt():
        return compute_bus_load(
            load_protocol(), run.data["rate_hz"], run.rig.data["bus"]["sync_divider"],
            [COMMAND_FRAMES[a] for a in run.actuators], run.data["heartbeat_hz"],
            run.rig.data["bus"]["bitrate_bit_s"])
    return binding_bus_load(
        run.rig.binding, run.data["rate_hz"], run.rig.data["bus"]["sync_divider"],
        run.actuators, run.data["heartbeat_hz"], run.rig.data["bus"]["bitrate_bit_s"])


def refuse_beyond_limits(run: RunConfig, controller: object,
                         should_stop: Callable[[], str | None] | None = None,
                         show_progress: bool = True) -> list[dict[str, Any]]:
    """The run's planned motion against its limits and the rig's (``harness.core.limits``),
    on a copy of its controller; RunRefused (a sentence naming the limit) before anything is
    sent, the checked rows otherwise; ``PlanInterrupted`` when ``should_stop`` asks."""
    try:
        planned = _plan_copy(run, controller)
        return check_run(run, planned, should_stop,
                         progress=_plan_progress if show_progress else None)
    except BeyondLimit as exc:
        raise RunRefused(str(exc)) from exc


def _plan_progress(fraction: float, tick: int, n_ticks: int) -> None:
    print(f"harness: checking the plan against the limits: {100 * fraction:.0f} % "
          f"(tick {tick} of {n_ticks}; Ctrl-C stops it, nothing sent)", file=sys.stderr,
          flush=True)


def _plan_copy(run: RunConfig, controller: object) -> object:
    """A second controller for the limit plan: a deep copy of the run's, or, when that
    cannot be copied (a plugin keeping the rig, a lock, a file), one built afresh as the
    run builds it; RunRefused naming the controller when neither can be had."""
    try:
        return copy.deepcopy(controller)
    except Exception as exc:  # noqa: BLE001 - any copy failure: build a fresh one instead
        why = f"{type(exc).__name__}: {exc}"
    try:
        return build_controller(run)
    except ConfigError as exc:
        named = controller_type(run.controller["type"]).describe()
        raise RunRefused(f"{run.source}: controller: {named} could not be copied for the "
                         f"limit plan ({why}) nor built a second time ({exc})") from None


def make_run_dir(out: Path, name: str) -> Path:
    """``<out>/<UTC time>-<safe_name(name)>``: a run's name never leaves ``out``."""
    stamp = dt.datetime.now(dt.UTC).strftime("%Y%m%dT%H%M%S.%fZ")
    run_dir = safe_child(out, f"{stamp}-{safe_name(name)}")
    run_dir.mkdir(parents=True, exist_ok=False)
    return run_dir


def _progress(tick: int, n: int) -> None:
    end = "" if sys.stderr.isatty() else "\n"
    if end or tick % max(1, n // 4) < max(1, n // 20):
        print(f"\rharness: tick {tick}/{n} ({100 * tick / n:.0f} %)", end=end, file=sys.stderr,
              flush=True)


def execute_run(
    run: RunConfig,
    out_dir: Path = Path("logs"),
    bus: str | None = None,
    clock: str | None = None,
    live_view_url: str | None = None,
    show_progress: bool = True,
    dry_run: bool = False,
    faults: list[FaultSpec] | None = None,
    should_stop: Callable[[], str | None] | None = None,
    rig_process: bool = False,
    device_rig: Any = None,
    truth_tail_s: float = 0.0,
) -> RunResult:
    """Run ``run`` and record it. ``device_rig``: the rig file whose devices and physics the
    in-process virtual rig emulates instead of the run's own (a lab's devices as they are,
    against a rig file under test: ``harness commission --devices-rig``). ``truth_tail_s``:
    the in-process virtual rig keeps its last this many seconds of noise-free truth
    (``VirtualRig.record_truth_tail``; harness calibrate's residuals)."""
    if not run.rig.binding.bound:
        raise RunRefused(f"{run.source}: rig {run.rig.name}: every device is bound "
                         "'binding: none': nothing on the bus to run against (devices: in the "
                         "rig file)")
    spec = parse_bus(bus or run.data["bus"])
    clock_name = clock or run.data["clock"]
    if device_rig is None and run.data.get("devices_rig"):
        try:
            device_rig = load_rig(run.data["devices_rig"])
        except ConfigError as exc:
            raise RunRefused(f"{run.source}: devices_rig: {exc}") from None
    if rig_process and not (spec.in_process and clock_name == "realtime"):
        raise RunRefused(f"{run.source}: --rig-process runs the virtual rig as its own "
                         f"process for a real-time run on the virtual bus; got bus {spec} "
                         f"and clock {clock_name}")
    if run.data["sync_source"] == "kernel":
        refuse_kernel_sync(run, spec, clock_name)
    load = bus_load_of(run)
    if load.percent > run.data["max_bus_load_percent"]:
        worst = max(load.rows, key=lambda r: r[2])
        raise RunRefused(
            f"{run.source}: bus load {load.percent:.1f} % exceeds max_bus_load_percent "
            f"{run.data['max_bus_load_percent']:g} % at {run.data['rate_hz']:g} Hz "
            f"({load.frames_per_s:.0f} frames/s; largest: {worst[0]} {worst[2] / 1e3:.0f} kbit/s)"
            "; lower rate_hz or raise the devices' sync_divider")
    controller = build_controller(run)
    if spec.in_process:
        from rig_models.virtual_rig import check_virtual_rig

        try:
            # a device it cannot be, a fault it cannot inject: refused, nothing sent
            check_virtual_rig(run.rig, run.faults + list(faults or []))
        except ConfigError as exc:
            raise RunRefused(str(exc)) from None
    if show_progress:  # what is wrong in the device files but not in what the rig binds
        notes = run.rig.binding.warnings
        for line in notes[:5]:
            print(f"harness: warning: {line}", file=sys.stderr)
        if len(notes) > 5:
            print(f"harness: warning: ... and {len(notes) - 5} more such messages",
                  file=sys.stderr)
    if not dry_run:  # a dry run sends no command: nothing moves
        refuse_beyond_limits(run, controller, should_stop, show_progress)
    # from here on something is opened and sent: a first Ctrl-C/SIGTERM stops at a tick
    # (harness.core.interrupts); until here (the controller's factory, the limit plan) it
    # ended the command at once, nothing sent
    begin = getattr(should_stop, "begin", None)
    if callable(begin):
        begin()
    SpaceGuard(out_dir).check()  # a folder already (nearly) full: refused, nothing sent
    try:
        run_dir = make_run_dir(out_dir, run.name)
    except OSError as exc:
        if is_output_failure(exc):
            raise as_output_error(out_dir, exc) from exc
        raise
    write_text_atomic(run_dir / "config.yaml", yaml.safe_dump(run.resolved(), sort_keys=False))
    rig_mode = virtual_rig_mode(run, spec, clock_name, rig_process,
                                run.faults + list(faults or []))
    if device_rig is not None and rig_mode not in ("lockstep", "thread"):
        shutil.rmtree(run_dir, ignore_errors=True)
        raise RunRefused(f"{run.source}: the devices of another rig file are emulated by the "
                         f"in-process virtual rig only (bus {spec}, {rig_mode})")
    with contextlib.ExitStack() as stack:
        rig_measures: dict[str, list[str]] = {}
        rig_exited: Callable[[float], str | None] | None = None
        if rig_mode.startswith("process"):
            rt = run.data["realtime"]
            rig_cpu = (rt["rig_cpu"] if rt["rig_cpu"] >= 0 else choose_cpus(rt["cpu"])[1]) \
                if rt["pin_cpu"] else None
            proc = RigProcess(run.rig, run.data["rate_hz"], run_dir,
                              run.faults + list(faults or []),
                              lifetime_s=run.data["duration_s"] + 60.0,
                              transport="tcp" if rig_mode == "process-tcp" else "unix",
                              cpu=rig_cpu,
                              priority=rt["rig_priority"] if rt["sched_fifo"] else 0,
                              realtime=rt["lock_memory"] or rt["gc_freeze"])
            try:
                where = stack.enter_context(proc)
            except RigProcessError as exc:
                raise _rig_did_not_start(run, proc, run_dir, exc) from exc
            rig_measures = proc.measures
            rig_exited = proc.exited
            spec = parse_bus(where)
            faults = []
        try:
            result = _execute(run, spec, clock_name, controller, load, run_dir, live_view_url,
                              show_progress, dry_run, faults, should_stop, device_rig,
                              truth_tail_s, rig_exited)
        except RunRefused:
            # nothing was sent and the folder holds only config.yaml: left behind, it would
            # read as a run killed on the way ('harness logs --failed')
            shutil.rmtree(run_dir, ignore_errors=True)
            raise
        except Exception as exc:  # the run raised: its directory can still be judged (ERROR)
            exc.run_dir = run_dir  # type: ignore[attr-defined]
            raise
        result.summary["virtual_rig_mode"] = rig_mode
        if rig_mode.startswith("process"):
            proc.stop()  # its SYNC timing and its own measures are known once it stops
            m = result.summary["realtime_measures"]
            for key in ("requested", "applied", "refused"):
                m[key] += rig_measures[key]
            if proc.timing is not None:
                timing = {k: v for k, v in proc.timing.items() if k not in ("late",
                                                                             "measures")}
                timing["held_fraction_of_period"] = RIG_HELD_FRACTION
                timing["syncs_not_held"] = sum(
                    1 for row in proc.timing.get("late", [])
                    if row[1] * 1e-3 >= RIG_HELD_FRACTION * run.dt_s)
                split = attribute_missing(
                    result.stats.missing_on_time_ticks, result.stats.missing_frames_on_time,
                    proc.timing.get("late", []), run.dt_s,
                    op_p99_s=(proc.timing.get("longest_op_ms") or {}).get("p99", 0.0) * 1e-3)
                timing["answers_after_window_ms"] = split.pop("rig_answers_after_window_ms")
                result.summary["virtual_rig_timing"] = timing
                result.summary["frames"].update(split)
            write_text_atomic(run_dir / "summary.json", json.dumps(result.summary, indent=2))
        return result


RIG_HELD_FRACTION = HELD_FRACTION
"""The host held a tick for the loop and the rig process when its delays of the tick (the
loop's lateness plus the rig's wake-up after the SYNC) stayed below this fraction of the
period: the loop's own rule for its lateness (``harness.core.loop.HELD_FRACTION``)."""


def attribute_missing(miss_ticks: list[tuple[int, int, float]], missing_on_time: int,
                      late_syncs: list[list[Any]], dt_s: float,
                      op_p99_s: float = 0.0) -> dict[str, Any]:
    """Split the telemetry frames missing in ticks the loop held (``miss_ticks``: tick,
    frames, the tick's lateness s) by the rig process's SYNC timing (``late_syncs``: tick,
    wake ms, work ms, work's CPU ms, longest operation ms, its name, page faults, context
    switches, for the SYNCs it answered late; older rows have the first three or four).

    A frame's way is: the loop wakes (its lateness), sends the SYNC, the rig process wakes
    (its wake-up), computes and sends (its work), the loop reads. The first two are the
    host's delays, what a floor loop measures on each CPU; the work is the harness's,
    unless the host took the CPU away during it. So:

    - ``missing_in_ticks_host_delayed``: the host's, when
      - the host's delays of the tick (the loop's lateness plus the rig's wake-up) reached
        ``RIG_HELD_FRACTION`` of a period, the rule the loop applies to its own lateness;
      - or the rig answered after the loop stopped waiting and
        - its thread ran less than half of its answer's wall time (the guest's scheduler
          gave the CPU to something else: ``missing_in_ticks_rig_preempted``);
        - or one fixed operation of the answer (a physics step, one frame's encode and
          send) took ``STALL_OP_FACTOR`` times the run's 99th percentile of the longest
          operation (``op_p99_s``) and at least ``STALL_OP_MIN_FRACTION`` of a period, with
          no page fault and no context switch of the thread (the CPU stopped under a running
          thread: on a VM, the hypervisor, which the guest counts as the thread's time;
          ``missing_in_ticks_rig_stalled``);
    - ``missing_in_ticks_held_by_both``: the rest, the harness's own; of those
      ``missing_rig_answered_after_window`` were sent by the rig after the loop stopped
      waiting, the others were sent in time and still not read in the tick (the transport
      or the loop). ``rig_answers_after_window_ms`` lists the first late answers' rows
      (the host's too), with the verdict of this rule as a last column.

    Frames beyond the ticks kept by tick (``MAX_MISS_TICKS``) or the rig's late list are
    counted as the harness's."""
    late = {int(row[0]): row for row in late_syncs}
    stall_s = max(STALL_OP_FACTOR * op_p99_s, STALL_OP_MIN_FRACTION * dt_s)
    host = preempted = stalled = answered_late = 0
    examples: list[list[Any]] = []
    for tick, n, lateness in miss_ticks:
        row = late.get(tick)
        if row is None:
            continue  # the rig answered in time: the frames were lost after it sent them
        wake, work = row[1] * 1e-3, row[2] * 1e-3
        ran = row[3] * 1e-3 if len(row) > 3 else -1.0
        op_s = row[4] * 1e-3 if len(row) > 4 else 0.0
        faults = row[6] if len(row) > 6 else -1
        switches = row[7] if len(row) > 7 else -1
        if lateness + wake >= RIG_HELD_FRACTION * dt_s:
            host += n
            continue
        if wake + work < (1.0 - RESERVE_FRACTION) * dt_s - lateness:
            continue
        if 0.0 <= ran < 0.5 * work:
            host += n
            preempted += n
            why = "preempted"
        elif op_s >= stall_s and faults == 0 and switches == 0:
            host += n
            stalled += n
            why = "stalled"
        else:
            answered_late += n
            why = "harness"
        if len(examples) < 10:
            examples.append([*row, why])
    return {"missing_in_ticks_host_delayed": host,
            "missing_in_ticks_rig_preempted": preempted,
            "missing_in_ticks_rig_stalled": stalled,
            "missing_in_ticks_held_by_both": missing_on_time - host,
            "missing_rig_answered_after_window": answered_late,
            "rig_answers_after_window_ms": examples}


STALL_OP_FACTOR = 10.0
"""A fixed operation of the rig's answer that took this many times its 99th percentile (and
``STALL_OP_MIN_FRACTION`` of a period), the thread neither faulting nor switching, stalled
on a CPU taken from under it (``attribute_missing``)."""

STALL_OP_MIN_FRACTION = 0.1
"""... and at least this fraction of the period (0.2 ms at 500 Hz), so that a run whose
operations are all fast does not call a 0.1 ms hiccup a stall."""


def _rig_did_not_start(run: RunConfig, proc: RigProcess, run_dir: Path,
                       exc: RigProcessError) -> RunRefused:
    """A rig process that did not start refuses the run, nothing sent: its folder (only
    config.yaml, rig.yaml and rig.log) goes, since a refused run leaves none ('harness logs
    --failed' read it as a run killed on the way), and rig.log's diagnosis, the process's
    last line (its own one-line error, or a traceback's exception), goes into the error."""
    try:
        lines = [ln.strip() for ln in proc.log_path.read_text(errors="replace").splitlines()]
    except OSError:
        lines = []
    said = next((ln for ln in reversed(lines) if ln), "")
    shutil.rmtree(run_dir, ignore_errors=True)
    what = str(exc).split("; see ")[0]  # rig.log is gone with the folder
    return RunRefused(f"{run.source}: {what}; it said: {said[:500] or '(nothing)'}")


REALTIME_BLOCK_ROWS = 500
"""Rows a recorded block holds in real time: a second at 500 Hz, so the live view and the
file lag the rig by about a second; its channels are sent one per tick's slack."""
LOCKSTEP_BLOCK_ROWS = 2500
LOCKSTEP_FLUSH_EVERY_BLOCKS = 2
"""In lockstep a block holds 2500 rows and the file sink is waited for every 2 blocks: the
same 5000 rows between waits as 10 blocks of 500 (what the output guard's reserve allows
for), a fifth of Rerun's calls a row. Measured (slew-rw, interleaved): 9 us less CPU a tick
of about 75, 12 %; 5000-row blocks gained nothing more."""


REALTIME_RIG_DEFAULT = "process-unix"
"""How a real-time run on the virtual bus runs the virtual rig unless its run file says
(``realtime.virtual_rig``): chosen by benchmarks/bench_rig_options.py (docs/realtime.md)."""


def virtual_rig_mode(run: RunConfig, spec: BusSpec, clock_name: str,
                     rig_process: bool = False, faults: list[FaultSpec] | None = None) -> str:
    """"lockstep" (pumped in the loop), "thread", "process-unix", "process-tcp", or
    "external" (the bus is not the in-process virtual bus: the rig is elsewhere). "auto"
    is ``REALTIME_RIG_DEFAULT`` (a rig process takes every fault, timed ones too:
    ``--fault KIND@AT_S+DURATION_S``). ``faults`` is kept for callers; it no longer
    changes the choice."""
    if not spec.in_process:
        return "external"
    if clock_name != "realtime":
        return "lockstep"
    if rig_process:
        return "process-tcp"
    mode = run.data["realtime"]["virtual_rig"]
    if mode == "auto":
        return REALTIME_RIG_DEFAULT
    return mode


def make_monitor(run: RunConfig, interface: RigInterface, realtime: bool) -> FaultMonitor:
    """The run's fault monitor on ``interface`` (also used by ``harness replay --check``)."""
    return FaultMonitor(
        interface, run.data["monitor"], run.data["limits"],
        run.rig.section("reaction_wheel")["max_speed_rad_s"], run.rig.accel_range_m_s2,
        run.rig.section("thruster_valves")["close_delay_s"], run.dt_s, realtime=realtime,
        valve_min_on_s=run.rig.section("thruster_valves")["min_on_time_s"],
        wheel_max_torque_n_m=run.rig.section("reaction_wheel")["max_torque_n_m"],
        rig=run.rig)


def _execute(run: RunConfig, spec: BusSpec, clock_name: str, controller: object,
             load: Any, run_dir: Path, live_view_url: str | None, show_progress: bool,
             dry_run: bool, faults: list[FaultSpec] | None,
             should_stop: Callable[[], str | None] | None,
             device_rig: Any = None, truth_tail_s: float = 0.0,
             rig_exited: Callable[[float], str | None] | None = None) -> RunResult:
    """``rig_exited``: how the run's rig process ended, when it has (``RigProcess.exited``):
    a bus failure of the loop while it is gone is the rig process's end, named so in the
    summary and raised as ``RigProcessExited``."""
    dt_s = run.dt_s
    protocol = load_protocol()
    kernel_sync = run.data["sync_source"] == "kernel"
    try:
        harness_bus = open_bus(spec)
    except Exception as exc:  # python-can raises many kinds (OSError, CanError, ValueError)
        raise RunRefused(f"bus {spec}: cannot open: {type(exc).__name__}: {exc}") from exc
    rig_bus = None
    rig: VirtualRig | None = None
    rig_thread: threading.Thread | None = None
    stop_rig = threading.Event()
    can_log = CanLog(run_dir / "can.blf")
    guard = SpaceGuard(run_dir)
    running = running_summary_for(run)
    plot_stats = PlotStats(CHANNELS)
    realtime = clock_name == "realtime"
    recorder = Recorder(run_dir / "run.rrd", CHANNELS, run.n_ticks, f"{run_dir.name}",
                        live_view_url=live_view_url, retain_rows=retain_rows_for(run),
                        observers=[running.update, plot_stats.add],
                        block_rows=REALTIME_BLOCK_ROWS if realtime else LOCKSTEP_BLOCK_ROWS,
                        # lockstep outruns the file sink: wait for it every few blocks so its
                        # queue stays bounded; real time never waits (the sink keeps up)
                        flush_every_blocks=0 if realtime else LOCKSTEP_FLUSH_EVERY_BLOCKS,
                        blueprint=layout_for_run(run.resolved(), CHANNELS),
                        annotator=ReviewAnnotator(), guard=guard)
    pump = None
    stats = LoopStats()
    setup = RealTimeSetup()
    summary: dict[str, Any] | None = None
    failure: OutputError | None = None
    try:
        if spec.in_process:
            rig_bus = open_bus(spec)
            rig = VirtualRig(device_rig if device_rig is not None else run.rig, rig_bus, dt_s,
                             faults=run.faults + list(faults or []))
            if truth_tail_s > 0:
                rig.record_truth_tail(math.ceil(truth_tail_s / dt_s) + 2)
            if clock_name == "lockstep":
                pump = rig.service
            else:
                rig_thread = threading.Thread(target=rig.run_forever,
                                              args=(stop_rig.is_set, 0.01), daemon=True)
                rig_thread.start()
        if clock_name == "realtime":
            rt = run.data["realtime"]
            setup = RealTimeSetup().apply(rt["sched_fifo"], rt["priority"], rt["cpu"],
                                          rt["lock_memory"], rt["gc_freeze"], rt["pin_cpu"])
            for line in setup.refused:
                recorder.log_event(0.0, "/events/harness",
                                   f"real-time measure not granted: {line}", "WARN")
            loop_clock: LockstepClock | RealTimeClock | KernelSyncClock = RealTimeClock(dt_s)
        else:
            loop_clock = LockstepClock(dt_s)
        interface = RigInterface(harness_bus, protocol, run.rig, can_log, run.actuators,
                                 dry_run=dry_run)
        if kernel_sync:
            from harness.bus.socketcan_echo import broadcast_manager_missing

            why = broadcast_manager_missing(harness_bus)
            if why is not None:  # before the CANopen set-up: nothing sent
                raise RunRefused(f"{run.source}: sync_source: kernel: bus {spec}: {why}")
            loop_clock = KernelSyncClock(dt_s, interface)
        heartbeat_every = max(1, round(run.data["rate_hz"] / run.data["heartbeat_hz"]))
        monitor = make_monitor(run, interface, realtime=clock_name == "realtime")
        co_nodes: list[Any] | None = None
        if interface.co is not None:
            co_nodes = canopen_setup(interface, pump, can_log, dry_run, show_progress)
            interface.watch_heartbeats(dt_s, grace_ticks=monitor.realtime_grace,
                                       quiet_ticks=monitor.startup_ticks)
        monitor.on_warning = _warning_logger(recorder, show_progress)
        reference = getattr(controller, "reference", None)
        sequence = controller if isinstance(controller, SequenceRunner) else None
        if sequence is not None:  # what the sequence's actions reach: the bus, the recording
            sequence.insert_fault = getattr(interface, "insert_fault", None)
            sequence.clear_faults = getattr(interface, "clear_faults", None)
            # a step's start and its when: actions in the events; a step that did not
            # pass marked on every plot too, where it was decided
            sequence.log_event = lambda t, entity, text, level: recorder.log_event(
                t, entity, text, level, mark=level != "INFO")
        # timing on the wire: from here on every frame's time stamp (the set-up's are not)
        wire = WireTiming(dt_s, interface.drivers,
                          "none" if pump is not None else interface.start_wire_timing(),
                          paced=realtime, sync_sent_by=run.data["sync_source"])
        recorder.log_static_text("/run/config", "```yaml\n" + yaml.safe_dump(
            run.resolved(), sort_keys=False) + "```")
        try:
            stats = run_loop(
                interface, controller, loop_clock, recorder, run.n_ticks, dt_s,
                heartbeat_every, run.data["receive_timeout_ms"] / 1e3, pump=pump,
                reference=reference, progress=_progress if show_progress else None,
                stats=stats, monitor=monitor, should_stop=should_stop,
                step_budget_s=run.step_budget_s, wire=wire,
                controller_name=controller_type(run.controller["type"]).describe(),
                sequence=sequence)
        except (ControllerError, OutputError):
            raise
        except Exception as exc:  # the bus failed: was it the rig process's end?
            ended = rig_exited(EXIT_WAIT_S) if rig_exited is not None else None
            if ended is None:
                raise
            # the bus's own words without the traceback python-can's socketcand client puts
            # into its error's text
            said = str(exc).split("Traceback (most recent call last)")[0]
            said = (said.strip().splitlines() or [""])[0].strip()
            stats.error = f"{ended}: {type(exc).__name__}: {said} (tick {stats.ticks})"
            raise RigProcessExited(stats.error) from exc
        finally:
            if show_progress:
                print("", file=sys.stderr)
            try:
                monitor.finish()  # the missing frames the rate limit held back
            except Exception as exc:  # never lose the summary for a warning
                print(f"harness: could not report the monitor's last warning ({exc})",
                      file=sys.stderr)
            summary = summarise(run, recorder, stats, load.percent, interface, clock_name,
                                str(spec), setup, rig, running)
            summary["monitor_warnings"] = dict(monitor.warning_counts)
            # what the monitor did not judge as a device's doing: stalls of the whole bench
            # on the wall clock, physics windows with late samples (docs/faults.md)
            summary["monitor_bench"] = {
                "stalls": monitor.bench_stalls,
                "behind_episodes": monitor.bench_behind,
                "longest_stall_s": round(monitor.bench_stall_max_s, 6),
                "stale_physics_windows": monitor.stale_windows}
            summary["wire_timing"] = wire.summary()
            # SYNC echoes that came after the next SYNC was sent: those ticks not timed
            summary["wire_timing"]["sync_echoes_late"] = interface.late_sync_echoes
            summary.update(periodic_summary(run, recorder, controller, running))
            design_report = getattr(controller, "design_report", None)
            if callable(design_report):
                summary["controller_design"] = design_report()
            summary["dry_run"] = dry_run
            summary["controller"] = controller_summary(run, stats)
            if co_nodes is not None:  # each node's identity, device type, scaling objects
                summary["canopen_nodes"] = co_nodes
            summary["faults"] = [f.to_dict() for f in stats.faults]
            if sequence is not None:
                sequence.close(max(0, stats.ticks - 1) * dt_s)
                summary["sequence"] = sequence.summary()
            summary["injected_faults"] = [vars(f) for f in (rig.injector.faults if rig else [])]
            # taken at run time by the rig's fault-insertion unit (in-process rig)
            summary["inserted_faults"] = [vars(f) for f in (rig.inserted_faults if rig else [])]
            failure = recorder.space_stop or recorder.failed or can_log.failed
            if failure is None:
                try:
                    _write_summary(run_dir, summary)
                except OutputError as exc:
                    failure = exc
                else:
                    _log_end(recorder, stats, summary, dt_s)
                    if sequence is not None:
                        _log_steps(recorder, summary["sequence"])
                    _final_layout(recorder, run, run_dir, plot_stats)
    finally:
        setup.restore()
        stop_rig.set()
        if rig_thread is not None:
            rig_thread.join(timeout=2.0)
        failure = _close_outputs(recorder, can_log, guard, dt_s, clock_name == "realtime",
                                 run.rig.data["bus"]["sync_divider"], failure,
                                 run.rig.binding)
        harness_bus.shutdown()
        if rig_bus is not None:
            rig_bus.shutdown()
        if failure is not None:
            _report_output_failure(run_dir, summary, stats, failure)
    if failure is not None:
        raise failure
    return RunResult(run_dir, summary, stats, recorder, rig)


def refuse_kernel_sync(run: RunConfig, spec: BusSpec, clock_name: str) -> None:
    """``sync_source: kernel`` needs SocketCAN's broadcast manager and the real-time clock;
    otherwise the run is refused before anything is sent."""
    if spec.interface != "socketcan":
        raise RunRefused(f"{run.source}: sync_source: kernel needs a SocketCAN bus (the "
                         f"kernel's broadcast manager sends SYNC); bus {spec} has none: use "
                         "--bus socketcan:CHANNEL or sync_source: loop")
    if clock_name != "realtime":
        raise RunRefused(f"{run.source}: sync_source: kernel needs --clock realtime (the "
                         f"kernel sends SYNC on its own period), not {clock_name}")


def _write_summary(run_dir: Path, summary: dict[str, Any]) -> None:
    write_text_atomic(run_dir / "summary.json", json.dumps(summary, indent=2))


def _close_outputs(recorder: Recorder, can_log: CanLog, guard: SpaceGuard, dt_s: float,
                   realtime: bool, dividers: dict[str, int],
                   failure: OutputError | None = None,
                   binding: Any = None) -> OutputError | None:
    """Close the CAN log and the recording (every exit path); the first failure of the
    output folder, if any (a full or read-only disk), instead of raising it, so that both
    are closed and what they hold stays readable."""
    failure = failure or recorder.space_stop or recorder.failed or can_log.failed
    try:
        can_log.close()
    except OutputError as exc:
        failure = failure or exc
    if failure is None:
        try:  # the decoded bus takes about 8 times the CAN log's size (slew-rw)
            guard.check(need_bytes=10 * can_log.path.stat().st_size)
        except (OSError, OutputError) as exc:
            print(f"harness: the CAN log is not decoded into the recording ({exc})",
                  file=sys.stderr)
        else:
            _log_bus(recorder, can_log.path, dt_s, realtime, dividers, binding)
    try:
        recorder.close()
    except OutputError as exc:
        failure = failure or exc
    return failure


def _report_output_failure(run_dir: Path, summary: dict[str, Any] | None, stats: LoopStats,
                           failure: OutputError) -> None:
    """A run whose folder failed never says "completed": its summary.json says why it
    stopped, or, when even that cannot be written, is removed (``harness logs`` then shows
    the run as not completed)."""
    stats.stopped_by = "error"
    stats.error = str(failure)
    if summary is None:
        return
    summary["stopped_by"] = "error"
    summary["error"] = str(failure)
    summary["output_failure"] = failure.reason
    try:
        _write_summary(run_dir, summary)
    except OutputError:
        with contextlib.suppress(OSError):
            (run_dir / "summary.json").unlink()


def canopen_setup(interface: RigInterface, pump: Callable[[], object] | None,
                  can_log: CanLog | None, dry_run: bool, show_progress: bool) -> list[Any]:
    """CANopen nodes to operational with the binding's PDOs, before the first tick
    (``drivers.binding.canopen_master``); a failure refuses the run, naming the node."""
    from drivers.binding.canopen_master import CanopenMaster, SetupError

    master = CanopenMaster(interface.bus, interface.co, dry_run=dry_run,
                           log=can_log.log if can_log is not None else None)
    try:
        return master.setup(pump=pump, progress=(
            (lambda m: print(f"harness: {m}", file=sys.stderr)) if show_progress else None))
    except SetupError as exc:
        raise RunRefused(f"CANopen set-up failed: {exc}; every node sent to "
                         "pre-operational") from exc


def _warning_logger(recorder: Recorder, show: bool) -> Callable[[MonitorWarning], None]:
    """The monitor's warnings: a WARN event under /events/monitor at its time (sent in the
    loop's slack, ``Recorder.queue_event``), marked on the plots, and a line on stderr."""
    def on_warning(w: MonitorWarning) -> None:
        recorder.queue_event(w.time_s, "/events/monitor", str(w), "WARN",
                             series=f"warning/{w.kind}",
                             name=f"WARNING {w.kind.replace('_', ' ')}")
        if show:
            print(f"\nharness: WARNING {w}", file=sys.stderr)
    return on_warning


def retain_rows_for(run: RunConfig) -> int:
    """Rows the recorder keeps for the summary: the longer of the residual and the steady
    windows, plus one tick."""
    window = max(run.data["residual_window_s"], run.data["steady_window_s"])
    return int(math.ceil(window * run.data["rate_hz"])) + 2


def running_summary_for(run: RunConfig) -> RunningSummary:
    return RunningSummary(CHANNELS, run.controller.get("angle_deg"),
                          run.data["settle_band_deg"])


def _log_end(recorder: Recorder, stats: LoopStats, summary: dict[str, Any],
             dt_s: float) -> None:
    """The summary as text, and the end of a run the loop did not log (Ctrl-C, an error)."""
    try:
        t_end = max(0, stats.ticks - 1) * dt_s
        if stats.stopped_by == "error":
            recorder.log_event(t_end, "/events/harness",
                               f"harness: error: {stats.error} (t = {t_end:.3f} s)", "ERROR")
        elif stats.stopped_by == "interrupted" and not stats.error:
            recorder.log_event(t_end, "/events/harness", "harness: interrupted (Ctrl-C or "
                               f"SIGTERM) (t = {t_end:.3f} s)", "WARN")
        elif stats.stopped_by == "completed":  # no marker: the log says how the run ended
            log_event(recorder.rec, t_end, "/events/harness",
                      f"harness: completed, {stats.ticks} ticks (t = {t_end:.3f} s)", "INFO")
        recorder.log_summary(summary)
    except Exception as exc:  # never lose the run for its text
        print(f"harness: could not write the summary to the recording ({exc})",
              file=sys.stderr)


def _log_steps(recorder: Recorder, sequence: dict[str, Any]) -> None:
    """The sequence's step timeline into the recording (harness.review.sequence)."""
    try:
        from harness.review.sequence import write_steps

        write_steps(recorder.bounded_stream, sequence)
    except Exception as exc:  # the steps are in summary.json and the events regardless
        print(f"harness: could not record the sequence's step timeline ({exc})",
              file=sys.stderr)


def _final_layout(recorder: Recorder, run: RunConfig, run_dir: Path,
                  plot_stats: PlotStats) -> None:
    """The run's layout with each plot's y axis on its recorded range and its legend in the
    emptiest corner (``plot_stats``, a recorder observer, saw every row; layout.json keeps
    both for identify.rrd and verdict.rrd, harness.review.layouts)."""
    try:
        # the time axes end where the recording does (a faulted run's at the fault)
        end_s = plot_stats.end_s or run.data["duration_s"]
        ranges, legends = plot_stats.ranges(), plot_stats.legends(end_s)
        write_layout_file(run_dir, ranges, legends, end_s, CHANNELS)
        recorder.send_layout(layout_for_run(run.resolved(), CHANNELS, ranges, legends, end_s))
    except Exception as exc:  # the layout of the start stays
        print(f"harness: could not write the run's final layout ({exc})", file=sys.stderr)


def _log_bus(recorder: Recorder, blf: Path, dt_s: float, realtime: bool,
             dividers: dict[str, int], binding: Any = None) -> None:
    """The CAN log decoded into the recording, after the run: the sgsrt protocol by
    harness.review.bus, any other binding (a DBC, CANopen) by harness.review.bus_binding."""
    try:
        if not blf.exists():
            return
        if binding is not None and not binding.is_sgsrt():
            from harness.review.bus_binding import write_bus_binding

            bus = write_bus_binding(recorder.bounded_stream, blf, dt_s, realtime, dividers,
                                    binding)
        else:
            fi = getattr(binding, "fault_insertion", None)
            bus = write_bus(recorder.bounded_stream, blf, dt_s, realtime, dividers,
                            fault_insertion_id=fi[0] if fi else None)
        for t_s, text in bus.warnings:
            log_event(recorder.rec, t_s, "/events/can_log", text, "WARN")
        if bus.late_or_missing > len(bus.warnings):
            log_event(recorder.rec, bus.warnings[-1][0], "/events/can_log",
                      f"can log: {bus.late_or_missing} late or missing telemetry frames in all "
                      f"(the first {len(bus.warnings)} ticks listed)", "WARN")
    except Exception as exc:  # the run's own recording is complete without it
        print(f"harness: could not decode the CAN log into the recording ({exc})",
              file=sys.stderr)


def _settle_time(t: np.ndarray, err_deg: np.ndarray, band_deg: float) -> float | None:
    outside = np.nonzero(np.abs(err_deg) > band_deg)[0]
    if len(outside) == 0:
        return float(t[0]) if len(t) else None
    last = outside[-1]
    return None if last + 1 >= len(t) else float(t[last + 1])


def summarise(run: RunConfig, rec: Recorder, stats: LoopStats, bus_load_percent: float,
              interface: RigInterface, clock_name: str, bus: str, setup: RealTimeSetup,
              rig: VirtualRig | None, running: RunningSummary | None = None) -> dict[str, Any]:
    """The run's summary from streaming figures (``running``, fed every recorded block)
    and the recorder's retained tail (the residual window); memory does not grow with the
    run. Without ``running``, one is built from the retained tail."""
    rec.finish_rows()
    t = rec.tail_time()
    if running is None:
        running = running_summary_for(run)
        running.update(t, np.column_stack([rec.column(c) for c in CHANNELS])
                       if len(t) else np.zeros((0, len(CHANNELS))))
    ix = {c: i for i, c in enumerate(CHANNELS)}
    last = running.last_row
    accel = rec.column("/tip/accel_m_s2")
    ctrl = run.controller
    target_deg = ctrl.get("angle_deg")
    has_ref = running.has_ref
    t_end = running.t_last if running.t_last is not None else 0.0
    window = t >= (t_end - run.data["residual_window_s"])
    t_max = run.rig.section("reaction_wheel")["max_torque_n_m"]
    sim_time = stats.ticks * run.dt_s
    slew_end = running.reach_t if has_ref and target_deg is not None else None
    # settle: from then on the hub stays within the band around the slew's target
    settle = running.settle_t if target_deg is not None and running.rows else None
    max_cmd = running.max_abs.get("/wheel/torque_cmd_n_m", math.nan)
    max_tlm = running.max_abs.get("/wheel/torque_n_m", math.nan)
    final_angle = last[ix["/attitude/angle_deg"]] if last is not None else None
    final_err = (last[ix["/attitude/reference_deg"]] - last[ix["/attitude/angle_deg"]]
                 if last is not None and has_ref else None)
    lat = stats.percentiles_ms(stats.lateness_s)
    work = stats.percentiles_ms(stats.work_s)
    malformed = sum(d.counters.malformed for d in interface.drivers.values())
    def f(x: float | None) -> float | None:
        return None if x is None or (isinstance(x, float) and math.isnan(x)) else float(x)
    return {
        "run": run.name,
        "clock": clock_name,
        **rig_identity(run.rig.data, bus),  # rig, rig_sha256, bus, binding
        "rate_hz": run.data["rate_hz"],
        "ticks": stats.ticks,
        "stopped_by": stats.stopped_by,
        "error": stats.error,
        "target_angle_deg": target_deg,
        "final_angle_deg": f(final_angle),
        "final_angle_error_deg": f(final_err),
        "slew_profile_end_s": slew_end,
        "settle_time_s": settle,
        "settle_band_deg": run.data["settle_band_deg"],
        "peak_tip_accel_m_s2": f(running.max_abs.get("/tip/accel_m_s2"))
        if running.rows else None,
        "residual_tip_accel_m_s2": f(np.max(np.abs(accel[window]))) if len(accel) else None,
        "residual_tip_accel_rms_m_s2": f(np.sqrt(np.mean(accel[window] ** 2)))
        if len(accel) else None,
        "residual_window_s": run.data["residual_window_s"],
        "max_wheel_torque_cmd_n_m": f(max_cmd) if running.rows else 0.0,
        "max_wheel_torque_measured_n_m": f(max_tlm) if running.rows else 0.0,
        "wheel_torque_limit_n_m": t_max,
        "wheel_torque_within_limit": bool(running.rows == 0 or (
            max_cmd <= t_max + 1e-9 and max_tlm <= t_max + 1e-5)),
        "overruns": stats.overruns,
        "overrun_episodes": stats.overrun_episodes,
        "lateness_ms": lat,
        "work_ms": work,
        "bus_load_percent": round(bus_load_percent, 2),
        "frames": {
            "sent": interface.counters.sent,
            "received": interface.counters.received,
            "unknown": interface.counters.unknown,
            "malformed": malformed,
            "missing": stats.missing_frames,
            "missing_in_ticks_on_time": stats.missing_frames_on_time,
            # split by a rig process's SYNC timing (attribute_missing); without it (the rig
            # as a thread, lockstep, a real rig) every such frame counts as the harness's
            "missing_in_ticks_host_delayed": 0,
            "missing_in_ticks_rig_preempted": 0,
            "missing_in_ticks_held_by_both": stats.missing_frames_on_time,
            "missing_rig_answered_after_window": 0,
            "error_frames": interface.counters.error_frames,
            # frames the bus refused to send (a full queue, a peer gone; the safe state at
            # the end of a run whose rig process exited among them)
            "not_sent": interface.counters.send_errors,
            # frames the host's kernel dropped because the harness's socket queue was full
            # (a loop behind on a busy host); null where the bus cannot say (not SocketCAN)
            "dropped_by_kernel": (interface.bus.kernel_drops
                                  if getattr(interface.bus, "drops_counted", False) else None),
        },
        "wall_time_s": round(stats.wall_s, 3),
        "simulated_time_s": round(sim_time, 6),
        "real_time_factor": round(sim_time / stats.wall_s, 2) if stats.wall_s > 0 else None,
        "realtime_measures": setup.to_dict(),
        "virtual_rig": None if rig is None else {
            "watchdog_trips": rig.counters.watchdog_trips,
            "steps": rig.counters.steps,
            "malformed": rig.counters.malformed,
            "unknown": rig.counters.unknown,
            # protected commands dropped for repeating the last alive counter (docs/lab.md)
            "repeated": rig.counters.repeated,
        },
    }


def periodic_summary(run: RunConfig, rec: Recorder, controller: object,
                     running: RunningSummary | None = None) -> dict[str, Any]:
    """For runs with a periodic disturbance: the steady-state tip acceleration amplitude,
    defined as half the peak-to-peak of a least-squares fit of harmonics 1-15 of the rotor
    frequency to the tip acceleration over the last ``steady_window_s`` (whole periods).
    The hub angle is detrended by the whole run's least-squares line (``running``, from
    streaming sums) before its fit; the windows come from the recorder's retained tail."""
    period = getattr(controller, "period_s", None)
    if period is None or rec.rows < 10:
        return {}
    rec.finish_rows()
    t = rec.tail_time()
    if running is None:
        running = running_summary_for(run)
        running.update(t, np.column_stack([rec.column(c) for c in CHANNELS]))
    angle = rec.column("/attitude/angle_deg")
    omega = 2 * math.pi / period
    window = min(run.data["steady_window_s"], 0.5 * t[-1], t[-1] - t[0])
    law = controller.law  # type: ignore[attr-defined]
    return {
        "rotor_speed_rad_s": omega,
        "rotor_period_s": period,
        "beta": controller.beta,  # type: ignore[attr-defined]
        "frequency_ratio": run.controller.get("frequency_ratio"),
        "disturbance_amplitude_n_m": law.amplitude_n_m(omega),
        "compensation_amplitude_n_m": controller.amplitude_n_m,  # type: ignore[attr-defined]
        "steady_window_s": window,
        "steady_tip_accel_amplitude_m_s2": steady_state_amplitude(
            t, rec.column("/tip/accel_m_s2"), omega, window),
        "steady_angle_amplitude_deg": steady_state_amplitude(
            t, angle - running.angle_trend(t), omega, window),
    }


def require_config(ok: bool, message: str) -> None:
    if not ok:
        raise ConfigError(message)
