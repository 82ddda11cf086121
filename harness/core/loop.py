"""The fixed-rate loop: one tick = SYNC out, telemetry in, controller, commands out, record.

Data flows one way per tick: sensors -> state -> controller -> command -> actuators -> log.
On every exit path (end of run, exception in a controller, Ctrl-C, SIGTERM turned into
KeyboardInterrupt by the caller) the actuators are commanded safe and the heartbeat is
disarmed; the caller then closes the recording and the CAN log.
"""

from __future__ import annotations

import gc
import math
import struct
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from harness.bus.rig_interface import RigInterface
from harness.core.clock import (
    BUS_LOCKSTEP_WAIT_S,
    KernelSyncClock,
    KernelSyncLost,
    LockstepClock,
    RealTimeClock,
)
from harness.core.streaming import LatencyHistogram
from harness.core.wire_timing import WireTiming
from harness.record.recording import Recorder
from harness.state import RigCommand, RigState

# what the loop records every tick (entity path = channel; the unit is in the name)
CHANNELS = [
    "/attitude/angle_deg",
    "/attitude/reference_deg",
    "/attitude/error_deg",
    "/attitude/rate_deg_s",
    "/wheel/torque_cmd_n_m",
    "/wheel/torque_n_m",
    "/wheel/speed_rad_s",
    "/tip/accel_m_s2",
    "/thrusters/valve_cmd",
    "/thrusters/valve_state",
    "/thrusters/firings",
    "/thrusters/on_time_s",
    "/piezo/cmd_ch1_v",
    "/piezo/cmd_ch2_v",
    "/piezo/sensor_ch1_v",
    "/piezo/sensor_ch2_v",
    "/rotor/angle_rad",
    "/rotor/speed_rad_s",
    "/timing/lateness_ms",
    "/timing/work_ms",
    "/timing/frames_rx",
    # timing on the wire from the frames' own time stamps (harness.core.wire_timing; NaN
    # where not measured): this SYNC's period minus the loop's, the last device's first
    # answer after this SYNC, the previous tick's last command before this SYNC
    "/timing/sync_jitter_ms",
    "/timing/answer_latency_ms",
    "/timing/command_margin_ms",
]
# one recorded row packed straight into the recorder's float64 row (one call, not numpy's
# conversion of a tuple)
_ROW = struct.Struct(f"={len(CHANNELS)}d")


@dataclass
class LoopStats:
    """The loop's counters; lateness and work per tick are streaming histograms
    (``harness.core.streaming.LatencyHistogram``: fixed memory for any run length)."""

    ticks: int = 0
    overruns: int = 0
    overrun_episodes: int = 0  # runs of consecutive overruns (one host stall, one episode)
    lateness_s: LatencyHistogram = field(default_factory=LatencyHistogram)
    work_s: LatencyHistogram = field(default_factory=LatencyHistogram)
    missing_frames: int = 0
    # telemetry frames missing in ticks that were not themselves late (the loop held its
    # deadline, the frame still did not come)
    missing_frames_on_time: int = 0
    # the first MAX_MISS_TICKS of those ticks as (tick, frames missing, lateness s): a rig
    # process's SYNC timing tells which of them the host kept the rig from answering in time
    missing_on_time_ticks: list[tuple[int, int, float]] = field(default_factory=list)
    wall_s: float = 0.0
    # the controller's step() per tick (wall time, perf_counter around the call): the sum,
    # the longest and the ticks over its budget (run_loop's step_budget_s)
    step_total_s: float = 0.0
    step_max_s: float = 0.0
    steps_over_budget: int = 0
    stopped_by: str = "completed"
    error: str = ""
    faults: list[Any] = field(default_factory=list)

    def percentiles_ms(self, values: LatencyHistogram | list[float]) -> dict[str, float]:
        if isinstance(values, LatencyHistogram):
            return values.percentiles_ms()
        hist = LatencyHistogram()
        for v in values:
            hist.add(v)
        return hist.percentiles_ms()


class ControllerError(RuntimeError):
    """The controller failed in the tick: its ``step()`` raised (anything: ``SystemExit``,
    ``GeneratorExit`` and a ``KeyboardInterrupt`` no signal asked for included) or returned
    something other than a ``RigCommand``. The run ends ERROR, the rig left safe, the
    controller named; ``__cause__`` is what it raised."""


def _not_a_command(value: object) -> str:
    text = repr(value)
    return f"{type(value).__name__} {text[:60]}{'...' if len(text) > 60 else ''}"


RESERVE_FRACTION = 0.3
"""In real time the loop waits for a tick's telemetry until this fraction of the period is
left (for the controller, the commands and the recording): a frame that comes later is
missing for its tick."""

HELD_FRACTION = 0.5
"""A tick is held when it starts less than this fraction of the period late and does not
overrun (the host's delays of a rig process's answer are judged by the same rule)."""

MAX_MISS_TICKS = 20_000
"""Ticks with frames missing though the loop held them, kept by tick (the count is exact)."""

CAN_LOG_MAX_PENDING = 20_000
"""Frames the CAN log may queue in real time before it is written regardless (about 3 s of
the rig's traffic at 500 Hz)."""


def run_loop(
    interface: RigInterface,
    controller: object,
    clock: LockstepClock | RealTimeClock | KernelSyncClock,
    recorder: Recorder,
    n_ticks: int,
    dt_s: float,
    heartbeat_every: int,
    receive_timeout_s: float,
    pump: Callable[[], object] | None = None,
    reference: Callable[[float], tuple[float, float, float]] | None = None,
    progress: Callable[[int, int], None] | None = None,
    stats: LoopStats | None = None,
    monitor: Any = None,
    should_stop: Callable[[], str | None] | None = None,
    step_budget_s: float = math.inf,
    wire: WireTiming | None = None,
    controller_name: str = "the controller",
    sequence: Any = None,
) -> LoopStats:
    """Run ``n_ticks`` ticks. ``pump`` lets an in-process virtual rig answer (lockstep).
    ``stats`` (filled in place) stays with the caller even when the loop raises.
    ``step_budget_s``: the controller's time per tick; the ticks its step() took longer are
    counted (``stats.steps_over_budget``). ``wire``: timing on the wire, fed every tick
    from the interface's time stamps (``RigInterface.start_wire_timing``, called by the
    caller); without it those channels are NaN. The controller is given a copy of the
    tick's state (``RigState.copy``): the monitor and the recording read the original.
    Whatever its ``step()`` raises, or a return that is not a ``RigCommand``, ends the run
    with ``ControllerError`` naming ``controller_name`` (a ``KeyboardInterrupt`` while a
    stop was asked for, ``should_stop``, is the signal's: the run is interrupted).
    ``sequence``: the run's sequence (``harness.sequences.runner.SequenceRunner``, also the
    controller): the run ends when it has ``finished``; on a monitor fault it is told
    (``on_fault``) and, while it goes on deciding, the loop keeps ticking with every command
    safe and the heartbeat disarmed (the monitor then checks nothing more)."""
    stats = stats if stats is not None else LoopStats()
    step = controller.step  # type: ignore[attr-defined]
    copy_state = RigState.copy
    perf = time.perf_counter
    realtime = clock.realtime
    # lockstep in process: the rig answered inside pump(); over a bus: wait for its answers
    timeout = (receive_timeout_s if realtime else 0.0 if pump is not None
               else max(receive_timeout_s, BUS_LOCKSTEP_WAIT_S))
    can_log = interface.can_log
    cmd = RigCommand()
    sent = RigCommand()
    progress_every = max(1, n_ticks // 20)
    collect_young = realtime and not gc.isenabled()
    collect_every = max(1, round(1.0 / dt_s))
    next_collect = collect_every
    # bookkeeping fixed before the first tick: the frames due at each tick repeat with the
    # dividers' least common multiple; in lockstep no tick is late (lateness 0, counted in
    # one go at the end)
    div = getattr(interface, "divider", None)
    period = math.lcm(*div.values()) if div else 1
    # from tick `period` on (tick 0 may differ: a CANopen TPDO's first frame)
    expected_at = [interface.expected_frames(period + k) for k in range(period)] \
        if period <= 10_000 else None
    lockstep = not realtime
    # lockstep with the rig in process: it has answered inside pump()
    lockstep_read = pump is not None and not realtime
    lateness = 0.0
    lateness_add = stats.lateness_s.add
    work_add = stats.work_s.add
    # the tick's calls bound once
    send_sync, receive = interface.send_sync, interface.receive
    snapshot, command = interface.snapshot, interface.command
    new_row, commit, drain = recorder.row, recorder.commit, recorder.drain
    pack_row = _ROW.pack_into
    check = monitor.check if monitor is not None else None
    not_held = getattr(monitor, "note_not_held", None) if realtime else None
    degrees = math.degrees
    on_time_ticks = 0
    nan = math.nan
    wire_tick = wire.tick if wire is not None else None
    wire_rx = getattr(interface, "wire_rx", None)
    wire_names = getattr(interface, "device_of_driver", {})
    jitter_ms = latency_ms = margin_ms = nan
    step_total = step_max = 0.0
    steps_over = 0
    wall0 = perf()
    tick = 0
    prev_overrun = False
    held_safe = False  # a sequence's run after a monitor fault: commands safe, disarmed
    safe_cmd = RigCommand()
    try:
        clock.start()  # the kernel's SYNC (KernelSyncClock) starts here: inside, left safe
        for tick in range(n_ticks):
            if should_stop is not None and should_stop():
                stats.stopped_by = "interrupted"
                stats.error = f"stopped by {should_stop()}"
                recorder.log_event(tick * dt_s, "/events/harness", stats.error, "WARN")
                break
            if sequence is not None and sequence.finished:
                break  # the sequence is over: so is the run
            if not lockstep:
                lateness = clock.wait(tick)
            t_start = perf()
            if tick % heartbeat_every == 0:
                interface.send_heartbeat(armed=not held_safe)
            send_sync(tick)
            if pump is not None:
                pump()
            if realtime:  # never wait for telemetry past most of this tick's period
                timeout = min(receive_timeout_s,
                              max(0.0, clock.time_left(tick) - RESERVE_FRACTION * dt_s))
            expected = (expected_at[tick % period] if expected_at is not None and tick >= period
                        else interface.expected_frames(tick))
            got = receive(tick, timeout, lockstep_read, expected)
            missing = expected - got
            if missing > 0:
                stats.missing_frames += missing
            if wire_tick is not None and wire_rx is not None:
                jitter_ms, latency_ms, margin_ms = wire_tick(
                    interface.wire_sync_ts, interface.wire_prev_cmd_ts,
                    [(wire_names.get(id(d), ""), ts) for d, ts in wire_rx])
                wire_rx.clear()
            t_s = tick * dt_s
            state = snapshot(tick, t_s)
            t_step = perf()
            try:
                cmd = step(copy_state(state))
            except BaseException as exc:  # a plugin's SystemExit is no completed run
                if isinstance(exc, KeyboardInterrupt) and (
                        should_stop is None or should_stop() is not None):
                    raise  # the second Ctrl-C/SIGTERM of a stop (harness.core.interrupts)
                raise ControllerError(
                    f"{controller_name}: step() raised {type(exc).__name__}"
                    f"{': ' + str(exc) if str(exc) else ''} at tick {tick} "
                    f"(t = {tick * dt_s:.3f} s)") from exc
            t_step = perf() - t_step
            if cmd.__class__ is not RigCommand and not isinstance(cmd, RigCommand):
                raise ControllerError(
                    f"{controller_name}: step() returned {_not_a_command(cmd)}, not a "
                    f"RigCommand, at tick {tick} (t = {tick * dt_s:.3f} s)")
            if held_safe:
                cmd = safe_cmd
            step_total += t_step
            if t_step > step_max:
                step_max = t_step
            if t_step > step_budget_s:
                steps_over += 1
            try:
                sent = command(cmd)
            except (TypeError, ValueError) as exc:  # a value no driver can encode
                raise ControllerError(
                    f"{controller_name}: step() returned a command that cannot be sent "
                    f"({type(exc).__name__}: {exc}; a value of the wrong type?) at tick "
                    f"{tick} (t = {tick * dt_s:.3f} s)") from exc
            work = perf() - t_start
            if realtime:
                overrun = clock.time_left(tick) < 0
                if overrun:
                    stats.overruns += 1
                    stats.overrun_episodes += not prev_overrun
                prev_overrun = overrun
            else:
                overrun = False
            if not_held is not None and (overrun or lateness >= HELD_FRACTION * dt_s):
                # the monitor: frames missing around a long one are the bench's
                not_held(tick, max(lateness, -clock.time_left(tick)))
            if missing > 0 and not overrun and lateness < HELD_FRACTION * dt_s:
                stats.missing_frames_on_time += missing
                if len(stats.missing_on_time_ticks) < MAX_MISS_TICKS:
                    stats.missing_on_time_ticks.append((tick, missing, lateness))
            if lockstep:
                on_time_ticks += 1
            else:
                lateness_add(lateness)
            work_add(work)
            ref = reference(t_s)[0] if reference is not None else math.nan
            angle = state.hub_angle_rad
            piezo_v, piezo_sensor_v = sent.piezo_v, state.piezo_sensor_v
            pack_row(
                new_row(t_s), 0,
                degrees(angle), degrees(ref), degrees(ref - angle),
                degrees(state.hub_rate_rad_s),
                sent.wheel_torque_n_m, state.wheel_torque_n_m, state.wheel_speed_rad_s,
                state.tip_accel_m_s2, sent.valve_direction, state.valve_state,
                state.valve_firings, state.valve_on_time_s, piezo_v[0], piezo_v[1],
                piezo_sensor_v[0], piezo_sensor_v[1], state.rotor_angle_rad,
                state.rotor_speed_rad_s, lateness * 1e3, work * 1e3, got,
                jitter_ms, latency_ms, margin_ms,
            )
            commit()
            stats.ticks = tick + 1
            if check is not None and not held_safe:
                event = check(tick, state, sent)
                if event is not None:
                    stats.stopped_by = "fault"
                    stats.faults.append(event)
                    recorder.log_event(t_s, f"/events/{event.device}", str(event), "ERROR")
                    if sequence is None or not sequence.on_fault(t_s, event):
                        print(f"\nharness: FAULT {event}; leaving the rig safe",
                              file=sys.stderr)
                        break
                    print(f"\nharness: FAULT {event}; the rig held safe while the sequence "
                          "decides", file=sys.stderr)
                    # the sequence decides how the fault was handled: the rig held safe
                    # (the safe command through the run's own frames, not command_safe: a
                    # CANopen rig would leave operational and stop its telemetry)
                    held_safe = True
                    sent = command(safe_cmd)
                    interface.send_heartbeat(armed=False)
            # block logging and the CAN log's writer run outside the tick's critical path
            if realtime:
                if clock.time_left(tick) > 0.5 * dt_s:
                    drain(1)
                    if can_log is not None:
                        can_log.drain()
                    if collect_young and tick >= next_collect:
                        # the collector is off during a real-time run (RealTimeSetup): its
                        # young generations are collected here, in the slack, about once a
                        # second, so cyclic garbage cannot accumulate over a long run
                        gc.collect(1)
                        next_collect = tick + collect_every
                elif can_log is not None and can_log.pending > CAN_LOG_MAX_PENDING:
                    can_log.drain()  # a loop that never has time left still bounds memory
            else:
                drain()
                if can_log is not None and tick % 50 == 0:
                    can_log.drain()
            if progress is not None and tick % progress_every == 0:
                progress(tick, n_ticks)
    except KernelSyncLost as exc:  # the kernel's SYNC stopped: the run cannot go on
        stats.stopped_by = "error"
        stats.error = str(exc)
        recorder.log_event(tick * dt_s, "/events/harness", stats.error, "ERROR")
        print(f"\nharness: {exc}; leaving the rig safe", file=sys.stderr)
    except KeyboardInterrupt:
        stats.stopped_by = "interrupted"
        print("\nharness: interrupted; leaving the rig safe", file=sys.stderr)
    except ControllerError as exc:  # the controller failed: leave the rig safe first
        stats.stopped_by = "error"
        stats.error = str(exc)
        raise
    except Exception as exc:  # a driver failed: leave the rig safe first
        stats.stopped_by = "error"
        stats.error = f"{type(exc).__name__}: {exc} (tick {tick})"
        raise
    finally:
        stats.wall_s = perf() - wall0
        stats.step_total_s, stats.step_max_s = step_total, step_max
        stats.steps_over_budget = steps_over
        if on_time_ticks:
            stats.lateness_s.add_repeated(0.0, on_time_ticks)
        leave_safe(interface, pump)
    return stats


def leave_safe(interface: RigInterface, pump: Callable[[], object] | None) -> None:
    """Wheel torque zero, valves closed, piezo 0 V, rotor stopped; heartbeat disarmed."""
    try:
        stop_sync = getattr(interface, "stop_kernel_sync", None)
        if stop_sync is not None:  # no SYNC after the run: the devices stop answering
            stop_sync()
        interface.command_safe()
        interface.send_heartbeat(armed=False)
        if pump is not None:
            pump()
    except Exception as exc:  # the bus itself failed: report, the device watchdog takes over
        print(f"harness: could not command the safe state ({exc}); the rig's watchdog "
              "will make the devices safe", file=sys.stderr)
