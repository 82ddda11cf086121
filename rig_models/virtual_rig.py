"""The virtual SGSRT: a CAN node that answers exactly like the rig's devices.

Protocol (see drivers/sgsrt.dbc): on SYNC(tick) the rig first advances the physics to that
tick (one step of dt per tick, commands held over the step), then every device samples and
sends its telemetry frame (each on every n-th SYNC, as configured). Commands received
between two SYNCs take effect over the next step. Actuators stay at rest until the harness
heartbeat says ``armed``; with no heartbeat for ``watchdog.heartbeat_timeout_s`` every
device goes safe by itself (wheel torque 0, valves closed, piezo 0 V, rotor stopped).

Two ways to run it:
- in-process, lockstep: the harness calls ``service()`` right after it sends SYNC, so the
  rig answers before the harness reads (deterministic, as fast as the machine allows);
- its own process (``run_forever``): blocking reads on a SocketCAN channel or a socketcand
  server bus; the watchdog also runs on the wall clock there.

It emulates the rig as built (``RigConfig.as_built_rig()``: the rig file's model with its
``as_built:`` overlay; docs/as_built.md) wherever it runs; the harness keeps the model.
"""

from __future__ import annotations

import gc
import math
import random
import resource
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

import can
import numpy as np

from drivers.binding.frames import CommandMap, TelemetryMap
from drivers.dbc import FrameError, load_protocol
from rig_models.devices import (
    Accelerometer,
    DisturbanceRotor,
    HubSensor,
    NoiseSource,
    PiezoAmplifier,
    ReactionWheel,
    ThrusterValves,
)
from rig_models.faults import (
    CANOPEN_FAULTS,
    FAULT_CLEAR,
    UNKNOWN_ID,
    FaultFrameError,
    FaultInjector,
    FaultSpec,
    decode_fault_insertion,
    encode_fault_insertion,
    ended,
)
from rig_models.rig_file import RigConfig
from rig_models.schema import ConfigError

CAN_ERR_BUSERROR = 0x080  # SocketCAN error classes (linux/can/error.h)
CAN_ERR_BUSOFF = 0x040
LOCKSTEP_BACKSTOP_S = 10.0
"""A rig process in lockstep (``run_forever(lockstep=True)``) keeps its devices' timers on the
rig's own time, which stands still between SYNCs; after this long without a SYNC on the wall
clock its time runs on with the wall clock's, so a harness that died mid-run still trips the
heartbeat consumers and the watchdog (later by this much than in real time). Long: a harness
in lockstep pauses between ticks to let its recording's file sink catch up, and under CPU
emulation (CI's VM) such a pause lasted over 2 s and tripped a node's consumer."""


# each device's telemetry quantities (drivers.binding.quantities), in the order the rig
# passes them to its frame encoders (positional: no dict per frame)
TELEMETRY_QUANTITIES: dict[str, tuple[str, ...]] = {
    "hub_sensor": ("angle", "rate"),
    "accelerometer": ("accel", "sample_counter", "saturated"),
    "reaction_wheel": ("speed", "torque", "enabled", "fault", "speed_limited",
                       "torque_limited", "counter"),
    "thruster_valves": ("valve_pos_open", "valve_neg_open", "fault", "firings", "on_time",
                        "counter"),
    "piezo_amplifier": ("sensor_ch1", "sensor_ch2", "overcurrent", "counter"),
    "disturbance_rotor": ("angle", "speed", "enabled", "counter"),
}


@dataclass
class RigCounters:
    frames_in: int = 0
    frames_out: int = 0
    malformed: int = 0  # frames refused: a wrong length, or a command's wrong checksum
    unknown: int = 0
    repeated: int = 0  # protected commands dropped for repeating the last alive counter
    watchdog_trips: int = 0
    steps: int = 0


class SyncTiming:
    """How promptly the rig, as its own process, answered each SYNC, in bounded memory.

    ``wake``: from the SYNC's send time (stamped by the sender; the Unix-socket bus carries
    it) to the moment this process had it in hand: the host's scheduling and wake-up
    latency on the rig's CPU plus the transport. ``work``: from then to the last telemetry
    frame sent (the rig's own physics and codecs). Both in 10 us bins up to 0.5 s (exact
    maximum kept); SYNCs answered (wake + work) later than ``late_s`` are kept as (tick,
    wake, work, work's CPU time: how long this thread actually ran during it), the first
    ``max_late`` of them (the count stays exact), so the harness can tell a telemetry frame
    the host kept back (a late wake-up, or the CPU taken away during the answer) from one
    the rig was too slow to send.

    ``op``: the longest single operation of each answer (one physics step, or one frame's
    encode and send), a fixed amount of work, in the same bins. A late answer keeps it with
    its name and the page faults and context switches of the answer's thread: one fixed
    operation taking many times its usual cost, with neither, means the CPU was taken from
    under a running thread by something the guest's scheduler does not see (on a VM, the
    hypervisor: the guest counts that time as the thread's; docs/realtime.md).
    """

    BIN_S = 10e-6
    N_BINS = 50_000

    def __init__(self, late_s: float, max_late: int = 20_000) -> None:
        self.late_s = late_s
        self.max_late = max_late
        self.wake = np.zeros(self.N_BINS + 1, dtype=np.int64)
        self.work = np.zeros(self.N_BINS + 1, dtype=np.int64)
        self.op = np.zeros(self.N_BINS + 1, dtype=np.int64)
        self.wake_max_s = 0.0
        self.work_max_s = 0.0
        self.op_max_s = 0.0
        self.syncs = 0
        self.late_count = 0
        self.late: list[tuple[int, float, float, float, float, str, int, int]] = []

    def _bin(self, v: float) -> int:
        return min(self.N_BINS, max(0, int(v / self.BIN_S)))

    def add(self, tick: int, wake_s: float, work_s: float, work_cpu_s: float = -1.0,
            op_s: float = 0.0, op: str = "", faults: int = -1, switches: int = -1) -> None:
        """One answered SYNC. ``op_s``/``op``: its longest single operation; ``faults``,
        ``switches``: page faults and context switches of the thread during it (-1 not
        known)."""
        self.syncs += 1
        self.wake[self._bin(wake_s)] += 1
        self.work[self._bin(work_s)] += 1
        self.op[self._bin(op_s)] += 1
        self.wake_max_s = max(self.wake_max_s, wake_s)
        self.work_max_s = max(self.work_max_s, work_s)
        self.op_max_s = max(self.op_max_s, op_s)
        if wake_s + work_s > self.late_s:
            self.late_count += 1
            if len(self.late) < self.max_late:
                self.late.append((tick, wake_s, work_s, work_cpu_s, op_s, op, faults,
                                  switches))

    def _percentiles_ms(self, hist: np.ndarray, vmax: float) -> dict[str, float]:
        n = int(hist.sum())
        if n == 0:
            return {"p50": 0.0, "p99": 0.0, "max": 0.0}
        cum = np.cumsum(hist)
        def q(f: float) -> float:
            return (int(np.searchsorted(cum, f * n)) + 1) * self.BIN_S * 1e3
        return {"p50": round(min(q(0.5), vmax * 1e3), 3), "p99": round(min(q(0.99), vmax * 1e3), 3),
                "max": round(vmax * 1e3, 3)}

    def to_dict(self) -> dict[str, object]:
        return {"syncs": self.syncs,
                "wake_ms": self._percentiles_ms(self.wake, self.wake_max_s),
                "work_ms": self._percentiles_ms(self.work, self.work_max_s),
                "longest_op_ms": self._percentiles_ms(self.op, self.op_max_s),
                "late_threshold_ms": round(self.late_s * 1e3, 3),
                "late_syncs": self.late_count,
                # [tick, wake ms, work ms, work's CPU ms, longest op ms, its name,
                #  page faults, context switches]
                "late": [[t, round(w * 1e3, 3), round(k * 1e3, 3), round(c * 1e3, 3),
                          round(o * 1e3, 3), name, f, sw]
                         for t, w, k, c, o, name, f, sw in self.late]}


_RUSAGE_THREAD = getattr(resource, "RUSAGE_THREAD", resource.RUSAGE_SELF)


def _thread_usage() -> tuple[int, int]:
    """(page faults, context switches) of the calling thread so far."""
    ru = resource.getrusage(_RUSAGE_THREAD)
    return ru.ru_minflt + ru.ru_majflt, ru.ru_nvcsw + ru.ru_nivcsw


@dataclass
class TruthSample:
    """The physics' true values at the last SYNC (for tests and model comparison only)."""

    time_s: float = 0.0
    angle_rad: float = 0.0
    rate_rad_s: float = 0.0
    tip_accel_m_s2: float = 0.0
    modal: np.ndarray = field(default_factory=lambda: np.zeros(0))


def check_virtual_rig(rig: RigConfig, faults: list[FaultSpec] | tuple[FaultSpec, ...] = ()
                      ) -> None:
    """``ConfigError`` (naming the rig file's key and the device file's object) if the
    virtual rig cannot be one of the rig's devices, or cannot inject one of ``faults`` (a
    ``bad_checksum`` on a device whose telemetry declares no checksum): called before a run
    on the virtual bus, so such a rig is refused with nothing sent rather than failing
    mid-set-up or running a fault that never happens."""
    for f in faults:
        if f.kind == "bad_checksum" and not any(
                getattr(m, "checksum", None) is not None
                for m in rig.binding.telemetry.get(f.device, ())):
            raise ConfigError(f"fault bad_checksum:{f.device}: the {f.device}'s telemetry "
                              f"declares no checksum (a DBC binding's devices.{f.device}."
                              "checksums)")
    co = rig.binding.canopen
    if co is not None:
        from rig_models.canopen.rig_devices import check_emulation

        check_emulation(co)


def check_fault_insertion(rig: RigConfig,
                          faults: list[FaultSpec] | tuple[FaultSpec, ...] = ()) -> None:
    """``ConfigError`` if ``rig`` cannot take a fault at run time (``bus.fault_insertion_id``
    absent: it has no fault-insertion unit), or cannot take one of ``faults`` so: the rules
    of ``check_virtual_rig``, a CANopen kind on a device the rig does not bind to CANopen,
    ``sdo_abort`` (a set-up fault: at run time the set-up is over), a fault the frame
    cannot carry. Called before a run whose sequence inserts faults."""
    if rig.fault_insertion_key is None:
        raise ConfigError(f"{rig.source}: bus.fault_insertion_id: absent: this rig has no "
                          "fault-insertion unit (a fault cannot be inserted at run time)")
    for f in faults:
        encode_fault_insertion(f)
        if f.kind == "sdo_abort":
            raise ConfigError(f"fault sdo_abort:{f.device}: acts during the set-up only; it "
                              "cannot be inserted at run time")
        if f.kind in CANOPEN_FAULTS and rig.binding.kinds.get(f.device) != "canopen":
            raise ConfigError(f"fault {f.kind}:{f.device}: the {f.device} is not a CANopen "
                              f"device on this rig (devices.{f.device}.binding is "
                              f"{rig.binding.kinds.get(f.device)!r})")
    check_virtual_rig(rig, faults)


class VirtualRig:
    def __init__(self, rig: RigConfig, bus: can.BusABC, dt_s: float,
                 faults: list[FaultSpec] | None = None) -> None:
        # the rig as built (the model itself when its file has no as_built: section)
        self.model_rig = rig
        self.answer_latency_s, self.answer_jitter_s = rig.answer_timing
        rig = rig.as_built_rig()
        self.rig = rig
        self.injector = FaultInjector(list(faults or []))
        self.bus = bus
        self.dt_s = dt_s
        self.protocol = load_protocol()
        self.plant = rig.plant.discretise(dt_s)
        self.n_modes = rig.plant.n_modes
        self.x = np.zeros(rig.plant.n_states)
        # [x; u] in one buffer: the step is one product with the plant's fused matrix
        # (DiscreteHubBeam.advance); u is a view into it, as before a persistent array
        self._xu = np.zeros(rig.plant.n_states + self.plant.bd.shape[1])
        self.u = self._xu[rig.plant.n_states:]
        noise = NoiseSource(rig.data["noise_seed"])
        self.noise = noise
        rw, acc, hs = (rig.section(k) for k in ("reaction_wheel", "accelerometer", "hub_sensor"))
        self.wheel = ReactionWheel(
            max_torque_n_m=rw["max_torque_n_m"], max_speed_rad_s=rw["max_speed_rad_s"],
            rotor_inertia_kg_m2=rw["rotor_inertia_kg_m2"], torque_lag_s=rw["torque_lag_s"],
            dt_s=dt_s, friction_coulomb_n_m=rw.get("friction_coulomb_n_m") or 0.0,
            friction_viscous_n_m_s=rw.get("friction_viscous_n_m_s") or 0.0,
            friction_breakaway_n_m=rw.get("friction_breakaway_n_m"),
        )
        tv = rig.section("thruster_valves")
        self.valves = ThrusterValves(
            couple_n_m=tv["couple_n_m"], open_delay_s=tv["open_delay_s"],
            close_delay_s=tv["close_delay_s"], min_on_time_s=tv["min_on_time_s"], dt_s=dt_s,
            couple_negative_n_m=tv.get("couple_negative_n_m"),
            open_delay_negative_s=tv.get("open_delay_negative_s"),
            close_delay_negative_s=tv.get("close_delay_negative_s"),
        )
        # a table out of level: -gravity_torque sin(hub angle - azimuth) on the hub
        hub = rig.section("hub")
        self.gravity_torque_n_m = hub.get("gravity_torque_n_m") or 0.0
        self.gravity_azimuth_rad = hub.get("gravity_azimuth_rad") or 0.0
        pa = rig.section("piezo_amplifier")
        self.piezo_gains = rig.piezo_gains
        # modal forces per volt, one column per patch; the piezo's share of u is computed
        # only while a voltage is applied (and once more to clear it)
        self._piezo_drive = (np.column_stack([g.actuator for g in self.piezo_gains])
                             if self.piezo_gains else None)
        self._piezo_forcing = False
        caps = [g.capacitance_f for g in self.piezo_gains] + [0.0, 0.0]
        self.piezo = PiezoAmplifier(max_voltage_v=pa["max_voltage_v"],
                                    max_current_a=pa["max_current_a"],
                                    capacitance_f=(caps[0], caps[1]), dt_s=dt_s)
        self.piezo_noise_v = pa["sensor_noise_rms_v"]
        # one product a step gives x[k+1], the outputs y and the piezo sensor patches' volts
        # (modal coordinates times each patch's sensor gains): the plant's fused
        # [[Ad, Bd], [C Ad, C Bd + D]] with a row [S Ad, S Bd] per patch
        n_x = rig.plant.n_states
        fused = self.plant.fused
        if self.piezo_gains:
            sense = np.zeros((len(self.piezo_gains), n_x))
            for i, g in enumerate(self.piezo_gains):
                sense[i, 1:1 + self.n_modes] = g.sensor
            fused = np.vstack([fused, sense @ fused[:n_x]])
        self._fused = np.ascontiguousarray(fused)
        self._n_x = n_x
        self._n_y = self.plant.c.shape[0]
        # the last step's product: [x; y; patch volts] (zero before the first step, as x, u)
        self._state = np.zeros(fused.shape[0])
        dr = rig.section("disturbance_rotor")
        self.rotor = DisturbanceRotor(
            mass_kg=dr["mass_kg"], eccentricity_m=dr["eccentricity_m"],
            dish_radius_m=dr["dish_radius_m"], max_speed_rad_s=dr["max_speed_rad_s"],
            speed_lag_s=dr["speed_lag_s"], dt_s=dt_s,
        )
        self.divider = rig.data["bus"]["sync_divider"]
        self.accel = Accelerometer(
            range_m_s2=rig.accel_range_m_s2, bandwidth_hz=acc["bandwidth_hz"],
            noise_rms_m_s2=acc["noise_rms_m_s2"], lsb_m_s2=acc["lsb_m_s2"], dt_s=dt_s,
            noise=noise, bias_m_s2=acc.get("bias_m_s2") or 0.0,
            scale_error=acc.get("scale_error") or 0.0, tilt_rad=acc.get("tilt_rad") or 0.0,
            tilt_azimuth_rad=acc.get("tilt_azimuth_rad") or 0.0,
        )
        self.hub_sensor = HubSensor(
            angle_noise_rms_rad=hs["angle_noise_rms_rad"],
            rate_noise_rms_rad_s=hs["rate_noise_rms_rad_s"],
            angle_lsb_rad=hs["angle_lsb_rad"], rate_lsb_rad_s=hs["rate_lsb_rad_s"], noise=noise,
            angle_bias_rad=hs.get("angle_bias_rad") or 0.0,
            rate_bias_rad_s=hs.get("rate_bias_rad_s") or 0.0,
            angle_scale_error=hs.get("angle_scale_error") or 0.0,
            rate_scale_error=hs.get("rate_scale_error") or 0.0,
            rate_random_walk_rad_s_sqrt_s=hs.get("rate_random_walk_rad_s_sqrt_s") or 0.0,
            sample_dt_s=dt_s * self.divider["hub_sensor"],
        )
        # the sensors' latency: a delay line of the physics' outputs, a tuple (angle, rate,
        # tip acceleration) per SYNC; each sensor reads the one its latency back (whole
        # ticks). Only a rig with a latency or the accelerometer's errors goes through it
        self.hub_latency_ticks = round((hs.get("latency_s") or 0.0) / dt_s)
        self.accel_latency_ticks = round((acc.get("latency_s") or 0.0) / dt_s)
        self._sensor_terms = bool(self.hub_latency_ticks or self.accel_latency_ticks
                                  or not self.accel.ideal)
        depth = max(self.hub_latency_ticks, self.accel_latency_ticks) + 1
        self._outputs: deque[tuple[float, float, float]] = deque(
            [(0.0, 0.0, 0.0)] * depth, maxlen=depth)
        # the devices' late answers (real time only): their own generator, so the physics'
        # noise is the same sequence in every mode
        self._answer_rng = random.Random(rig.data["noise_seed"])
        period = math.lcm(*(self.divider[d] for d in TELEMETRY_QUANTITIES))
        self._due_period = period if period <= 10_000 else 0
        self._due_at = [tuple(k % self.divider[d] == 0 for d in TELEMETRY_QUANTITIES)
                        for k in range(self._due_period)]
        self.watchdog_timeout_s = rig.data["watchdog"]["heartbeat_timeout_s"]
        self.counters = RigCounters()
        self.tick = -1  # the SYNC's own count (modulo its counter's range)
        self.sync_index = -1  # the same, unwrapped: the harness's tick in its own process
        self.time_s = 0.0
        self.armed = False
        self.safe = True
        self.last_heartbeat_s = 0.0  # rig time
        self.last_heartbeat_wall = time.monotonic()
        # in its own process on the wall clock: when the frame being handled came (on the
        # monotonic clock), None between frames (see run_forever)
        self._arrived: float | None = None
        self.lockstep_process = False  # run_forever(lockstep=True): SYNC-driven, own process
        self.last_sync_wall = time.monotonic()
        self.idle_s = 0.0  # wall time without SYNC beyond the backstop, added to co_now
        self.wheel_counter = 0
        # the longest single operation of the current answer (run_forever with timing only:
        # lockstep runs do not pay for the clock readings)
        self.time_ops = False
        self.longest_op_s = 0.0
        self.longest_op = ""
        self._hooks: list[Callable[[VirtualRig], None]] = []
        # the devices speak the rig file's binding (sgsrt, any DBC, CANopen): the same maps
        # the harness uses, in the other direction
        b = self.binding = rig.binding
        self._handlers: dict[tuple[int, bool], Callable[[bytes], None]] = {
            b.sync.key: self._on_sync}
        if b.heartbeat is not None:
            self._handlers[b.heartbeat.key] = self._on_heartbeat
        # the fault-insertion unit (bus.fault_insertion_id): faults taken at run time, in
        # order, and who is told of each (the rig process writes them to its log)
        self.inserted_faults: list[FaultSpec] = []
        self.on_fault_inserted: Callable[[str], None] | None = None
        if b.fault_insertion is not None:
            self._handlers[b.fault_insertion] = self._on_fault_insertion
        apply = {"reaction_wheel": self._wheel_cmd, "thruster_valves": self._valve_cmd,
                 "piezo_amplifier": self._piezo_cmd, "disturbance_rotor": self._rotor_cmd}
        self._apply = apply
        self._command_args: dict[str, tuple[tuple[str, ...], tuple[float, ...],
                                             Callable[..., None]]] = {
            "reaction_wheel": (("torque_cmd", "enable"), (0.0, 1), self._wheel_args),
            "thruster_valves": (("valve_pos", "valve_neg"), (0, 0), self._valve_args),
            "piezo_amplifier": (("voltage_ch1", "voltage_ch2"), (0.0, 0.0), self._piezo_args),
            "disturbance_rotor": (("speed_cmd", "enable"), (0.0, 1), self._rotor_args),
        }
        for key, cmaps in b.commands_by_key().items():
            if b.kinds[cmaps[0].device] != "canopen":  # a CANopen node takes its own RPDOs
                self._handlers[key] = self._command_handler(cmaps, apply)
        self._tlm = {d: maps for d, maps in b.telemetry.items()
                     if maps and b.kinds[d] != "canopen"}
        self.protocol_kinds = b.kinds
        # CANopen devices: a node per the rig file's binding, from the same EDS files
        self.co_devices = None
        self.wall_clock = False  # own process: the nodes' heartbeat timers on the wall clock
        if b.canopen is not None:
            from rig_models.canopen.rig_devices import CanopenDevices

            self._co_tpdo_device = {m.key[0]: d for d, maps in b.telemetry.items()
                                    if b.kinds[d] == "canopen" for m in maps}
            # no fault to inject: a node's frame goes straight onto the bus
            self.co_devices = CanopenDevices(
                b.canopen, self._send_raw if self.injector.faults or bus is None
                else self._co_sender())
            self._co_actuators = tuple(d for d in apply if b.kinds[d] == "canopen")
            self._co_sensors = frozenset(d for d, k in b.kinds.items() if k == "canopen")
            if all(k in ("canopen", "none") for k in b.kinds.values()):
                # the nodes' own heartbeat consumers and error behaviour make them safe
                self.watchdog_timeout_s = float("inf")
            self.co_devices.boot(self.time_s)
            self._co_faults_done: set[int] = set()
            for f in self.injector.faults:  # set-up faults: armed before the master asks
                node = self.co_devices.node_of(f.device)
                if f.kind == "sdo_abort" and node is not None:
                    node.sdo_abort_next(int(f.value) if f.value is not None else 0x1017,
                                        0x08000020)
        self._build_emitters()

    # ------------------------------------------------------------------ bus side
    def service(self) -> int:
        """Handle every frame waiting on the bus; return how many were handled."""
        n = 0
        recv = self.bus.recv
        if self.co_devices is not None:
            while True:
                msg = recv(0.0)
                if msg is None:
                    return n
                self.handle(msg)
                n += 1
        # handle() inline (no CANopen node on this bus): every frame of a lockstep tick
        handlers, counters = self._handlers, self.counters
        while True:
            msg = recv(0.0)
            if msg is None:
                return n
            n += 1
            counters.frames_in += 1
            if msg.is_error_frame or msg.is_remote_frame:
                continue
            handler = handlers.get((msg.arbitration_id, msg.is_extended_id))
            if handler is None:
                counters.unknown += 1
                continue
            try:
                handler(bytes(msg.data))
            except FrameError:
                counters.malformed += 1

    def _send_raw(self, can_id: int, data: bytes) -> None:
        """A CANopen node's frame onto the bus; a TPDO through the frame faults of its
        device, as the sgsrt devices' telemetry goes."""
        payloads = [data]
        if self.injector.faults:
            device = self._co_tpdo_device.get(can_id)
            if device is not None:
                payloads = self.injector.telemetry(self.time_s, self.tick, device, data)
        for payload in payloads:
            self.bus.send(can.Message(arbitration_id=can_id, data=payload,
                                      is_extended_id=False))
            self.counters.frames_out += 1

    def _co_sender(self) -> Callable[[int, bytes], None]:
        """``_send_raw`` without the fault path (a run that injects no fault)."""
        send, message, counters = self._send_owned(), can.Message, self.counters

        def send_raw(can_id: int, data: bytes) -> None:
            send(message(arbitration_id=can_id, data=data, is_extended_id=False))
            counters.frames_out += 1
        return send_raw

    def wall_now(self) -> float:
        """The devices' wall-clock time (monotonic): while a frame is handled, when it came.
        Real devices handle a frame when it arrives; this process may get to it late (a
        stalled host), and its devices must not time out the heartbeat of a harness whose
        frames came in time but waited in the socket."""
        arrived = self._arrived
        return time.monotonic() if arrived is None else arrived

    def co_now(self) -> float:
        """The CANopen nodes' time: the rig's in lockstep, the wall clock in its own
        process (a harness that stops sending SYNC must still time out as a consumer). A
        process in lockstep runs on the rig's time, plus the wall time that passed beyond
        ``LOCKSTEP_BACKSTOP_S`` without a SYNC (kept, so this time never runs backwards)."""
        if self.wall_clock:
            return self.wall_now()
        if self.lockstep_process:
            now = time.monotonic()
            idle = now - self.last_sync_wall - LOCKSTEP_BACKSTOP_S
            if idle > 0:
                self.idle_s += idle
                self.last_sync_wall = now - LOCKSTEP_BACKSTOP_S
            return self.time_s + self.idle_s
        return self.time_s

    def handle(self, msg: can.Message) -> None:
        self.counters.frames_in += 1
        if msg.is_error_frame or msg.is_remote_frame:
            return
        key = (msg.arbitration_id, msg.is_extended_id)
        handler = self._handlers.get(key)
        co = self.co_devices
        if co is not None and not msg.is_extended_id and key != self.binding.sync.key:
            co.handle(msg.arbitration_id, bytes(msg.data), self.co_now())
            if handler is None:
                return
        if handler is None:
            self.counters.unknown += 1
            return
        try:
            handler(bytes(msg.data))
        except FrameError:
            self.counters.malformed += 1

    def run_forever(self, stop: Callable[[], bool], poll_s: float = 0.05,
                    timing: SyncTiming | None = None, lockstep: bool = False) -> None:
        """Own-process mode: block on the bus; watchdog on the wall clock as well.

        ``lockstep``: the harness runs in lockstep over the bus (``harness run --clock
        lockstep --bus socketcan:vcan0``), as fast as this process answers: the physics
        already steps once per SYNC; the devices' timers (CANopen heartbeats and consumers)
        then run on the rig's time too, and the wall-clock watchdog waits
        ``LOCKSTEP_BACKSTOP_S`` longer (a backstop for a harness that died).

        A rig file's ``as_built.timing`` holds each SYNC's answer back by the devices'
        latency plus a uniform jitter (the physics is the same: it steps by SYNC), in real
        time only; lockstep (in process, or ``lockstep=True``) ignores it.

        ``timing`` measures every SYNC's wake-up and answer (``SyncTiming``). With the
        collector disabled (``gc.disable()`` by the caller), generations 0-1 are collected
        right after a SYNC's answer about once a second, in the slack before the next one,
        so a collection never delays an answer and cyclic garbage cannot pile up."""
        sync_key = self.binding.sync.key
        collect = not gc.isenabled()
        next_collect = time.monotonic() + 1.0
        clock, cpu = time.time, time.thread_time
        self.time_ops = timing is not None
        self._build_emitters()  # timed operations: through _send
        self.wall_clock = not lockstep
        self.lockstep_process = lockstep
        wall_timeout_s = self.watchdog_timeout_s + (LOCKSTEP_BACKSTOP_S if lockstep else 0.0)
        # devices answering late (as_built.timing): in real time only, lockstep ignores it
        late = not lockstep and (self.answer_latency_s > 0 or self.answer_jitter_s > 0)
        while not stop():
            msg = self.bus.recv(poll_s)
            self._arrived = None
            if msg is not None:
                if not lockstep and msg.timestamp > 0:
                    # how long the frame waited for this process (its receive time stamp, on
                    # the wall clock), taken back from the monotonic clock
                    waited = time.time() - msg.timestamp
                    if 0.0 < waited < wall_timeout_s + 60.0:
                        self._arrived = time.monotonic() - waited
                if ((msg.arbitration_id, msg.is_extended_id) == sync_key
                        and not msg.is_error_frame):
                    woke, ran = clock(), cpu()
                    self.last_sync_wall = time.monotonic()
                    if late:
                        self._answer_delay()
                    if timing is None:
                        self.handle(msg)
                    else:
                        self.longest_op_s, self.longest_op = 0.0, ""
                        ru0 = _thread_usage()
                        self.handle(msg)
                        work, work_cpu = clock() - woke, cpu() - ran
                        ru1 = _thread_usage()
                        if msg.timestamp > 0:
                            timing.add(self.sync_index, woke - msg.timestamp, work, work_cpu,
                                       self.longest_op_s, self.longest_op,
                                       ru1[0] - ru0[0], ru1[1] - ru0[1])
                    if collect and time.monotonic() > next_collect:
                        gc.collect(1)
                        next_collect = time.monotonic() + 1.0
                else:
                    self.handle(msg)
            if self.co_devices is not None:
                self.co_devices.poll(self.co_now())
            if (not self.safe and
                    self.wall_now() - self.last_heartbeat_wall > wall_timeout_s):
                self.make_safe(watchdog=True)
                # like a CANopen emergency message: every device reports its (now safe)
                # state once, unprompted, so the trip is seen on the bus without a SYNC
                self._sample_and_send(max(self.tick, 0))

    def _build_emitters(self) -> None:
        """Each device's telemetry sender, called with its quantities positionally
        (``TELEMETRY_QUANTITIES`` order). A device of one frame, with no fault to inject
        and no operation to time (a lockstep run), gets a closure that encodes and sends
        in one call (the lockstep tick near its floor); the rest go through ``_send``."""
        emit: dict[str, Callable[..., None]] = {}
        plain = not self.injector.faults and not self.time_ops and self.bus is not None
        for device, names in TELEMETRY_QUANTITIES.items():
            maps = self._tlm.get(device)
            if maps is None:  # a CANopen device (its node sends), or none
                if self.co_devices is not None and device in self._co_sensors:
                    emit[device] = self._canopen_emitter(device, names)
                else:
                    emit[device] = _nothing
                continue
            encoders = tuple((tmap.encoder(names), tmap) for tmap in maps)
            if plain and len(encoders) == 1:
                emit[device] = self._frame_emitter(encoders[0][0], encoders[0][1].key)
            else:
                emit[device] = self._general_emitter(device, encoders)
        self._emit = emit

    def _send_owned(self) -> Callable[[can.Message], None]:
        """How the plain senders put a frame on the bus: a fresh Message each, never used
        again, so a bus that can hand it over without a copy (the harness's in-process
        virtual bus: ``send_owned``) does; any other bus's ``send``."""
        return getattr(self.bus, "send_owned", None) or self.bus.send

    def _frame_emitter(self, encode: Callable[..., bytes], key: tuple[int, bool]
                       ) -> Callable[..., None]:
        send, message, counters = self._send_owned(), can.Message, self.counters
        aid, ext = key

        def emit(*values: float) -> None:
            send(message(arbitration_id=aid, data=encode(*values), is_extended_id=ext))
            counters.frames_out += 1
        return emit

    def _general_emitter(self, device: str,
                         encoders: tuple[tuple[Callable[..., bytes], TelemetryMap], ...]
                         ) -> Callable[..., None]:
        def emit(*values: float) -> None:
            self._send(device, encoders, values)
        return emit

    def _canopen_emitter(self, device: str, names: tuple[str, ...]) -> Callable[..., None]:
        """The device's quantities into its node's objects (the node sends its TPDOs on
        the SYNC): the writer compiled for these names."""
        return self.co_devices.telemetry_writer(device, names)  # type: ignore[union-attr]

    def _send(self, device: str,
              encoders: tuple[tuple[Callable[..., bytes], TelemetryMap], ...],
              values: tuple[float, ...]) -> None:
        """The device's telemetry frames (one, or several pages) from its quantities,
        through the frame faults and the operation timing."""
        for encode, tmap in encoders:
            t0 = time.perf_counter() if self.time_ops else 0.0
            data = encode(*values)
            payloads = [data] if not self.injector.faults else self.injector.telemetry(
                self.time_s, self.tick, device, data,
                tmap.checksum.byte if tmap.checksum is not None else None)
            key = tmap.key
            for payload in payloads:
                self.bus.send(can.Message(arbitration_id=key[0], data=payload,
                                          is_extended_id=key[1]))
                self.counters.frames_out += 1
            if self.time_ops:
                self._note_op(tmap.codec.name, time.perf_counter() - t0)

    def _note_op(self, name: str, seconds: float) -> None:
        if seconds > self.longest_op_s:
            self.longest_op_s, self.longest_op = seconds, name

    def _send_fault_frames(self) -> None:
        inj, t = self.injector, self.time_s
        if inj.active(t, "unknown_ids"):
            self.bus.send(can.Message(arbitration_id=UNKNOWN_ID, data=bytes(8),
                                      is_extended_id=False))
        f = inj.active(t, "error_frames")
        if f is not None:
            for _ in range(int(f.value if f.value is not None else 2)):
                self.bus.send(can.Message(arbitration_id=CAN_ERR_BUSERROR, is_error_frame=True,
                                          data=bytes(8), is_extended_id=False))
        f = inj.active(t, "bus_off")
        if f is not None and not getattr(self, "_bus_off_sent", False):
            self._bus_off_sent = True
            self.bus.send(can.Message(arbitration_id=CAN_ERR_BUSOFF, is_error_frame=True,
                                      data=bytes(8), is_extended_id=False))

    def _apply_canopen_faults(self) -> None:
        """Faults CANopen's way, once each at its time, on the device's node."""
        from rig_models.canopen.node import NmtState

        co = self.co_devices
        done = self._co_faults_done
        for i, f in enumerate(self.injector.faults):
            if f.kind not in CANOPEN_FAULTS or f.kind == "sdo_abort" or i in done:
                continue
            if not f.active(self.time_s):
                continue
            done.add(i)
            if co is not None:
                co.touch()
            node = co.node_of(f.device) if co is not None else None
            if node is None:
                continue  # not a CANopen device: nothing of this kind to inject
            if f.kind == "node_heartbeat_lost":
                node.stop_heartbeat()
            elif f.kind == "node_emcy":
                node.emcy(int(f.value) if f.value is not None else 0x5000)
            elif f.kind == "drive_fault":
                drive = co.drive(f.device)
                if drive is not None:
                    drive.inject_fault(0x2310)
            elif f.kind == "drive_disabled":
                drive = co.drive(f.device)
                if drive is not None:
                    drive.disable_voltage()
            elif f.kind == "node_reboot":
                node.reboot()
            elif f.kind == "node_stopped":
                node.force_nmt(NmtState.STOPPED)

    def _apply_device_faults(self) -> None:
        if self.co_devices is not None:
            self._apply_canopen_faults()
        inj, t = self.injector, self.time_s
        if inj.active(t, "wheel_fault") and not self.wheel.fault:
            self.wheel.fault = True
            self.wheel.make_safe()
        if inj.active(t, "wheel_overspeed"):
            self.wheel.speed_rad_s = 1.1 * self.wheel.max_speed_rad_s
        self.valves.stuck_open = inj.active(t, "valve_stuck_open") is not None
        if inj.active(t, "piezo_overcurrent") and not self.piezo.overcurrent:
            self.piezo.overcurrent = True
            self.piezo.make_safe()

    # ------------------------------------------------------------------ faults at run time
    def _next_sync_time(self) -> float:
        """The rig time of the next SYNC's answer (the first SYNC does not step)."""
        return self.time_s + self.dt_s if self.tick >= 0 else self.time_s

    def _on_fault_insertion(self, data: bytes) -> None:
        """A fault-insertion frame: the fault starts at the next SYNC, as one given at start
        with that ``at_s`` would; a frame the rig cannot act on is malformed (logged)."""
        key = self.binding.fault_insertion
        where = f"fault-insertion frame (0x{key[0]:03X})" if key else "fault-insertion frame"
        try:
            kind, device, duration_s, value = decode_fault_insertion(data, where)
        except FaultFrameError as exc:
            self._tell(f"refused {exc} ({bytes(data).hex(' ')})")
            raise FrameError(str(exc)) from None
        if kind == FAULT_CLEAR:
            self.clear_faults()
            return
        self.insert_fault(FaultSpec(kind, self._next_sync_time(), duration_s, device, value))

    def insert_fault(self, spec: FaultSpec) -> None:
        """Take ``spec`` now (its ``at_s`` as given): what the rig left out for a run
        without faults (its plain telemetry senders, the CANopen nodes' direct sender) is
        built, so the fault acts exactly as one given at construction."""
        plain = not self.injector.faults
        self.injector.faults.append(spec)
        self.inserted_faults.append(spec)
        if plain:
            self._build_emitters()
            if self.co_devices is not None and self.bus is not None:
                for node in self.co_devices.nodes.values():
                    node.send = self._send_raw
        if self.co_devices is not None and spec.kind == "sdo_abort":
            node = self.co_devices.node_of(spec.device)
            if node is not None:
                node.sdo_abort_next(int(spec.value) if spec.value is not None else 0x1017,
                                    0x08000020)
        what = spec.kind + (f":{spec.device}" if spec.device else "")
        dur = f" for {spec.duration_s:g} s" if spec.duration_s > 0 else ""
        val = f", value {spec.value:g}" if spec.value is not None else ""
        self._tell(f"fault inserted at t = {self.time_s:.3f} s (tick {self.sync_index}): "
                   f"{what} from t = {spec.at_s:.3f} s{dur}{val}")

    def clear_faults(self) -> None:
        """End every fault (given at start or inserted) from the next SYNC on."""
        end = self._next_sync_time()
        self.injector.faults[:] = ended(self.injector.faults, end)
        self._tell(f"faults cleared at t = {self.time_s:.3f} s (tick {self.sync_index}): none "
                   f"from t = {end:.3f} s")

    def _tell(self, text: str) -> None:
        if self.on_fault_inserted is not None:
            self.on_fault_inserted(text)

    # ------------------------------------------------------------------ commands
    def _on_heartbeat(self, data: bytes) -> None:
        armed = self.binding.heartbeat.decode_armed(data)  # type: ignore[union-attr]
        self.last_heartbeat_s = self.time_s
        self.last_heartbeat_wall = self.wall_now()
        self.armed = armed
        self.safe = False
        if not self.armed:
            self.make_safe()
            self.safe = False

    def _command_handler(self, cmaps: tuple[CommandMap, ...],
                         apply: dict[str, Callable[[dict[str, float]], None]]
                         ) -> Callable[[bytes], None]:
        # each map decodes straight into its device's command arguments (positional: no
        # dict of quantities per frame). An end-to-end protected frame (a checksum declared)
        # is dropped as a device drops it: a wrong checksum raises FrameError (counted as
        # malformed by the caller), and with an alive counter, a frame repeating the last
        # accepted counter value is not applied (a stale or replayed frame)
        decoders = []
        for cmap in cmaps:
            names, defaults, apply_args = self._command_args[cmap.device]
            counted = cmap.checksum is not None and cmap.counter is not None
            decoders.append((cmap.decoder(names, defaults, counted), apply_args, counted,
                             [None]))
        counters = self.counters

        def handler(data: bytes) -> None:
            for decode, apply_args, counted, last in decoders:
                values = decode(data)
                if values is not None:
                    if counted:
                        count = values[-1]
                        if count == last[0]:
                            counters.repeated += 1
                            return
                        last[0] = count
                        values = values[:-1]
                    if self.armed:
                        apply_args(*values)
                    return
        return handler

    # each actuator's command quantities with the value a frame without one means, and
    # what applies them; the dict forms serve the CANopen nodes' commands
    def _wheel_args(self, torque_cmd: float, enable: float) -> None:
        self.wheel.command(torque_cmd, bool(enable))

    def _valve_args(self, valve_pos: float, valve_neg: float) -> None:
        pos, neg = int(valve_pos), int(valve_neg)
        self.valves.command(0 if pos and neg else pos - neg)

    def _piezo_args(self, voltage_ch1: float, voltage_ch2: float) -> None:
        self.piezo.command(voltage_ch1, voltage_ch2)

    def _rotor_args(self, speed_cmd: float, enable: float) -> None:
        self.rotor.command(speed_cmd, bool(enable))

    def _wheel_cmd(self, v: dict[str, float]) -> None:
        self._wheel_args(v.get("torque_cmd", 0.0), v.get("enable", 1))

    def _valve_cmd(self, v: dict[str, float]) -> None:
        self._valve_args(v.get("valve_pos", 0), v.get("valve_neg", 0))

    def _piezo_cmd(self, v: dict[str, float]) -> None:
        self._piezo_args(v.get("voltage_ch1", 0.0), v.get("voltage_ch2", 0.0))

    def _rotor_cmd(self, v: dict[str, float]) -> None:
        self._rotor_args(v.get("speed_cmd", 0.0), v.get("enable", 1))

    def make_safe(self, watchdog: bool = False) -> None:
        self.wheel.make_safe()
        self.valves.make_safe()
        self.piezo.make_safe()
        self.rotor.make_safe()
        self.armed = False
        self.safe = True
        if self.co_devices is not None:
            self.co_devices.touch()  # the CANopen devices' commands are read again
        if watchdog:
            self.counters.watchdog_trips += 1

    # ------------------------------------------------------------------ physics
    def record_truth_tail(self, n_steps: int) -> None:
        """Keep the last ``n_steps`` steps' (time, state, true tip acceleration) in
        ``truth_tail`` (bounded): a run's noise-free truth read forward, which a rig with
        inputs after the manoeuvre (friction, a table out of level) needs; propagating the
        last state back through the free plant does not hold there."""
        tail: deque[tuple[float, np.ndarray, float]] = deque(maxlen=max(1, n_steps))
        self.truth_tail = tail

        def keep(rig: VirtualRig) -> None:
            tail.append((rig.time_s, rig.x.copy(), float(rig.y[2])))

        self.add_step_hook(keep)

    def add_step_hook(self, hook: Callable[[VirtualRig], None]) -> None:
        """Call ``hook(rig)`` after every physics step (tests, fault injection)."""
        self._hooks.append(hook)

    def step(self) -> None:
        """Advance the physics by one step with the actuators' current commands."""
        if self.co_devices is not None and not self.safe:
            co = self.co_devices
            for device in self._co_actuators:
                values = co.changed_commands(device)
                if values is not None:
                    self._apply[device](values)
        hub_torque = self.wheel.step() + self.valves.step() + self.rotor.step()
        if self.gravity_torque_n_m:
            hub_torque -= self.gravity_torque_n_m * math.sin(
                float(self.x[0]) - self.gravity_azimuth_rad)
        u = self.u
        u[0] = hub_torque
        volts = self.piezo.voltages_v
        if self._piezo_drive is not None and (volts[0] or volts[1] or self._piezo_forcing):
            drive = self._piezo_drive
            u[1:] = drive @ np.asarray(volts[:drive.shape[1]], dtype=float)
            self._piezo_forcing = bool(volts[0] or volts[1])
        xu = self._xu
        n_x = self._n_x
        xu[:n_x] = self.x
        out = self._state = self._fused @ xu
        self.x = out[:n_x]
        self.time_s += self.dt_s
        self.counters.steps += 1
        if (not self.safe
                and self.time_s - self.last_heartbeat_s > self.watchdog_timeout_s + 1e-12):
            self.make_safe(watchdog=True)
        for hook in self._hooks:
            hook(self)

    @property
    def truth(self) -> TruthSample:
        """The physics' true values at the last SYNC (the last step's; read on demand, not
        kept every tick)."""
        y = self.y
        return TruthSample(self.time_s, float(y[0]), float(y[1]), float(y[2]),
                           self.x[1 : 1 + self.n_modes])

    @property
    def y(self) -> np.ndarray:
        """The outputs (hub angle, rate, tip acceleration) after the last step: C x + D u."""
        n_x = self._n_x
        return self._state[n_x:n_x + self._n_y]

    def _on_sync(self, data: bytes) -> None:
        tick = self.binding.sync.decode(data)
        if self.tick >= 0:
            steps = tick - self.tick
            if steps <= 0 or steps > 10_000:
                steps = 1  # counter wrap or restart: advance one step
            if self.time_ops:
                perf = time.perf_counter
                for _ in range(steps):
                    t0 = perf()
                    self.step()
                    self._note_op("physics step", perf() - t0)
            else:
                for _ in range(steps):
                    self.step()
        if self.tick >= 0:
            # unwrapped (a CANopen SYNC counts 1..240): the rig's timing names the harness's
            # tick, which the run's missing frames are matched against
            self.sync_index += (tick - self.tick) % self.binding.sync.modulus or 1
        else:
            self.sync_index = tick
        self.tick = tick
        if self.injector.faults:
            self._apply_device_faults()
            self._send_fault_frames()
        self._sample_and_send(tick)
        if self.co_devices is not None:
            now = self.co_now()
            self.co_devices.poll(now)
            # the nodes count this SYNC and send their TPDOs of the values just written
            self.co_devices.handle(self.binding.sync.key[0], data, now)

    def _as_built_sensors(self, angle: float, rate: float, accel: float
                          ) -> tuple[float, float, float]:
        """The hub sensor's angle and rate and the accelerometer's input, as built: each
        sensor's latency back in the delay line, the accelerometer's bias, scale error and
        tilt (at the hub angle of its own latency)."""
        outputs = self._outputs
        outputs.append((angle, rate, accel))
        hub_angle, hub_rate, _ = outputs[-1 - self.hub_latency_ticks]
        acc_angle, _, acc_true = outputs[-1 - self.accel_latency_ticks]
        return hub_angle, hub_rate, self.accel.sensed(acc_true, acc_angle)

    def _answer_delay(self) -> None:
        """Hold the answer to a SYNC back by the devices' latency plus a uniform jitter
        (``as_built.timing``; real time only): sleep, then spin the last 0.1 ms."""
        delay = self.answer_latency_s + self.answer_jitter_s * self._answer_rng.random()
        if delay <= 0.0:
            return
        deadline = time.perf_counter() + delay
        if delay > 2e-4:
            time.sleep(delay - 1e-4)
        while time.perf_counter() < deadline:
            pass

    def _sample_and_send(self, tick: int) -> None:
        # the last step's outputs and patch volts as Python floats, one conversion a tick
        n_y0 = self._n_x
        out = self._state.tolist()
        y0, y1, y2 = out[n_y0], out[n_y0 + 1], out[n_y0 + 2]
        if self._sensor_terms:
            y0, y1, y2 = self._as_built_sensors(y0, y1, y2)
        # which devices answer this SYNC: a table by tick modulo the dividers' least common
        # multiple (or the dividers themselves beyond 10 000)
        due = (self._due_at[tick % self._due_period] if self._due_period
               else tuple(tick % self.divider[d] == 0 for d in TELEMETRY_QUANTITIES))
        hub_due, acc_due, wheel_due, valves_due, piezo_due, rotor_due = due
        emit = self._emit
        if hub_due:
            angle, rate = self.hub_sensor.sample(y0, y1)
            emit["hub_sensor"](angle, rate)
        if acc_due:
            extra = 0.0
            if self.injector.faults:
                f = self.injector.active(self.time_s, "accel_saturation")
                extra = 0.0 if f is None else (f.value if f.value is not None else 30.0)
            acc = self.accel
            a = acc.sample(y2 + extra)
            emit["accelerometer"](a, acc.counter, int(acc.saturated))
        if wheel_due:
            w = self.wheel
            self.wheel_counter = (self.wheel_counter + 1) & 0xFF
            emit["reaction_wheel"](w.speed_rad_s, w.torque_n_m, int(w.enabled), int(w.fault),
                                   int(w.speed_limited), int(w.torque_limited),
                                   self.wheel_counter)
        if valves_due:
            v = self.valves
            emit["thruster_valves"](int(v.state > 0), int(v.state < 0), int(v.fault),
                                    v.firings & 0xFFFF, v.on_time_s, tick & 0xFF)
        if piezo_due:
            # the patches' volts plus the amplifier's sensor noise, a draw per patch in
            # patch order (the noise sequence as before)
            normal, rms = self.noise.normal, self.piezo_noise_v
            s1 = s2 = 0.0
            n_patches = len(self.piezo_gains)
            if n_patches:
                k = n_y0 + self._n_y
                s1 = out[k] + rms * normal()
                if n_patches > 1:
                    s2 = out[k + 1] + rms * normal()
            emit["piezo_amplifier"](s1, s2, int(self.piezo.overcurrent), tick & 0xFF)
        if rotor_due:
            r = self.rotor
            emit["disturbance_rotor"](r.angle_rad % (2 * math.pi), r.speed_rad_s,
                                      int(r.enabled), tick & 0xFF)


def _nothing(*values: float) -> None:
    """A device the rig does not have on this bus: nothing is sent."""
