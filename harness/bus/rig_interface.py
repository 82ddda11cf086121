"""All device drivers on one bus: SYNC/heartbeat out, telemetry in, commands out.

Every frame sent or received goes to the run's CAN log. Unknown ids and malformed frames
are counted, never raised.
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import can

from drivers.accelerometer import AccelerometerDriver
from drivers.base import DeviceDriver
from drivers.binding import RigBinding
from drivers.binding.frames import SyncMap, TelemetryMap
from drivers.dbc import FrameError, Protocol
from drivers.disturbance_rotor import DisturbanceRotorDriver
from drivers.hub_sensor import HubSensorDriver
from drivers.piezo_amplifier import PiezoAmplifierDriver
from drivers.reaction_wheel import ReactionWheelDriver
from drivers.thruster_valves import ThrusterValvesDriver
from harness.record.can_log import CanLog
from harness.state import SAFE_COMMAND, RigCommand, RigState
from rig_models.faults import FaultSpec, encode_fault_clear, encode_fault_insertion
from rig_models.rig_file import RigConfig
from rig_models.schema import ConfigError

CAN_ERR_BUSOFF = 0x040  # SocketCAN error class (linux/can/error.h)
KERNEL_SYNC_BACKLOG = 1000
"""Kernel-sent SYNCs kept for a loop that fell behind (their time stamps)."""
HARNESS_HEARTBEAT_LOST = "harness heartbeat lost"
"""The kind of a CANopen node's EMCY 0x8130 about the harness's own heartbeat (it came late
at the node: on the wall clock after a tick the loop held back, the bench's doing)."""
DUPLICATE_HB_COUNT = 8
DUPLICATE_HB_PERIODS = 5.0
"""A node id used twice: this many heartbeats within this many of the node's periods (a
healthy node needs 7 periods for 8 heartbeats; a late one followed by an on-time one bunches
two, not four)."""


def own_transmit_keys(b: RigBinding) -> dict[tuple[int, bool], str]:
    """(id, extended) -> what it is, for every frame only the harness sends on this rig's
    bus: SYNC, its heartbeat, every command frame (bound or not in this run), and on a
    CANopen bus NMT commands and SDO requests to its nodes. Telemetry ids are never in it."""
    out: dict[tuple[int, bool], str] = {b.sync.key: "SYNC"}
    if b.heartbeat is not None:
        out[b.heartbeat.key] = "master heartbeat"
    for device, maps in b.commands.items():
        for m in maps:
            out[m.key] = f"{device} command"
    if b.canopen is not None:
        out[(0x000, False)] = "NMT command"
        for nid in b.canopen.nodes:
            out[(0x600 + nid, False)] = f"SDO request to node {nid}"
    for key in b.telemetry_by_key():
        out.pop(key, None)
    return out


@dataclass
class BusCounters:
    sent: int = 0
    received: int = 0
    unknown: int = 0
    error_frames: int = 0
    send_errors: int = 0
    bus_off: bool = False
    last_unknown_id: int = 0
    # frames with an id only the harness sends (SYNC, NMT, heartbeat, commands, SDO
    # requests): another master on the bus; the first one is described for the fault
    foreign: int = 0
    first_foreign: str = ""


class RigInterface:
    """Every device of the rig on one bus, through the rig file's binding (sgsrt, any DBC,
    CANopen): SYNC and heartbeat out, telemetry decoded into the drivers' quantities,
    commands encoded from RigCommand. ``protocol`` is the sgsrt protocol the drivers' own
    ``handle``/``encode`` helpers use; the frames come from ``rig.binding``."""

    def __init__(
        self,
        bus: can.BusABC,
        protocol: Protocol,
        rig: RigConfig,
        can_log: CanLog | None,
        actuators: tuple[str, ...] = ("reaction_wheel",),
        dry_run: bool = False,
    ) -> None:
        self.bus = bus
        self.protocol = protocol
        self.binding: RigBinding = rig.binding
        self.can_log = can_log
        self.actuators = actuators
        self.dry_run = dry_run
        self.counters = BusCounters()
        self.hub = HubSensorDriver(protocol)
        self.accel = AccelerometerDriver(protocol)
        self.wheel = ReactionWheelDriver(
            protocol, max_torque_n_m=rig.section("reaction_wheel")["max_torque_n_m"])
        self.valves = ThrusterValvesDriver(protocol)
        self.piezo = PiezoAmplifierDriver(
            protocol, max_voltage_v=rig.section("piezo_amplifier")["max_voltage_v"])
        self.rotor = DisturbanceRotorDriver(
            protocol, max_speed_rad_s=rig.section("disturbance_rotor")["max_speed_rad_s"])
        div = rig.data["bus"]["sync_divider"]
        every: dict[str, DeviceDriver] = {
            "hub_sensor": self.hub, "accelerometer": self.accel, "reaction_wheel": self.wheel,
            "thruster_valves": self.valves, "piezo_amplifier": self.piezo,
            "disturbance_rotor": self.rotor,
        }
        b = self.binding
        # a device the rig does not have (binding none) is neither expected nor stale
        self.drivers: dict[str, DeviceDriver] = {n: every[n] for n in b.bound}
        for name, drv in self.drivers.items():
            drv.stale_after_ticks = 2 * div[name] + 1
            drv.sequence = b.sequence.get(name)
            drv.multi_frame = len(b.telemetry[name]) > 1
        self.divider = {n: div[n] for n in self.drivers}
        # frames due per tick: each distinct telemetry frame (or multiplexed page) once, at
        # its device's divider (a CANopen TPDO may carry two devices' quantities)
        groups: dict[int, set[tuple[tuple[int, bool], int | None]]] = {}
        for n in self.drivers:
            for m in b.telemetry[n]:
                groups.setdefault(div[n], set()).add((m.key, m.mux))
        self._due_groups = tuple((d, len(keys)) for d, keys in groups.items())
        # (id, extended) -> [(frame map, its driver)]
        self._by_key: dict[tuple[int, bool], tuple[tuple[TelemetryMap, DeviceDriver], ...]] = {
            k: tuple((m, every[m.device]) for m in maps)
            for k, maps in b.telemetry_by_key().items()}
        # id -> (decode, driver): a standard-id frame of one device, not multiplexed (its
        # decode never returns None): the sgsrt protocol's identity-mapped frames (the
        # codec's own dict), a CANopen TPDO of one device (its compiled decoder), ...
        self._fast = {k[0]: (v[0][0].codec.decode if v[0][0].identity else v[0][0].decode,
                             v[0][1])
                      for k, v in self._by_key.items()
                      if len(v) == 1 and not k[1] and v[0][0].mux is None}
        self._driver_items = tuple(self.drivers.items())
        sync = b.sync
        if isinstance(sync, SyncMap):  # a DBC's SYNC: its counter through a positional encoder
            sync_encode, modulus = sync.codec.encoder((sync.signal,)), sync.modulus
            self._sync_payload: Callable[[int], bytes] = lambda tick: sync_encode(tick % modulus)
        else:
            self._sync_payload = sync.encode
        self._commands = b.commands
        # the fault-insertion unit's frame (bus.fault_insertion_id; None: the rig has none):
        # sent by insert_fault, never an unknown id when read back (an echo, a replay)
        self.fault_insertion_key = b.fault_insertion
        self.rig_source = rig.source
        # the ids only a master sends: a frame with one of them that the harness did not
        # send comes from another master (one SYNC producer, one NMT master per network)
        self.own_ids = own_transmit_keys(b)
        # each actuator's command frames as positional encoders of its driver's
        # ``command_args`` and the counter (no dict per frame: the tick's cost)
        self._command_encoders: dict[str, tuple[tuple[Callable[..., bytes],
                                                      tuple[int, bool]], ...]] = {
            device: tuple((cmap.encoder(every[device].command_quantities), cmap.key)
                          for cmap in cmaps)
            for device, cmaps in b.commands.items() if device in every}
        self._wheel_on = "reaction_wheel" in actuators
        self._valves_on = "thruster_valves" in actuators
        self._piezo_on = "piezo_amplifier" in actuators
        self._rotor_on = "disturbance_rotor" in actuators
        # CANopen: the nodes' heartbeats, boot-ups and EMCYs are watched here (the frames
        # are not telemetry); a fault among them waits in protocol_events for the monitor
        self.co = b.canopen
        # only a CANopen bus reports protocol faults (the monitor asks only then)
        self.has_protocol_faults = self.co is not None
        self.protocol_events: list[tuple[str, str, str]] = []
        self._hb_tick: dict[int, int] = {}
        # the ticks of each node's last heartbeats (a second node with the same id doubles
        # them: DUPLICATE_HB_COUNT within DUPLICATE_HB_PERIODS of its periods)
        self._hb_recent: dict[int, list[float]] = {}
        self._dt_s = 0.0
        self._hb_wall = False
        # heartbeats queued during the set-up arrive in a burst in the first ticks: counted
        # for the duplicate rule only from this tick (the monitor's start-up)
        self._hb_dup_from = 0
        self._hb_dup_windows: dict[int, int] = {}
        self._hb_timeout_ticks: dict[int, int] = {}
        # no heartbeat can be missing up to this tick (None: look at every node)
        self._hb_quiet_until: int | None = None
        self._counter = 0
        self._hb_counter = 0
        # timing on the wire (``start_wire_timing``), off until the loop turns it on: the
        # tick's frames as (driver, time stamp), this tick's SYNC time stamp (the kernel's
        # echo, or the send time), the last command frame's, and the last one's before the
        # SYNC (its margin)
        self.wire_rx: list[tuple[DeviceDriver, float]] | None = None
        self.wire_sync_ts = math.nan
        self.wire_cmd_ts = math.nan
        self.wire_prev_cmd_ts = math.nan
        # the payload of the last SYNC sent: its echo is known by it, so an echo that comes
        # only after the next SYNC went out (a stalled host) times no tick (late_sync_echoes)
        self._sync_sent = b""
        self.late_sync_echoes = 0
        self._wire_own = False  # frames to look at first: the echo, the kernel's SYNC
        self._echo = False
        self._sender_ts = False
        self._cmd_keys = frozenset(m.key for maps in b.commands.values() for m in maps)
        self.device_of_driver = {id(drv): name for name, drv in self.drivers.items()}
        # SYNC sent by the kernel's broadcast manager (``start_kernel_sync``): its task and
        # the SYNCs seen and not yet taken by the loop, as (time stamp, last command before)
        self.kernel_sync: can.broadcastmanager.CyclicSendTaskABC | None = None
        self._kernel_syncs: deque[tuple[float, float]] = deque(maxlen=KERNEL_SYNC_BACKLOG)
        self.kernel_syncs_read = 0
        self.state = RigState()
        # the drivers' values dicts the state was last read from (snapshot)
        self._snapshot_seen: list[dict[str, float] | None] = [None] * 6

    # ------------------------------------------------------------------ sending
    def _send_key(self, key: tuple[int, bool], data: bytes,
                  best_effort: bool = False) -> can.Message | None:
        """Send one frame; a frame the bus refuses is counted (``send_errors``). With
        ``best_effort`` (the safe state, the disarming heartbeat) a transport that fails
        outright (``OSError``: the other end of a socket gone) is counted too, so that every
        frame of the safe state is tried and none raises."""
        msg = can.Message(arbitration_id=key[0], data=data, is_extended_id=key[1],
                          timestamp=time.time(), is_rx=False)
        try:
            self.bus.send(msg)
        except can.CanError:
            self.counters.send_errors += 1
            return None
        except OSError:
            if not best_effort:
                raise
            self.counters.send_errors += 1
            return None
        self.counters.sent += 1
        if self.can_log is not None:
            self.can_log.log(msg)
        return msg

    def _send_args(self, device: str, args: tuple[float, ...], counter: int) -> None:
        """The device's command frames from its driver's ``command_args`` (``_send_key``
        inline: every tick)."""
        for encode, (aid, ext) in self._command_encoders[device]:
            msg = can.Message(arbitration_id=aid, data=encode(*args, counter),
                              is_extended_id=ext, timestamp=time.time(), is_rx=False)
            try:
                self.bus.send(msg)
            except can.CanError:
                self.counters.send_errors += 1
                continue
            self.counters.sent += 1
            if self._sender_ts:
                self.wire_cmd_ts = msg.timestamp
            if self.can_log is not None:
                self.can_log.log(msg)

    def send_sync(self, tick: int) -> None:
        """The SYNC of ``tick``; with the kernel sending SYNC, the payload (counter) of the
        next one instead: the number of kernel SYNCs read so far, the next one's index on
        the wire (the broadcast manager sends the task's data as it is)."""
        task = self.kernel_sync
        if task is not None:
            key = self.binding.sync.key
            try:
                task.modify_data(can.Message(  # type: ignore[attr-defined]
                    arbitration_id=key[0], is_extended_id=key[1],
                    data=self._sync_payload(self.kernel_syncs_read)))
            except can.CanError:
                self.counters.send_errors += 1
            return
        self.wire_sync_ts = math.nan  # the echo's (or this send's) time stamp
        self._sync_sent = payload = self._sync_payload(tick)
        msg = self._send_key(self.binding.sync.key, payload)
        if msg is not None and self._sender_ts:
            self.wire_prev_cmd_ts = self.wire_cmd_ts
            self.wire_sync_ts = msg.timestamp

    # ------------------------------------------------------------------ on the wire
    def start_wire_timing(self) -> str:
        """Time stamps of every frame from now on, for timing on the wire; returns their
        source: "kernel" (SocketCAN: the kernel's receive time stamps and its echo of the
        harness's own frames) or "sender" (every other bus: each frame's sender's clock,
        the harness's own frames stamped at send())."""
        enable = getattr(self.bus, "enable_echo", None)
        self.wire_rx = []
        if enable is not None:
            enable()
            self._echo = self._wire_own = True
            return "kernel"
        self._sender_ts = True
        return "sender"

    def start_kernel_sync(self, dt_s: float) -> None:
        """SYNC every ``dt_s`` from the kernel's broadcast manager (SocketCAN only; the
        caller has checked ``has_broadcast_manager``), starting with tick 0's payload."""
        key = self.binding.sync.key
        self._wire_own = True
        self.kernel_sync = self.bus.send_periodic(
            can.Message(arbitration_id=key[0], is_extended_id=key[1],
                        data=self._sync_payload(0)), dt_s)

    def stop_kernel_sync(self) -> None:
        task, self.kernel_sync = self.kernel_sync, None
        if task is not None:
            task.stop()

    def wait_kernel_sync(self, tick: int, timeout_s: float) -> float | None:
        """Read frames (fed as received during the previous tick) until a kernel-sent SYNC
        is there; its time stamp (kernel time, ``time.time()``'s clock), or None when none
        came within ``timeout_s``."""
        q = self._kernel_syncs
        deadline = time.monotonic() + timeout_s
        recv, feed = self.bus.recv, self.feed
        while not q:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return None
            msg = recv(remaining)
            if msg is None:
                return None
            feed(msg, max(0, tick - 1))
        ts, prev_cmd = q.popleft()
        self.wire_sync_ts, self.wire_prev_cmd_ts = ts, prev_cmd
        return ts

    def _own_frame(self, msg: can.Message) -> bool:
        """The kernel's echo of a frame the harness sent, or a SYNC its broadcast manager
        sent: its time stamp noted (never a received frame, never another master's). True
        if it was one."""
        key = (msg.arbitration_id, msg.is_extended_id)
        if self.kernel_sync is not None and key == self.binding.sync.key:
            # from the broadcast manager's own socket: logged as the harness's transmission
            self._kernel_syncs.append((msg.timestamp, self.wire_cmd_ts))
            self.kernel_syncs_read += 1
            self.counters.sent += 1
            if self.can_log is not None:
                msg.is_rx = False
                self.can_log.log(msg)
            return True
        if not self._echo or msg.is_rx:
            return False
        if key == self.binding.sync.key:
            if bytes(msg.data) != self._sync_sent:  # an earlier SYNC's echo, come late
                self.late_sync_echoes += 1
                return True
            self.wire_prev_cmd_ts = self.wire_cmd_ts
            self.wire_sync_ts = msg.timestamp
        elif key in self._cmd_keys:
            self.wire_cmd_ts = msg.timestamp
        return True

    def insert_fault(self, spec: FaultSpec) -> can.Message | None:
        """Send the fault-insertion frame of ``spec`` (its ``at_s`` is not sent: the rig
        starts the fault at its next SYNC, a fault inserted in tick k acts from tick k + 1)
        the way commands go, so the run's CAN log has it as a sent frame. The frame sent
        (None: the bus refused it, counted in ``send_errors``). ``ConfigError`` if the rig
        has no fault-insertion unit or the frame cannot carry ``spec``."""
        return self._send_key(self._fault_insertion(), encode_fault_insertion(spec))

    def clear_faults(self) -> can.Message | None:
        """Send the fault-insertion frame that ends every fault of the rig (given at start
        or inserted) from its next SYNC on."""
        return self._send_key(self._fault_insertion(), encode_fault_clear())

    def _fault_insertion(self) -> tuple[int, bool]:
        key = self.fault_insertion_key
        if key is None:
            raise ConfigError(f"{self.rig_source}: bus.fault_insertion_id: absent: this rig "
                              "has no fault-insertion unit (a fault cannot be inserted at "
                              "run time)")
        return key

    def send_heartbeat(self, armed: bool) -> None:
        self._hb_counter = (self._hb_counter + 1) & 0xFF
        armed = armed and not self.dry_run
        hb = self.binding.heartbeat
        if hb is not None:
            self._send_key(hb.key, hb.encode(self._hb_counter, armed), best_effort=not armed)

    def _send_command(self, device: str, values: dict[str, float], counter: int,
                      best_effort: bool = False) -> None:
        for cmap in self._commands[device]:
            self._send_key(cmap.key, cmap.encode(values, counter), best_effort)

    def command(self, cmd: RigCommand) -> RigCommand:
        """Send the command frames of the run's actuators; return what was really sent
        (after clamping to the device limits)."""
        if self.dry_run:
            return SAFE_COMMAND
        self._counter = (self._counter + 1) & 0xFF
        c = self._counter
        sent = RigCommand()
        if self._wheel_on:
            args = self.wheel.command_args(cmd.wheel_torque_n_m, True)
            sent.wheel_torque_n_m = args[0]  # the clamped torque (enabled)
            self._send_args("reaction_wheel", args, c)
        if self._valves_on:
            sent.valve_direction = cmd.valve_direction
            self._send_args("thruster_valves", self.valves.command_args(cmd.valve_direction),
                            c)
        if self._piezo_on:
            args = self.piezo.command_args(cmd.piezo_v[0], cmd.piezo_v[1])
            sent.piezo_v = args
            self._send_args("piezo_amplifier", args, c)
        if self._rotor_on:
            sent.rotor_speed_rad_s, sent.rotor_enable = cmd.rotor_speed_rad_s, cmd.rotor_enable
            self._send_args("disturbance_rotor", self.rotor.command_args(
                cmd.rotor_speed_rad_s, cmd.rotor_enable), c)
        return sent

    def command_safe(self) -> None:
        """Wheel torque zero (disabled), valves closed, piezo 0 V, rotor stopped: sent to
        every actuator the rig has, whatever the run used."""
        if self.dry_run:
            return
        c = self._counter = (self._counter + 1) & 0xFF
        safe = {"reaction_wheel": self.wheel.command_values(0.0, False),
                "thruster_valves": self.valves.command_values(0),
                "piezo_amplifier": self.piezo.command_values(0.0, 0.0),
                "disturbance_rotor": self.rotor.command_values(0.0, False)}
        for device, values in safe.items():
            if device in self.drivers:
                self._send_command(device, values, c, best_effort=True)
        if self.co is not None:
            # CANopen: drives disabled and outputs 0 by the PDOs above, then every node to
            # pre-operational (no PDO accepted any more)
            from drivers.binding.canopen_master import NMT_PREOP, nmt_frame

            self._send_key((0, False), nmt_frame(NMT_PREOP, 0).data, best_effort=True)

    # ------------------------------------------------------------------ receiving
    def expected_frames(self, tick: int) -> int:
        if tick == 0 and self.co is not None:
            # a CANopen TPDO sent every n-th SYNC (n > 1) counts from the SYNC whose counter
            # is its start value (CiA 301): its first frame comes at tick n, never tick 0
            return sum(n for d, n in self._due_groups if d == 1)
        return sum(n for d, n in self._due_groups if tick % d == 0)

    def receive(self, tick: int, timeout_s: float, lockstep: bool = False,
                expected: int | None = None) -> int:
        """Read telemetry until every device due at ``tick`` has answered or the timeout
        passes (0: only what is already waiting). Returns the number of frames read.
        ``expected``: ``expected_frames(tick)``, if the caller has it already."""
        if expected is None:
            expected = self.expected_frames(tick)
        got = 0
        recv = self.bus.recv
        if lockstep:  # the rig answered already: what is waiting, up to the frames due
            feed, fast, counters = self.feed, self._fast, self.counters
            log = self.can_log.log if self.can_log is not None else None
            wire = self.wire_rx
            while got < expected:
                msg = recv(0.0)
                if msg is None:
                    return got
                entry = (None if msg.is_extended_id or msg.is_error_frame
                         else fast.get(msg.arbitration_id))
                if entry is None:
                    if feed(msg, tick):
                        got += 1
                    continue
                # feed()'s one-device frame, inline (every telemetry frame of the tick)
                counters.received += 1
                if log is not None:
                    log(msg)
                decode, drv = entry
                try:
                    values = decode(msg.data)
                except FrameError as exc:
                    drv.malformed(str(exc))
                    continue
                drv.update(values, tick)
                if wire is not None:
                    wire.append((drv, msg.timestamp))
                got += 1
            return got
        deadline = time.monotonic() + timeout_s
        while True:
            remaining = deadline - time.monotonic()
            msg = recv(remaining if remaining > 0 and got < expected else 0.0)
            if msg is None:
                if got >= expected or remaining <= 0:
                    return got
                continue
            if self.feed(msg, tick):
                got += 1

    def feed(self, msg: can.Message, tick: int) -> bool:
        """One received frame: logged, counted, and decoded through the binding into its
        device's driver (as received during ``tick``). True if a driver accepted it as
        telemetry; error frames, unknown ids and malformed frames are counted, never raised.
        ``harness replay`` feeds a CAN log's frames through here."""
        if self._wire_own and self._own_frame(msg):
            return False
        self.counters.received += 1
        if self.can_log is not None:
            self.can_log.log(msg)
        if msg.is_error_frame:
            self.counters.error_frames += 1
            if msg.arbitration_id & CAN_ERR_BUSOFF:
                self.counters.bus_off = True
            return False
        if not msg.is_extended_id:
            fast = self._fast.get(msg.arbitration_id)
            if fast is not None:  # one device's frame, not multiplexed (see _fast)
                decode, drv = fast
                try:
                    values = decode(msg.data)
                except FrameError as exc:
                    drv.malformed(str(exc))
                    return False
                drv.update(values, tick)
                if self.wire_rx is not None:
                    self.wire_rx.append((drv, msg.timestamp))
                return True
        maps = self._by_key.get((msg.arbitration_id, msg.is_extended_id))
        if maps is None:
            if (msg.arbitration_id, msg.is_extended_id) == self.fault_insertion_key:
                return False  # the fault-insertion unit's frame: no device's, not unknown
            if (msg.arbitration_id, msg.is_extended_id) in self.own_ids:
                self._foreign(msg)
                return False
            if self.co is not None and not msg.is_extended_id and self._canopen_service(
                    msg, tick):
                return False
            self.counters.unknown += 1
            self.counters.last_unknown_id = msg.arbitration_id
            return False
        accepted = False
        for tmap, drv in maps:  # every device the frame (or this mux page of it) serves
            try:
                values = tmap.decode(msg.data)
            except FrameError as exc:
                drv.malformed(str(exc))
                return False
            if values is not None:
                drv.update(values, tick)
                accepted = True
                if self.wire_rx is not None:
                    self.wire_rx.append((drv, msg.timestamp))
        if accepted:
            return True
        self.counters.unknown += 1  # a multiplexed page no device is bound to
        self.counters.last_unknown_id = msg.arbitration_id
        return False

    def _foreign(self, msg: can.Message) -> None:
        """A frame with an id only the harness sends: another master on the bus."""
        c = self.counters
        c.foreign += 1
        if not c.first_foreign:
            what = self.own_ids[(msg.arbitration_id, msg.is_extended_id)]
            c.first_foreign = (f"{what} (id 0x{msg.arbitration_id:03X}, "
                               f"{bytes(msg.data).hex(' ') or 'no data'}) that the harness did "
                               "not send: another master is on the bus")

    # ------------------------------------------------------------------ CANopen
    def watch_heartbeats(self, dt_s: float, start_tick: int = 0, grace_ticks: int = 0,
                         quiet_ticks: int = 0) -> None:
        """From ``start_tick`` on, each node must send its heartbeat within 3 of its periods
        (at least 2 ticks, and at least ``grace_ticks``: the monitor's real-time grace on a
        slow host): a node silent for longer is a fault (``protocol_fault``)."""
        if self.co is None:
            return
        self._dt_s = dt_s
        self._hb_dup_from = start_tick + quiet_ticks
        # lockstep: the rig's time is the tick's; on the wall clock a stalled loop reads a
        # node's heartbeats in a burst, so their spacing is the senders' time stamps'
        self._hb_wall = grace_ticks > 0
        for nid, node in self.co.nodes.items():
            self._hb_tick.setdefault(nid, start_tick)
            self._hb_quiet_until = None
            self._hb_timeout_ticks[nid] = max(2, grace_ticks,
                                              round(3 * node.heartbeat_ms * 1e-3 / dt_s))

    def _canopen_service(self, msg: can.Message, tick: int) -> bool:
        """A CANopen service frame of a node (heartbeat, boot-up, EMCY, SDO): True if it is
        one. Boot-up mid-run, a node not operational, and an EMCY are faults."""
        from drivers.binding.canopen import EMCY_BASE, EMCY_HEARTBEAT_ERROR, emcy_meaning
        from drivers.binding.canopen_master import heartbeat_state

        cid, data = msg.arbitration_id, bytes(msg.data)
        co = self.co
        nid = cid & 0x7F
        if nid not in co.nodes:
            return False  # (NMT and SYNC are the master's own: feed's foreign frames)
        fn = cid & 0x780
        device = co.device_of_node(nid)
        if fn == 0x700:
            self._hb_tick[nid] = tick
            self._hb_quiet_until = None
            state = data[0] & 0x7F if data else -1
            if state != 0 and self._dt_s > 0.0 and tick >= self._hb_dup_from:
                self._duplicate_heartbeat(
                    nid, msg.timestamp if self._hb_wall else tick * self._dt_s, device)
            if state == 0:
                self.protocol_events.append((device, "node rebooted", (
                    f"node {nid} sent a boot-up frame: it reset mid-run (its outputs and "
                    "set-up are lost)")))
            elif state != 0x05:
                self.protocol_events.append((device, "NMT state", (
                    f"node {nid} reports NMT state {heartbeat_state(data)}, not "
                    "OPERATIONAL")))
            return True
        if fn == EMCY_BASE and cid != EMCY_BASE:
            if len(data) != 8:  # CiA 301: an EMCY is always 8 bytes
                drv = self.drivers.get(device.split("/")[0])
                reason = (f"node {nid}: an EMCY of {len(data)} bytes "
                          f"({data.hex(' ') or 'no data'}), not 8")
                if drv is not None:
                    drv.malformed(reason)
                else:
                    self.protocol_events.append((device, "malformed EMCY", reason))
            if len(data) >= 3:
                code, reg = int.from_bytes(data[:2], "little"), data[2]
                if code != 0:  # 0x0000: error reset
                    kind, text = "EMCY", f"node {nid}: {emcy_meaning(code, reg)}"
                    # a heartbeat consumer's time-out about the harness (the producer's id
                    # in the first vendor byte, or none given): the harness's heartbeat was
                    # late at the node, which the monitor tells from a device's fault
                    if code == EMCY_HEARTBEAT_ERROR and (len(data) < 4 or data[3] in (
                            0, co.master_id)):
                        kind = HARNESS_HEARTBEAT_LOST
                        text += (f"; the node heard no heartbeat from the harness (node "
                                 f"{co.master_id}) within its consumer time "
                                 f"({co.consumer_timeout_ms} ms)")
                    self.protocol_events.append((device, kind, text))
            return True
        return fn in (0x580, 0x600)

    def _duplicate_heartbeat(self, nid: int, t_s: float, device: str) -> None:
        """A node's heartbeats far more often than its period: a second node answers with
        the same node id (its heartbeat would mask the real node's loss)."""
        recent = self._hb_recent.setdefault(nid, [])
        recent.append(t_s)
        if len(recent) > DUPLICATE_HB_COUNT:
            del recent[0]
        period_s = self.co.nodes[nid].heartbeat_ms * 1e-3
        if len(recent) < DUPLICATE_HB_COUNT:
            return
        if recent[-1] - recent[0] >= DUPLICATE_HB_PERIODS * period_s:
            self._hb_dup_windows[nid] = 0
            return
        # twice in a row: a stalled host or loop delivers one burst of a node's heartbeats;
        # a second node with its id keeps doubling them
        windows = self._hb_dup_windows[nid] = self._hb_dup_windows.get(nid, 0) + 1
        span = recent[-1] - recent[0]
        recent.clear()
        if windows >= 2:
            self.protocol_events.append((device, "node id used twice", (
                f"node {nid}: twice {DUPLICATE_HB_COUNT} heartbeats in a row within "
                f"{span:.3g} s, its period is {self.co.nodes[nid].heartbeat_ms} ms: two "
                f"nodes answer with id {nid}")))

    def protocol_fault(self, tick: int) -> tuple[str, str, str] | None:
        """The first protocol fault so far (CANopen): an EMCY, a boot-up, a node not
        operational, or a heartbeat missing past its consumer time."""
        if self.protocol_events:
            return self.protocol_events[0]
        quiet = self._hb_quiet_until
        if quiet is not None and tick <= quiet:  # every tick: the nodes' deadlines, once
            return None
        limits = self._hb_timeout_ticks
        self._hb_quiet_until = min((last + limits[nid] for nid, last in self._hb_tick.items()
                                    if nid in limits), default=None)
        for nid, last in self._hb_tick.items():
            limit = limits.get(nid)
            if limit is not None and tick - last > limit:
                node = self.co.nodes[nid]
                return (self.co.device_of_node(nid), "heartbeat lost", (
                    f"node {nid}: no heartbeat for {tick - last} ticks (its period is "
                    f"{node.heartbeat_ms} ms; the consumer time is 3 periods)"))
        return None

    def snapshot(self, tick: int, time_s: float) -> RigState:
        s = self.state
        s.tick, s.time_s = tick, time_s
        r = self.rotor
        hv, av, wv, vv, pv, rv = (self.hub.values, self.accel.values, self.wheel.values,
                                  self.valves.values, self.piezo.values, r.values)
        # a device's fields are read again only when its values changed (a driver replaces
        # its values dict with every frame; valves and rotor answer every 5th SYNC)
        seen = self._snapshot_seen
        if hv is not seen[0]:
            seen[0] = hv
            s.hub_angle_rad = hv.get("angle", 0.0)
            s.hub_rate_rad_s = hv.get("rate", 0.0)
        if av is not seen[1]:
            seen[1] = av
            s.tip_accel_m_s2 = av.get("accel", 0.0)
            s.accel_saturated = bool(av.get("saturated", 0))
        if wv is not seen[2]:
            seen[2] = wv
            s.wheel_speed_rad_s = wv.get("speed", 0.0)
            s.wheel_torque_n_m = wv.get("torque", 0.0)
            s.wheel_enabled = bool(wv.get("enabled", 0))
            s.wheel_fault = bool(wv.get("fault", 0))
        if vv is not seen[3]:
            seen[3] = vv
            s.valve_state = int(vv.get("valve_pos_open", 0)) - int(vv.get("valve_neg_open", 0))
            s.valve_firings = int(vv.get("firings", 0))
            s.valve_on_time_s = vv.get("on_time", 0.0)
        if pv is not seen[4]:
            seen[4] = pv
            s.piezo_sensor_v = (pv.get("sensor_ch1", 0.0), pv.get("sensor_ch2", 0.0))
        if rv is not seen[5]:
            seen[5] = rv
            s.rotor_angle_rad = rv.get("angle", 0.0)
            s.rotor_speed_rad_s = rv.get("speed", 0.0)
        s.rotor_sample_tick = r.last_tick
        stale: tuple[str, ...] = ()
        for n, d in self._driver_items:  # DeviceDriver.is_stale, inline (every tick)
            if tick - d.last_tick > d.stale_after_ticks:
                stale += (n,)
        s.stale = stale
        return s
