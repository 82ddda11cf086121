"""Pre-flight check of the rig's bus: does every device answer its SYNCs, correctly?

The probe never arms the rig: the heartbeat goes out with ``armed = 0`` and no command frame
is sent (a ``RigInterface`` in dry-run mode), so the devices stay in their safe state while
it listens. Each tick it sends SYNC and reads the telemetry through the harness's own
drivers, then counts per device: frames received, SYNCs due (its ``sync_divider``), SYNCs
it did not answer within the tick, malformed frames and sequence errors, and keeps the last
decoded values. Unknown ids and error frames on the bus are counted too. SYNCs of the first
``settle_s`` (default 0.5 s, the fault monitor's start-up allowance) go out and their answers
are read, but not counted: a socketcand server, for one, settles its connection first.

Pure logic, no printing: ``harness probe`` is the command.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import Any

import can

from drivers.dbc import load_protocol
from harness.bus.rig_interface import RigInterface
from harness.core.clock import BUS_LOCKSTEP_WAIT_S, LockstepClock, RealTimeClock
from rig_models.rig_file import RigConfig, rig_identity

HEARTBEAT_HZ = 20.0


@dataclass
class DeviceReport:
    device: str
    frame: str
    frame_id: int
    sync_divider: int
    due: int
    """SYNCs this device should have answered (after the settling time)."""
    received: int
    """Of those, the ones it answered within their tick."""
    missing: int
    """Due SYNCs not answered within their tick (late or lost)."""
    malformed: int
    sequence_errors: int
    frames: int = 0
    """Every well-formed frame of this device, settling time and late ones included."""
    last_values: dict[str, float] = field(default_factory=dict)
    last_error: str = ""

    @property
    def status(self) -> str:
        if self.frames == 0 and self.malformed == 0:
            return "silent"
        problems = []
        if self.malformed:
            problems.append(f"{self.malformed} malformed")
        if self.missing:
            problems.append(f"{self.missing} of {self.due} SYNCs unanswered")
        if self.sequence_errors:
            problems.append(f"{self.sequence_errors} sequence errors")
        return "; ".join(problems) or "ok"

    @property
    def ok(self) -> bool:
        return self.status == "ok"


@dataclass
class ProbeResult:
    bus: str
    rate_hz: float
    ticks: int
    devices: list[DeviceReport]
    unknown: int
    last_unknown_id: int
    error_frames: int
    bus_off: bool
    # CANopen: every node as set-up found it (identity, device type, the PDO mapping written
    # from the rig file); a set-up failure instead of the SYNC count
    nodes: list[dict[str, Any]] = field(default_factory=list)
    setup_error: str = ""
    # which rig was probed: rig_models.rig_file.rig_identity (name, hash, bus, binding)
    rig: dict[str, Any] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        if self.setup_error:
            return False
        return (all(d.ok for d in self.devices) and self.unknown == 0
                and self.error_frames == 0 and not self.bus_off)

    def to_dict(self) -> dict[str, Any]:
        """The report as ``harness probe --json`` prints it (and a suite's probe item)."""
        return {
            "bus": self.bus, "rate_hz": self.rate_hz, "ticks": self.ticks, "ok": self.ok,
            "unknown_ids": self.unknown, "error_frames": self.error_frames,
            "bus_off": self.bus_off,
            "devices": [dict(asdict(d), status=d.status, ok=d.ok) for d in self.devices],
            "canopen_nodes": self.nodes, "setup_error": self.setup_error,
            **self.rig,  # rig, rig_sha256, bus (the same), binding
        }


def probe(bus: can.BusABC, rig: RigConfig, rate_hz: float, duration_s: float, *,
          bus_name: str = "", pump: Callable[[], object] | None = None,
          realtime: bool = True, receive_timeout_s: float = 0.005,
          settle_s: float = 0.5) -> ProbeResult:
    """Send ``duration_s`` of SYNCs at ``rate_hz`` (disarmed heartbeat, no commands) and
    report how each device answered. ``pump`` lets an in-process virtual rig answer after
    each SYNC (then ``realtime=False`` runs as fast as it can)."""
    if not rate_hz > 0:
        raise ValueError(f"rate_hz: expected a number > 0 (Hz), got {rate_hz}")
    if not duration_s > 0:
        raise ValueError(f"duration_s: expected a number > 0 (s), got {duration_s}")
    if not settle_s >= 0:
        raise ValueError(f"settle_s: expected a number >= 0 (s), got {settle_s}")
    protocol = load_protocol()
    iface = RigInterface(bus, protocol, rig, None, (), dry_run=True)
    nodes: list[dict[str, Any]] = []
    if iface.co is not None:
        # CANopen nodes: set up (NMT, identity, PDO mapping) but, dry run, no drive enabled
        from drivers.binding.canopen_master import CanopenMaster, SetupError

        master = CanopenMaster(bus, iface.co, dry_run=True)
        try:
            nodes = master.setup(pump=pump)
        except SetupError as exc:
            return ProbeResult(bus=bus_name, rate_hz=rate_hz, ticks=0, devices=[], unknown=0,
                               last_unknown_id=0, error_frames=0, bus_off=False,
                               setup_error=str(exc), rig=rig_identity(rig.data, bus_name))
    dt_s = 1.0 / rate_hz
    clock: LockstepClock | RealTimeClock = RealTimeClock(dt_s) if realtime else LockstepClock(dt_s)
    n_settle = round(settle_s * rate_hz)
    n_ticks = n_settle + max(1, round(duration_s * rate_hz))
    heartbeat_every = max(1, round(rate_hz / HEARTBEAT_HZ))
    due = dict.fromkeys(iface.drivers, 0)
    answered = dict.fromkeys(iface.drivers, 0)
    lockstep = pump is not None and not realtime
    clock.start()
    for tick in range(n_ticks):
        clock.wait(tick)
        if tick % heartbeat_every == 0:
            iface.send_heartbeat(armed=False)
        iface.send_sync(tick)
        if pump is not None:
            pump()
        timeout = 0.0 if pump is not None else BUS_LOCKSTEP_WAIT_S
        if realtime:
            timeout = min(receive_timeout_s, max(0.0, clock.time_left(tick) - 0.3 * dt_s))
        iface.receive(tick, timeout, lockstep=lockstep)
        if tick < n_settle:
            continue
        for name, drv in iface.drivers.items():
            if tick % iface.divider[name] == 0:
                due[name] += 1
                answered[name] += drv.last_tick == tick
    if iface.co is not None:
        from drivers.binding.canopen_master import NMT_PREOP, nmt_frame

        bus.send(nmt_frame(NMT_PREOP, 0))
        if pump is not None:
            pump()
    first = {n: iface.binding.telemetry[n][0].codec for n in iface.drivers}
    devices = [
        DeviceReport(
            device=name, frame=first[name].name, frame_id=first[name].frame_id,
            sync_divider=iface.divider[name], due=due[name], received=answered[name],
            missing=due[name] - answered[name], malformed=drv.counters.malformed,
            sequence_errors=drv.counters.sequence_errors, frames=drv.counters.received,
            last_values=dict(drv.values),
            last_error=drv.counters.last_error)
        for name, drv in iface.drivers.items()
    ]
    c = iface.counters
    return ProbeResult(bus=bus_name, rate_hz=rate_hz, ticks=n_ticks - n_settle, devices=devices,
                       unknown=c.unknown, last_unknown_id=c.last_unknown_id,
                       error_frames=c.error_frames, bus_off=c.bus_off, nodes=nodes,
                       rig=rig_identity(rig.data, bus_name))
