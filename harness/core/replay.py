"""Replaying a CAN log through the harness's own drivers, and the determinism check.

A log (the run's ``can.blf``, or an ``.asc`` / candump ``.log`` capture of the real rig) is
split into ticks at each SYNC frame. The frames the devices sent in a tick are fed, in log
order, through :meth:`RigInterface.feed`, the per-frame path of the loop's ``receive``: the
same drivers decode them, count malformed frames, unknown ids, error frames and sequence
errors, and ``snapshot`` gives the tick's :class:`RigState`. The
frames the harness sent (the DBC's ``HARNESS`` node: SYNC, HEARTBEAT, ``*_CMD``) are decoded
with the DBC codecs. A HEARTBEAT goes out just before its tick's SYNC, so it falls into the
previous tick; it carries nothing the replay needs.

:func:`check_run` rebuilds a run's controller from its ``config.yaml`` as ``execute_run``
does, steps it on the reconstructed states, sends its commands through a second
``RigInterface`` (same clamping, encoding and frame counter) and compares them with the
logged command frames tick by tick: integer signals (enable, valve, counter) exactly,
scaled signals within one quantisation step.

The loop leaves the rig safe on every exit path (``leave_safe``: wheel disabled, valves
closed, piezo 0 V, rotor stopped, all four frames with one new counter), after the last
tick's own commands. That group is recognised (``split_commands``) and not compared with the
controller. A last tick without controller commands (the run was interrupted, or the
controller raised, before its commands went out; or the log stops there) is skipped with the
reason; anywhere else a missing command is a mismatch.

:class:`MonitorReplay` re-runs the run's fault monitor (built as ``execute_run`` builds it) on
the replayed ticks, through the replay's ``on_tick`` hook, so it sees the drivers' counters
and values as they were at each tick; its first event is compared with summary.json's first
fault (tick, device, kind).
"""

from __future__ import annotations

import copy
import math
from collections import Counter
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

import can

from drivers.binding import FAULT_INSERTION_NAME
from drivers.dbc import FrameCodec, FrameError, Protocol, load_protocol
from harness.bus.rig_interface import RigInterface
from harness.core.monitor import FaultEvent
from harness.core.runs import RunConfig, build_controller, run_from_dict
from harness.record.recording import Recorder
from harness.state import RigCommand, RigState
from rig_models.rig_file import RigConfig, rig_from_dict
from rig_models.schema import ConfigError

HARNESS_NODE = "HARNESS"
COMMAND_FRAMES = ("WHEEL_CMD", "VALVE_CMD", "PIEZO_CMD", "ROTOR_CMD")
"""Every command frame, in the order ``RigInterface.command``/``command_safe`` send them."""


class ReplayError(ValueError):
    """The log (or run directory) cannot be replayed; the message names the file."""


@dataclass(frozen=True)
class CommandFrame:
    """One command frame the harness sent: DBC name, payload, decoded values (empty if the
    payload does not fit the DBC)."""

    name: str
    data: bytes
    values: dict[str, float]

    @property
    def malformed(self) -> bool:
        return not self.values


@dataclass
class ReplayTick:
    tick: int
    time_s: float
    state: RigState
    commands: list[CommandFrame]
    """Every command frame the harness sent in this tick, in log order."""
    telemetry_frames: int
    """Telemetry frames the drivers accepted in this tick."""
    missing: int
    """Devices due at this tick (``sync_divider``) that did not answer."""


@dataclass
class Replay:
    source: Path
    dt_s: float
    ticks: list[ReplayTick]
    frames_by_id: dict[int, int]
    """Data frames (error frames excluded) per arbitration id."""
    harness_ids: frozenset[int]
    error_frames: int
    bus_off: bool
    unknown: int
    malformed: dict[str, int]
    """Per frame name: telemetry as counted by the drivers, harness frames by their codec."""
    sequence_errors: dict[str, int]
    """Per device: frame counters that did not advance by one (the drivers' count)."""
    sync_gaps: int
    """SYNC frames whose tick is not the previous one plus one."""
    before_first_sync: int
    """Device frames before the first SYNC (not fed to the drivers: their tick is unknown)."""
    n_ticks: int = 0
    first_tick: int | None = None
    last_tick: int | None = None
    first_time_s: float = 0.0
    last_time_s: float = 0.0
    missing_total: int = 0
    """Counted as the ticks go by: ``ticks`` is empty when they were not kept (a streamed
    replay, ``replay_messages(keep_ticks=False)``)."""

    @property
    def total_frames(self) -> int:
        return sum(self.frames_by_id.values()) + self.error_frames

    @property
    def missing_frames(self) -> int:
        return self.missing_total

    def strict_problems(self) -> list[str]:
        """What a log of a healthy run has none of (``harness replay --strict``): unknown
        ids, malformed frames, error frames, SYNC gaps, missing telemetry, sequence errors."""
        out = []
        for n, what in ((self.unknown, "frames of unknown ids"),
                        (sum(self.malformed.values()), "malformed frames"),
                        (self.error_frames, "error frames"), (self.sync_gaps, "SYNC gaps"),
                        (self.missing_frames, "telemetry frames missing at their tick"),
                        (sum(self.sequence_errors.values()), "sequence errors")):
            if n:
                out.append(f"{n} {what}")
        return out


@dataclass(frozen=True)
class Mismatch:
    tick: int
    time_s: float
    frame: str
    """Command frame name, or ``"(frames)"`` when the frames sent differ in number or id."""
    logged: dict[str, float] | list[str] | None
    replayed: dict[str, float] | list[str] | None
    detail: str


@dataclass
class CheckResult:
    ticks_compared: int = 0
    ticks_matching: int = 0
    ticks_identical: int = 0
    """Ticks whose command payloads are byte-identical (a subset of the matching ones)."""
    first_mismatch: Mismatch | None = None
    skipped: list[tuple[int, str]] = field(default_factory=list)
    """(tick, reason) of ticks not compared."""
    safe_tick: int | None = None
    """Tick whose frames end with the leave-safe commands (normally the last)."""
    stopped_by: str | None = None
    """From summary.json, if there."""
    summary_ticks: int | None = None
    monitor_event: FaultEvent | None = None
    """The first event of the run's fault monitor re-run on the replay (``check_run``)."""
    logged_fault: dict[str, Any] | None = None
    """summary.json's first fault."""
    monitor_consistent: bool = True

    @property
    def consistent(self) -> bool:
        return (self.first_mismatch is None and self.ticks_matching == self.ticks_compared
                and self.monitor_consistent)


class _LogBus:
    """What ``RigInterface`` needs of a bus: nothing to receive (frames are fed), ``send``
    keeps what the replayed controller's commands would have put on the bus."""

    def __init__(self) -> None:
        self.sent: list[can.Message] = []

    def recv(self, timeout: float | None = None) -> can.Message | None:
        return None

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self.sent.append(msg)


def _interface(protocol: Protocol, rig: RigConfig, actuators: tuple[str, ...] = (),
               dry_run: bool = False) -> tuple[RigInterface, _LogBus]:
    bus = _LogBus()
    iface = RigInterface(cast(can.BusABC, bus), protocol, rig, None,
                         actuators or ("reaction_wheel",), dry_run=dry_run)
    return iface, bus


def harness_frame_ids(protocol: Protocol) -> frozenset[int]:
    """Ids of the frames the harness sends (the DBC's ``HARNESS`` node)."""
    return frozenset(m.frame_id for m in protocol.database.messages
                     if HARNESS_NODE in (m.senders or []))


def read_log(path: Path) -> Iterator[can.Message]:
    """Every frame of a CAN log python-can reads (.blf, .asc, candump .log, ...), one at a
    time: the frames are never all in memory (a 600 s capture's list took about 1 GB)."""
    if not path.is_file():
        raise ReplayError(f"{path}: no such file")
    if path.suffix.lower() == ".blf":  # bounded in memory whatever the file says
        return _frames_of(path, _blf_messages(path))
    try:
        reader = can.LogReader(str(path))
    except Exception as exc:  # python-can raises many kinds for a damaged or foreign file
        raise ReplayError(f"{path}: cannot read as a CAN log ({type(exc).__name__}: {exc})"
                          ) from exc
    return _frames_of(path, reader)


def _blf_messages(path: Path) -> Iterator[can.Message]:
    """The frames of a BLF log as python-can's ``BLFReader`` gives them, read by
    ``harness.record.blf_frames`` (which bounds an object's and a container's size)."""
    from harness.record.blf_frames import read_frames

    for t, can_id, ext, remote, error, rx, dlc, data, channel in read_frames(path):
        yield can.Message(timestamp=t, arbitration_id=can_id, is_extended_id=ext,
                          is_remote_frame=remote, is_error_frame=error, is_rx=rx, dlc=dlc,
                          data=data, channel=channel)


def _frames_of(path: Path, reader: Iterable[can.Message]) -> Iterator[can.Message]:
    try:
        yield from reader
    except Exception as exc:  # a damaged container found part way through the file
        raise ReplayError(f"{path}: cannot read as a CAN log ({type(exc).__name__}: {exc})"
                          ) from exc
    finally:
        stop = getattr(reader, "stop", None)
        if callable(stop):
            stop()


def _decode(codec: FrameCodec, data: bytes) -> dict[str, float]:
    try:
        return codec.decode(data)
    except FrameError:
        return {}


class _Ticks:
    """A replay's ticks as they close: each tick's received frames through the drivers, its
    state and commands, the counts the report needs; kept only when asked (a streamed
    replay holds none), handed to ``on_tick`` as they come."""

    def __init__(self, iface: RigInterface, dt_s: float,
                 on_tick: Callable[[RigInterface, ReplayTick], None] | None,
                 keep: bool) -> None:
        self.iface, self.dt_s, self.on_tick, self.keep = iface, dt_s, on_tick, keep
        self.ticks: list[ReplayTick] = []
        self.n = self.missing = 0
        self.first: int | None = None
        self.last: int | None = None
        self.t0 = self.t1 = 0.0

    def close(self, tick: int, rx: list[can.Message], cmds: list[CommandFrame]) -> None:
        iface = self.iface
        got = sum(iface.feed(msg, tick) for msg in rx)
        state = copy.copy(iface.snapshot(tick, tick * self.dt_s))
        t = ReplayTick(tick, tick * self.dt_s, state, list(cmds), got,
                       max(0, iface.expected_frames(tick) - got))
        if self.keep:
            self.ticks.append(t)
        self.n += 1
        if self.first is None:
            self.first, self.t0 = tick, t.time_s
        self.last, self.t1 = tick, t.time_s
        self.missing += t.missing
        if self.on_tick is not None:
            self.on_tick(iface, t)

    def totals(self) -> dict[str, Any]:
        return {"n_ticks": self.n, "first_tick": self.first, "last_tick": self.last,
                "first_time_s": self.t0, "last_time_s": self.t1,
                "missing_total": self.missing}


def replay_messages(messages: Iterable[can.Message], rig: RigConfig, dt_s: float,
                    source: Path = Path("-"), protocol: Protocol | None = None,
                    on_tick: Callable[[RigInterface, ReplayTick], None] | None = None,
                    keep_ticks: bool = True) -> Replay:
    """Split ``messages`` into ticks at each SYNC and decode them with the harness's drivers.
    ``on_tick(interface, tick)`` is called after each tick's frames went through the drivers
    (the fault monitor's re-run, the check and the recording of a streamed replay use it).
    ``keep_ticks=False``: the ticks are not kept (``Replay.ticks`` stays empty), so memory
    does not grow with the capture."""
    protocol = protocol or load_protocol()
    iface, bus = _interface(protocol, rig)
    binding = rig.binding
    if not binding.is_sgsrt():
        # another binding (a vendor DBC, CANopen): SYNC, heartbeat and commands are the
        # binding's frames; CANopen's NMT and SDO requests are the harness's too
        return _replay_binding(messages, rig, dt_s, source, iface, on_tick, keep_ticks)
    tx_ids = harness_frame_ids(protocol)
    sync = protocol["SYNC"]
    frames_by_id: Counter[int] = Counter()
    harness_malformed: Counter[str] = Counter()
    closer = _Ticks(iface, dt_s, on_tick, keep_ticks)
    sync_gaps = before = 0
    tick: int | None = None
    rx: list[can.Message] = []
    cmds: list[CommandFrame] = []

    def close_tick() -> None:
        if tick is not None:
            closer.close(tick, rx, cmds)

    fi_key = binding.fault_insertion
    if fi_key is not None:
        tx_ids = tx_ids | {fi_key[0]}
    for msg in messages:
        if not msg.is_error_frame:
            frames_by_id[msg.arbitration_id] += 1
            if (msg.arbitration_id, msg.is_extended_id) == fi_key:
                continue  # the fault-insertion unit's frame: neither telemetry nor command
        harness = not msg.is_error_frame and msg.arbitration_id in tx_ids
        if harness and msg.arbitration_id == sync.frame_id:
            close_tick()
            rx, cmds = [], []
            values = _decode(sync, bytes(msg.data))
            if not values:
                harness_malformed["SYNC"] += 1
            new = int(values["tick"]) if values else (tick + 1 if tick is not None else 0)
            if tick is not None and new != tick + 1:
                sync_gaps += 1
            tick = new
            continue
        if tick is None:
            before += not harness
            continue
        if harness:
            codec = protocol.by_id[msg.arbitration_id]
            values = _decode(codec, bytes(msg.data))
            if not values:
                harness_malformed[codec.name] += 1
            if codec.name in COMMAND_FRAMES:
                cmds.append(CommandFrame(codec.name, bytes(msg.data), values))
        else:
            rx.append(msg)
    close_tick()
    malformed = {d.telemetry_frame: d.counters.malformed for d in iface.drivers.values()}
    malformed.update(harness_malformed)
    return Replay(
        source=source, dt_s=dt_s, ticks=closer.ticks, frames_by_id=dict(frames_by_id),
        harness_ids=tx_ids, error_frames=iface.counters.error_frames,
        bus_off=iface.counters.bus_off, unknown=iface.counters.unknown, malformed=malformed,
        sequence_errors={n: d.counters.sequence_errors for n, d in iface.drivers.items()},
        sync_gaps=sync_gaps, before_first_sync=before, **closer.totals())


def _replay_binding(messages: Iterable[can.Message], rig: RigConfig, dt_s: float,
                    source: Path, iface: RigInterface,
                    on_tick: Callable[[RigInterface, ReplayTick], None] | None,
                    keep_ticks: bool) -> Replay:
    """``replay_messages`` for a rig whose devices bind a DBC of their own or CANopen: every
    frame decoded through the rig file's binding (commands by device and quantity, the SYNC
    counter unwrapped into the tick), CANopen's service frames counted by name."""
    b = rig.binding
    sync, hb = b.sync, b.heartbeat
    cmd = b.commands_by_key()
    modulus = int(getattr(sync, "modulus", 1 << 32))
    co = b.canopen
    service = Counter()
    frames_by_id: Counter[int] = Counter()
    harness_malformed: Counter[str] = Counter()
    fi_key = b.fault_insertion
    tx_ids: set[int] = {sync.key[0]} | ({hb.key[0]} if hb is not None else set()) | {
        k[0] for k in cmd} | ({fi_key[0]} if fi_key is not None else set())
    closer = _Ticks(iface, dt_s, on_tick, keep_ticks)
    sync_gaps = before = 0
    tick: int | None = None
    raw_last: int | None = None
    rx: list[can.Message] = []
    cmds: list[CommandFrame] = []

    def close_tick() -> None:
        if tick is not None:
            closer.close(tick, rx, cmds)

    for msg in messages:
        if msg.is_error_frame:
            rx.append(msg)
            continue
        frames_by_id[msg.arbitration_id] += 1
        key = (msg.arbitration_id, msg.is_extended_id)
        data = bytes(msg.data)
        if key == sync.key:
            close_tick()
            rx, cmds = [], []
            try:
                raw = sync.decode(data)
            except (FrameError, IndexError):
                harness_malformed["SYNC"] += 1
                raw = (raw_last + 1) if raw_last is not None else 0
            new = raw if tick is None else tick + ((raw - raw_last) % modulus or modulus)
            if tick is not None and new != tick + 1:
                sync_gaps += 1
            tick, raw_last = new, raw
            continue
        if co is not None and not msg.is_extended_id and (
                msg.arbitration_id == 0 or msg.arbitration_id & 0x780 == 0x600):
            service["NMT" if msg.arbitration_id == 0 else "SDO request"] += 1
            tx_ids.add(msg.arbitration_id)
            continue
        if (hb is not None and key == hb.key) or key == fi_key:
            continue
        if key in cmd:
            if tick is None:
                continue
            for c in cmd[key]:
                try:
                    values = c.decode(data)
                except FrameError:
                    harness_malformed[c.codec.name] += 1
                    break
                if values is not None:
                    cmds.append(CommandFrame(c.codec.name, data, values))
            continue
        if tick is None:
            before += 1
            continue
        rx.append(msg)
    close_tick()
    malformed = {f"{n} telemetry": d.counters.malformed for n, d in iface.drivers.items()}
    malformed.update(harness_malformed)
    return Replay(
        source=source, dt_s=dt_s, ticks=closer.ticks, frames_by_id=dict(frames_by_id),
        harness_ids=frozenset(tx_ids), error_frames=iface.counters.error_frames,
        bus_off=iface.counters.bus_off, unknown=iface.counters.unknown, malformed=malformed,
        sequence_errors={n: d.counters.sequence_errors for n, d in iface.drivers.items()},
        sync_gaps=sync_gaps, before_first_sync=before, **closer.totals())


def replay_log(path: Path, rig: RigConfig, dt_s: float,
               on_tick: Callable[[RigInterface, ReplayTick], None] | None = None,
               keep_ticks: bool = True) -> Replay:
    return replay_messages(read_log(path), rig, dt_s, source=path, on_tick=on_tick,
                           keep_ticks=keep_ticks)


# ----------------------------------------------------------------------- run directories
def load_run_dir(run_dir: Path) -> tuple[RunConfig, dict[str, Any]]:
    """(the run's RunConfig rebuilt from config.yaml, summary.json or {}).

    The run section is validated again by ``run_from_dict`` and the rig is the resolved rig
    written in config.yaml (rig file and ``rig_overrides`` already merged), so the rig file
    the run named need not exist any more."""
    cfg_path = run_dir / "config.yaml"
    if not cfg_path.is_file():
        raise ReplayError(f"{cfg_path}: no such file (not a run directory)")
    from harness.record.run_folder import RunFolderError, load_run_folder
    from rig_models.yaml_file import load_yaml

    try:  # checked as every reader of a run folder checks it (rate, duration, sections)
        load_run_folder(run_dir)
    except RunFolderError as exc:
        raise ReplayError(str(exc)) from exc

    try:
        cfg = load_yaml(cfg_path, "config.yaml")  # bounded: a hand-edited copy may not be
    except ConfigError as exc:
        raise ReplayError(str(exc)) from exc
    if not isinstance(cfg, dict) or not isinstance(cfg.get("run"), dict) \
            or not isinstance(cfg.get("rig"), dict):
        raise ReplayError(f"{cfg_path}: expected the resolved run config (keys run, rig)")
    try:
        rig = rig_from_dict(cfg["rig"], source=f"{cfg_path}: rig")
        # the run's own rig reference may be a file that is gone: validate against the
        # built-in rig, then put the resolved rig (and the original keys) back
        raw = dict(cfg["run"], rig="sgsrt", rig_overrides=None)
        checked = run_from_dict(raw, source=f"{cfg_path}: run", check_files=False)
    except ConfigError as exc:
        raise ReplayError(str(exc)) from exc
    data = dict(checked.data, rig=cfg["run"].get("rig"),
                rig_overrides=cfg["run"].get("rig_overrides"))
    run = RunConfig(source=checked.source, data=data, rig=rig)
    summary: dict[str, Any] = {}
    sum_path = run_dir / "summary.json"
    if sum_path.is_file():
        from harness.record.summary_file import read_summary

        try:  # as the judge reads it: a field of the wrong shape is left out
            summary, _ = read_summary(sum_path)
        except ValueError as exc:
            raise ReplayError(f"{sum_path}: {exc}") from exc
        except OSError:
            summary = {}
    return run, summary


def split_commands(commands: list[CommandFrame]
                   ) -> tuple[list[CommandFrame], list[CommandFrame]]:
    """(the controller's command frames, the leave-safe frames) of one tick.

    The leave-safe group is all four command frames in ``command_safe``'s order, one
    counter, wheel disabled with zero torque, valves closed, piezo 0 V, rotor disabled at
    zero speed. ``command`` always enables the wheel, so a controller's all-zero command is
    never taken for it."""
    names = [c.name for c in commands]
    for i in range(len(commands) - len(COMMAND_FRAMES), -1, -1):
        group = commands[i:i + len(COMMAND_FRAMES)]
        if names[i:i + len(COMMAND_FRAMES)] == list(COMMAND_FRAMES) and _is_safe(group):
            return commands[:i] + commands[i + len(COMMAND_FRAMES):], group
    return list(commands), []


def _is_safe(group: list[CommandFrame]) -> bool:
    if any(c.malformed for c in group) or len({c.values["counter"] for c in group}) != 1:
        return False
    wheel, valve, piezo, rotor = (c.values for c in group)
    return (wheel["enable"] == 0 and wheel["torque_cmd"] == 0 and valve["valve_pos"] == 0
            and valve["valve_neg"] == 0 and piezo["voltage_ch1"] == 0
            and piezo["voltage_ch2"] == 0 and rotor["enable"] == 0 and rotor["speed_cmd"] == 0)


def _compare(codec: FrameCodec, logged: CommandFrame, replayed: bytes) -> str:
    """'' if equal within one quantisation step (integer signals exactly), else the first
    differing signal."""
    if logged.malformed:
        return f"logged payload of {len(logged.data)} bytes does not fit the DBC"
    want = codec.decode(replayed)
    for sig in codec.signals:
        integer = sig.scale == 1.0 and sig.offset == 0.0
        tol = 0.0 if integer else abs(sig.scale) * (1.0 + 1e-9)
        if abs(logged.values[sig.name] - want[sig.name]) > tol:
            return (f"{sig.name}: logged {logged.values[sig.name]:.9g}, "
                    f"replayed {want[sig.name]:.9g} {sig.unit}").rstrip()
    return ""


def check_replay(replay: Replay, run: RunConfig, dry_run: bool = False,
                 protocol: Protocol | None = None) -> CheckResult:
    """Step ``run``'s controller (built as ``execute_run`` builds it) on the replayed states
    and compare its encoded commands with the logged ones, tick by tick."""
    checker = ReplayChecker(run, dry_run, protocol)
    for t in replay.ticks:
        checker.feed(t)
    return checker.finish()


class ReplayChecker:
    """``check_replay`` one tick at a time (a streamed replay's ``on_tick``): memory does
    not grow with the capture. The last tick is told apart (a run that stopped before its
    commands went out), so each tick is checked when the next one arrives, the last one by
    ``finish()``."""

    def __init__(self, run: RunConfig, dry_run: bool = False,
                 protocol: Protocol | None = None) -> None:
        if not run.rig.binding.is_sgsrt():
            # the comparison reads sgsrt's command frames and its leave-safe group; on
            # another binding it would compare nothing and call that consistent
            raise ReplayError(f"--check: {run.rig.name} binds its devices to "
                              f"{', '.join(sorted(set(run.rig.binding.kinds.values())))}; the "
                              "controller check compares sgsrt command frames only (replay "
                              "without --check decodes this rig's frames)")
        self.protocol = protocol or load_protocol()
        self.controller = build_controller(run)
        self.enc, self.bus = _interface(self.protocol, run.rig, run.actuators,
                                        dry_run=dry_run)
        self.out = CheckResult()
        self._held: ReplayTick | None = None

    def __call__(self, iface: RigInterface, t: ReplayTick) -> None:
        self.feed(t)

    def feed(self, t: ReplayTick) -> None:
        if self._held is not None:
            self._step(self._held, last=False)
        self._held = t

    def finish(self) -> CheckResult:
        if self._held is not None:
            self._step(self._held, last=True)
            self._held = None
        return self.out

    def _step(self, t: ReplayTick, last: bool) -> None:
        out, protocol, bus = self.out, self.protocol, self.bus
        logged, safe = split_commands(t.commands)
        if safe:
            out.safe_tick = t.tick
        bus.sent.clear()
        try:
            self.enc.command(self.controller.step(t.state))
        except Exception as exc:  # the run's controller failed at this tick
            if last and not logged:
                out.skipped.append((t.tick, f"the controller raised {type(exc).__name__}: "
                                    f"{exc}; the run sent no command in this tick either"))
                return
            out.ticks_compared += 1
            _mismatch(out, Mismatch(t.tick, t.time_s, "(controller)", None, None,
                                    f"the controller raised {type(exc).__name__}: {exc}"))
            return
        sent = [(protocol.by_id[m.arbitration_id], bytes(m.data)) for m in bus.sent]
        if last and sent and not logged:
            out.skipped.append((t.tick, "no controller command in the log: the run stopped "
                                "before this tick's commands went out"
                                + (" (only the safe commands)" if safe else "")))
            return
        out.ticks_compared += 1
        if [c.name for c in logged] != [c.name for c, _ in sent]:
            _mismatch(out, Mismatch(
                t.tick, t.time_s, "(frames)", [c.name for c in logged],
                [c.name for c, _ in sent], "the command frames sent differ"))
            return
        pairs = list(zip(logged, sent, strict=True))
        bad = [(c.name, d) for c, (codec, data) in pairs if (d := _compare(codec, c, data))]
        if bad:
            name, detail = bad[0]
            k = [c.name for c in logged].index(name)
            _mismatch(out, Mismatch(t.tick, t.time_s, name, logged[k].values,
                                    sent[k][0].decode(sent[k][1]), detail))
            return
        out.ticks_matching += 1
        if all(c.data == data for c, (_, data) in pairs):
            out.ticks_identical += 1


def _mismatch(out: CheckResult, m: Mismatch) -> None:
    if out.first_mismatch is None:
        out.first_mismatch = m


class MonitorReplay:
    """The run's fault monitor re-run on the replayed ticks (``on_tick`` of the replay): the
    same checks on the same driver state as in the run, with the valve direction the logged
    VALVE_CMD carried. Its first event is compared with summary.json's first fault."""

    def __init__(self, run: RunConfig, realtime: bool, dry_run: bool) -> None:
        self.run = run
        self.realtime = realtime
        self.dry_run = dry_run
        self.monitor: Any = None
        self.first: FaultEvent | None = None

    def __call__(self, iface: RigInterface, t: ReplayTick) -> None:
        if self.first is not None:
            return  # the run stopped at its first fault
        if self.monitor is None:
            from harness.core.session import make_monitor  # the run's own construction

            self.monitor = make_monitor(self.run, iface, realtime=self.realtime)
        sent = RigCommand()
        logged, _ = split_commands(t.commands)
        valve = next((c.values for c in logged if c.name == "VALVE_CMD" and c.values), None)
        if valve is not None and not self.dry_run:
            sent.valve_direction = int(valve["valve_pos"]) - int(valve["valve_neg"])
        wheel = next((c.values for c in logged if c.name == "WHEEL_CMD" and c.values), None)
        if wheel is not None and not self.dry_run and wheel.get("enable", 1):
            # the torque the run sent: the monitor's physics checks integrate it
            sent.wheel_torque_n_m = float(wheel["torque_cmd"])
        self.first = self.monitor.check(t.tick, t.state, sent)


def _same_event(replayed: FaultEvent | None, logged: dict[str, Any] | None) -> bool:
    if replayed is None or logged is None:
        return replayed is None and logged is None
    return (replayed.tick == logged.get("tick") and replayed.device == logged.get("device")
            and replayed.kind == logged.get("kind"))


def apply_monitor(result: CheckResult, monitor: MonitorReplay | None,
                  summary: dict[str, Any]) -> None:
    """Put the monitor's re-run beside summary.json's first fault in ``result``."""
    if monitor is None:
        return
    faults = summary.get("faults") or []
    result.monitor_event = monitor.first
    result.logged_fault = faults[0] if faults else None
    result.monitor_consistent = _same_event(monitor.first, result.logged_fault)


def check_run(run_dir: Path, log: Path | None = None) -> tuple[Replay, CheckResult]:
    """Replay a run directory's CAN log (or ``log``, e.g. a copy) with its rig and rate,
    check its controller's commands against the logged ones, and re-run its fault monitor."""
    run, summary = load_run_dir(run_dir)
    dry_run = bool(summary.get("dry_run", False))
    monitor = MonitorReplay(run, realtime=summary.get("clock") == "realtime", dry_run=dry_run)
    replay = replay_log(log or run_dir / "can.blf", run.rig, run.dt_s, on_tick=monitor)
    result = check_replay(replay, run, dry_run=dry_run)
    result.stopped_by = summary.get("stopped_by")
    result.summary_ticks = summary.get("ticks")
    apply_monitor(result, monitor, summary)
    return replay, result


# ----------------------------------------------------------------------- recording
TELEMETRY_CHANNELS: dict[str, Any] = {
    "/attitude/angle_deg": lambda s: math.degrees(s.hub_angle_rad),
    "/attitude/rate_deg_s": lambda s: math.degrees(s.hub_rate_rad_s),
    "/wheel/torque_n_m": lambda s: s.wheel_torque_n_m,
    "/wheel/speed_rad_s": lambda s: s.wheel_speed_rad_s,
    "/tip/accel_m_s2": lambda s: s.tip_accel_m_s2,
    "/thrusters/valve_state": lambda s: s.valve_state,
    "/thrusters/firings": lambda s: s.valve_firings,
    "/thrusters/on_time_s": lambda s: s.valve_on_time_s,
    "/piezo/sensor_ch1_v": lambda s: s.piezo_sensor_v[0],
    "/piezo/sensor_ch2_v": lambda s: s.piezo_sensor_v[1],
    "/rotor/angle_rad": lambda s: s.rotor_angle_rad,
    "/rotor/speed_rad_s": lambda s: s.rotor_speed_rad_s,
}
# channel -> (command frame, value from its decoded signals); NaN when not sent that tick
COMMAND_CHANNELS: dict[str, tuple[str, Any]] = {
    "/wheel/torque_cmd_n_m": ("WHEEL_CMD", lambda v: v["torque_cmd"]),
    "/wheel/enable_cmd": ("WHEEL_CMD", lambda v: v["enable"]),
    "/thrusters/valve_cmd": ("VALVE_CMD", lambda v: v["valve_pos"] - v["valve_neg"]),
    "/piezo/cmd_ch1_v": ("PIEZO_CMD", lambda v: v["voltage_ch1"]),
    "/piezo/cmd_ch2_v": ("PIEZO_CMD", lambda v: v["voltage_ch2"]),
    "/rotor/speed_cmd_rad_s": ("ROTOR_CMD", lambda v: v["speed_cmd"]),
    "/rotor/enable_cmd": ("ROTOR_CMD", lambda v: v["enable"]),
}
REPLAY_CHANNELS = [*TELEMETRY_CHANNELS, *COMMAND_CHANNELS, "/timing/frames_rx"]


def write_rrd(replay: Replay, path: Path, recording_name: str | None = None) -> Path:
    """The replayed telemetry and the controller's command frames (the leave-safe group
    left out, as run.rrd records them) as scalar channels on the ``time`` timeline
    (tick * dt), with the entity paths of run.rrd."""
    writer = ReplayRecording(path, recording_name or replay_recording_name(replay.source))
    try:
        for t in replay.ticks:
            writer.feed(t)
    finally:
        writer.close()
    return path


def replay_recording_name(source: Path) -> str:
    return f"replay-{source.parent.name or source.name}"


class ReplayRecording:
    """``write_rrd`` one tick at a time (a streamed replay's ``on_tick``)."""

    def __init__(self, path: Path, recording_name: str) -> None:
        from harness.review.annotations import ReviewAnnotator

        self.path = path
        self.rec = Recorder(path, REPLAY_CHANNELS, 1, recording_name,
                            annotator=ReviewAnnotator())

    def __call__(self, iface: RigInterface, t: ReplayTick) -> None:
        self.feed(t)

    def feed(self, t: ReplayTick) -> None:
        rec = self.rec
        row = rec.row(t.time_s)
        ctrl = {c.name: c.values for c in split_commands(t.commands)[0] if not c.malformed}
        row[:] = (
            *(f(t.state) for f in TELEMETRY_CHANNELS.values()),
            *(get(ctrl[name]) if name in ctrl else math.nan
              for name, get in COMMAND_CHANNELS.values()),
            t.telemetry_frames,
        )
        rec.commit()
        rec.drain()

    def close(self) -> None:
        self.rec.close()


def frame_names(rig: RigConfig | None) -> dict[int, tuple[str, str]]:
    """id -> (name, who sends it) by the rig's binding: sgsrt's DBC, a vendor DBC's
    messages, CANopen's PDOs and service frames (NMT, SYNC, EMCY, SDO, heartbeat) by node."""
    if rig is None or rig.binding.is_sgsrt():
        protocol = load_protocol()
        out = {c.frame_id: (c.name, "device") for c in protocol.by_id.values()}
        if rig is not None and rig.binding.fault_insertion is not None:
            out[rig.binding.fault_insertion[0]] = (FAULT_INSERTION_NAME, "harness")
        return out
    b = rig.binding
    out = {}
    if b.fault_insertion is not None:
        out[b.fault_insertion[0]] = (FAULT_INSERTION_NAME, "harness")
    for f in b.frames():
        who = "harness" if f.kind in ("sync", "heartbeat", "cmd") else f.device
        out[f.key[0]] = (f.name if f.kind != "tlm" else f"{f.name} ({f.device})", who)
    if b.canopen is not None:
        out[0x000] = ("NMT", "harness")
        for nid in b.canopen.nodes:
            dev = b.canopen.device_of_node(nid)
            out[0x080 + nid] = (f"EMCY node {nid}", dev)
            out[0x580 + nid] = (f"SDO response node {nid}", dev)
            out[0x600 + nid] = (f"SDO request node {nid}", "harness")
            out[0x700 + nid] = (f"heartbeat node {nid}", dev)
    return out


def report_dict(replay: Replay, rig_name: str, result: CheckResult | None,
                rig: RigConfig | None = None) -> dict[str, Any]:
    """The replay's report as ``harness replay --json`` prints it: every frame id with its
    name, sender and count, what was malformed or missing, and the check's result."""
    names = frame_names(rig)
    frames = []
    for fid, n in sorted(replay.frames_by_id.items()):
        name, who = names.get(fid, ("?", "unknown"))
        frames.append({"id": f"0x{fid:03X}", "name": name,
                       "from": "harness" if fid in replay.harness_ids else who, "frames": n})
    out: dict[str, Any] = {
        "log": str(replay.source), "rig": rig_name, "rate_hz": 1.0 / replay.dt_s,
        "ticks": replay.n_ticks, "first_tick": replay.first_tick,
        "last_tick": replay.last_tick,
        "duration_s": replay.last_time_s - replay.first_time_s, "frames": frames,
        "total_frames": replay.total_frames, "malformed": sum(replay.malformed.values()),
        "malformed_by_frame": {k: v for k, v in replay.malformed.items() if v},
        "unknown_ids": replay.unknown, "error_frames": replay.error_frames,
        "bus_off": replay.bus_off, "sync_gaps": replay.sync_gaps,
        "sequence_errors": {k: v for k, v in replay.sequence_errors.items() if v},
        "missing_telemetry": replay.missing_frames,
        "before_first_sync": replay.before_first_sync,
    }
    if result is not None:
        m = result.first_mismatch
        out["check"] = {
            "consistent": result.consistent, "ticks_compared": result.ticks_compared,
            "ticks_matching": result.ticks_matching,
            "ticks_identical": result.ticks_identical,
            "first_mismatch": None if m is None else {
                "tick": m.tick, "time_s": m.time_s, "frame": m.frame, "detail": m.detail,
                "logged": _tidy(m.logged), "replayed": _tidy(m.replayed)},
            "skipped": [{"tick": k, "reason": r} for k, r in result.skipped],
            "safe_commands_tick": result.safe_tick, "stopped_by": result.stopped_by,
            "summary_ticks": result.summary_ticks,
            "monitor": {
                "consistent": result.monitor_consistent,
                "replayed_first_fault": None if result.monitor_event is None
                else result.monitor_event.to_dict(),
                "logged_first_fault": result.logged_fault},
        }
    return out


def _tidy(v: Any) -> Any:
    """Decoded values to 9 significant digits (0.00028, not 0.00028000000000000003)."""
    return {k: float(f"{x:.9g}") for k, x in v.items()} if isinstance(v, dict) else v
