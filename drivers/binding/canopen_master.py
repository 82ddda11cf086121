"""The harness as CANopen master, outside the tick: set-up and leaving the nodes safe.

Set-up uses the ``canopen`` library (NMT, SDO; its notifier thread runs only during
set-up): reset communication, wait for every boot-up, check device type (0x1000) and
identity (0x1018) against the EDS (and the rig file), write the PDO mapping and synchronous
transmission types the binding decided (CiA 301's sequence: disable, count 0, entries,
count, enable), heartbeat producer (0x1017) and consumer of the harness's heartbeat
(0x1016), the devices' own error behaviour (0x1029; CiA 401 error-mode outputs
0x6206/0x6207 and 0x6443/0x6444; CiA 402 abort connection 0x6007) so that a node left
without the harness goes safe by itself, the rig file's parameters, NMT start, and CiA 402
drives through the state machine to Operation Enabled. Any failure raises SetupError naming
the node, its device, the object and (an SDO abort) the abort code's meaning; the nodes are
then sent to pre-operational. Nothing is sent before the binding was built and checked.

In the tick the harness sends SYNC and PDOs itself (``drivers.binding.canopen`` codecs).
"""

from __future__ import annotations

import struct
import threading
import time
from collections.abc import Callable
from typing import Any

import can

from drivers.binding.canopen import (
    HEARTBEAT_BASE,
    MODE_BITS,
    MODE_NAMES,
    NMT_STATES,
    CanopenBus,
    NodeSpec,
    ObjRef,
)

NMT_START, NMT_STOP, NMT_PREOP, NMT_RESET_NODE, NMT_RESET_COMM = 0x01, 0x02, 0x80, 0x81, 0x82
BOOT_TIMEOUT_S = 2.0
# the objects by which a profile's device states its own units, read during set-up (where
# the EDS has them) and reported, for commissioning to compare with the rig file's
# conversions: CiA 402 rated current and torque, the position/velocity factors and SI
# units; CiA 406 measuring units per revolution and total range; CiA 401 analog input
# offset and scaling (float)
SCALING_OBJECTS: dict[str, tuple[int, ...]] = {
    "cia402": (0x6075, 0x6076, 0x608F, 0x6090, 0x6091, 0x6092, 0x6093, 0x6094, 0x6095,
               0x6096, 0x60A8, 0x60A9),
    "cia406": (0x6001, 0x6002),
    "cia401": (0x642E, 0x642F),
}
SDO_TIMEOUT_S = 0.5
PUMPED_SDO_TIMEOUT_S = 2.0
"""An in-process virtual rig answers an SDO from a thread of the harness's own process
(``setup(pump=...)``): on a loaded host that thread may wait for the CPU longer than a
device ever would, so its answers get this long; a device on a bus keeps ``SDO_TIMEOUT_S``."""


class SetupError(RuntimeError):
    """CANopen set-up failed; the message names the node, device and object."""


def _sdo_text(exc: Exception) -> str:
    import canopen

    if isinstance(exc, canopen.SdoAbortedError):
        return f"SDO abort 0x{exc.code:08X} ({exc})"
    return f"{type(exc).__name__}: {exc}"


def nmt_frame(command: int, node_id: int = 0) -> can.Message:
    """An NMT command from the harness: transmitted (``is_rx`` False), so the run's CAN log
    records it as the harness's own frame, not as one it received."""
    return can.Message(arbitration_id=0, data=bytes((command, node_id)), is_extended_id=False,
                       is_rx=False)


class CanopenMaster:
    """Set-up and safe state of a rig's CANopen nodes over ``bus``."""

    def __init__(self, bus: can.BusABC, co: CanopenBus, dry_run: bool = False,
                 log: Callable[[can.Message], None] | None = None) -> None:
        self.bus = bus
        self.co = co
        self.dry_run = dry_run
        self.log = log
        self.report: list[dict[str, Any]] = []

    def _send(self, msg: can.Message) -> None:
        msg.timestamp = time.time()
        self.bus.send(msg)
        if self.log is not None:
            self.log(msg)

    # ------------------------------------------------------------------ set-up
    def setup(self, pump: Callable[[], object] | None = None,
              progress: Callable[[str], None] | None = None) -> list[dict[str, Any]]:
        """Bring every node to operational with the binding's PDOs (``pump``: lets an
        in-process virtual rig answer while the library waits). Returns a per-node report
        (state, identity, device type, PDO mapping written)."""
        import canopen

        net = canopen.Network(self.bus)
        stop_pump = threading.Event()
        pump_thread = None
        if pump is not None:
            def run_pump() -> None:
                while not stop_pump.is_set():
                    pump()
                    time.sleep(0.0005)
            pump_thread = threading.Thread(target=run_pump, daemon=True, name="canopen-pump")
            pump_thread.start()
        listeners = list(net.listeners)
        if self.log is not None:
            # the set-up's traffic goes to the run's CAN log too, both ways (its SDOs, the
            # nodes' boot-ups): the library sends through the network, frames come in here
            log = self.log
            send = net.send_message

            def send_logged(can_id: int, data: Any, remote: bool = False) -> None:
                send(can_id, data, remote)
                log(can.Message(arbitration_id=can_id, data=bytes(data), is_extended_id=False,
                                timestamp=time.time(), is_rx=False))

            net.send_message = send_logged  # type: ignore[method-assign]

            class _Logged(can.Listener):
                def on_message_received(self, msg: can.Message) -> None:
                    log(msg)

            listeners.append(_Logged())
        net.notifier = can.Notifier(self.bus, listeners, 0.05)
        booted: dict[int, threading.Event] = {}
        try:
            remotes: dict[int, Any] = {}
            for nid, spec in self.co.nodes.items():
                rn = canopen.RemoteNode(nid, spec.od)
                rn.sdo.RESPONSE_TIMEOUT = SDO_TIMEOUT_S if pump is None else PUMPED_SDO_TIMEOUT_S
                net.add_node(rn)
                remotes[nid] = rn
                ev = booted[nid] = threading.Event()
                rn.nmt.add_heartbeat_callback(lambda state, ev=ev: state == 0 and ev.set())
            if progress:
                progress(f"CANopen: reset communication of {len(remotes)} nodes")
            self._send(nmt_frame(NMT_RESET_COMM, 0))
            deadline = time.monotonic() + BOOT_TIMEOUT_S
            for nid, ev in booted.items():
                if not ev.wait(max(0.0, deadline - time.monotonic())):
                    raise SetupError(f"{self.co.nodes[nid].label}: no boot-up within "
                                     f"{BOOT_TIMEOUT_S:g} s of reset communication (is it on "
                                     "the bus, at this node id and bit rate?)")
            for nid, rn in remotes.items():
                self.report.append(self._configure(rn, self.co.nodes[nid]))
            if progress:
                progress("CANopen: start")
            self._send(nmt_frame(NMT_START, 0))
            if not self.dry_run:
                for nid, rn in remotes.items():
                    spec = self.co.nodes[nid]
                    if spec.profile == "cia402":
                        self._enable_drive(rn, spec)
            return self.report
        except Exception as exc:
            self.leave_safe()
            if isinstance(exc, SetupError):
                raise
            raise SetupError(f"CANopen set-up: {_sdo_text(exc)}") from exc
        finally:
            net.notifier.stop(1.0)
            stop_pump.set()
            if pump_thread is not None:
                pump_thread.join(1.0)

    def _sdo(self, rn: Any, spec: NodeSpec, index: int, sub: int, what: str,
             data: bytes | None = None) -> bytes:
        try:
            if data is None:
                return bytes(rn.sdo.upload(index, sub))
            rn.sdo.download(index, sub, data)
            return data
        except Exception as exc:
            raise SetupError(f"{spec.label}: {'reading' if data is None else 'writing'} "
                             f"0x{index:04X}.{sub} ({what}): {_sdo_text(exc)}") from exc

    def _has(self, spec: NodeSpec, index: int, sub: int = 0) -> bool:
        if index not in spec.od:
            return False
        obj = spec.od[index]
        # an ODArray's ``in`` makes up sub-indices: ask what the EDS declares
        return (sub == 0) if hasattr(obj, "data_type") else sub in obj.subindices

    def _configure(self, rn: Any, spec: NodeSpec) -> dict[str, Any]:
        u32 = struct.Struct("<I")
        device_type = u32.unpack(self._sdo(rn, spec, 0x1000, 0, "device type"))[0]
        want_type = spec.device_type if spec.device_type is not None else int(
            spec.od[0x1000].default or 0)
        if device_type != want_type:
            raise SetupError(f"{spec.label}: device type 0x{device_type:08X}, the rig file / "
                             f"EDS expect 0x{want_type:08X} (another device at this node id?)")
        identity = {}
        for sub, name in ((1, "vendor_id"), (2, "product_code"), (3, "revision")):
            if not self._has(spec, 0x1018, sub):
                continue
            v = u32.unpack(self._sdo(rn, spec, 0x1018, sub, f"identity {name}"))[0]
            identity[name] = v
            want = spec.identity.get(name)
            if want is not None and v != want:
                source = spec.identity_source.get(name, "the rig file")
                raise SetupError(
                    f"{spec.label}: identity {name} (0x1018.{sub}) is 0x{v:08X} on the device, "
                    f"{source} expects 0x{want:08X}; another device at this node id? If it "
                    f"is the right one, set devices.{spec.devices[0]}.identity.{name}: "
                    f"0x{v:08X} in the rig file")
        scaling: dict[str, Any] = {}
        for index in SCALING_OBJECTS.get(spec.profile, ()):
            if index not in spec.od:
                continue
            obj = spec.od[index]
            subs = [0] if hasattr(obj, "data_type") else sorted(
                s for s in obj.subindices if s > 0)
            for sub in subs:
                var = obj if sub == 0 else obj[sub]
                raw = self._sdo(rn, spec, index, sub, f"scaling object {var.name}")
                try:
                    scaling[f"0x{index:04X}.{sub}"] = var.decode_raw(raw)
                except Exception:  # noqa: BLE001 - reported raw: commissioning names it
                    scaling[f"0x{index:04X}.{sub}"] = raw.hex()
        if spec.verify:
            self._verify_pdos(rn, spec)
        # PDOs: the binding's, every other one disabled (a DCF's: verified above instead)
        for comm_base, map_base, pdos in ([] if spec.verify else ((0x1800, 0x1A00, spec.tpdos),
                                          (0x1400, 0x1600, spec.rpdos))):
            by_number = {p.number: p for p in pdos}
            for n in range(1, 5):
                comm, mapping = comm_base + n - 1, map_base + n - 1
                if not self._has(spec, comm, 1):
                    continue
                cob = u32.unpack(self._sdo(rn, spec, comm, 1, "PDO COB-ID"))[0]
                self._sdo(rn, spec, comm, 1, "PDO disable", u32.pack(cob | 0x80000000))
                p = by_number.get(n)
                if p is None:
                    continue
                self._sdo(rn, spec, mapping, 0, "PDO mapping count", b"\x00")
                for i, e in enumerate(p.codec.entries, start=1):
                    self._sdo(rn, spec, mapping, i, f"PDO mapping entry {e.label}",
                              u32.pack(e.mapping_entry))
                self._sdo(rn, spec, mapping, 0, "PDO mapping count",
                          bytes((len(p.codec.entries),)))
                self._sdo(rn, spec, comm, 2, "PDO transmission type", bytes((p.trans_type,)))
                if comm_base == 0x1800 and self._has(spec, comm, 6):
                    # the phase of every-n-th-SYNC: the SYNC with counter s is the first
                    # counted, so the PDO goes at counters s + n - 1, s + 2n - 1, ...; the
                    # harness's counter is tick % 240 + 1, so s = 2 sends at tick % n == 0
                    # (n = 1: every SYNC, no start value needed)
                    start = 0 if p.trans_type == 1 else 2
                    self._sdo(rn, spec, comm, 6, "SYNC start value", bytes((start,)))
                self._sdo(rn, spec, comm, 1, "PDO enable", u32.pack(p.cob_id))
        if self._has(spec, 0x1019):
            pass  # the SYNC counter overflow is the master's (0x1019 on the SYNC producer)
        self._sdo(rn, spec, 0x1017, 0, "heartbeat producer time",
                  struct.pack("<H", spec.heartbeat_ms))
        if spec.heartbeat_consumer and self._has(spec, 0x1016, 1):
            try:
                self._sdo(rn, spec, 0x1016, 1, "heartbeat consumer", u32.pack(
                    self.co.master_id << 16 | self.co.consumer_timeout_ms))
            except SetupError as exc:
                raise SetupError(f"{exc}; if the device cannot consume the harness's "
                                 f"heartbeat, set devices.{spec.devices[0]}."
                                 "heartbeat_consumer: false in the rig file (docs/lab.md: what "
                                 "must then keep it safe)") from exc
        if self._has(spec, 0x1029, 1):
            self._sdo(rn, spec, 0x1029, 1, "error behaviour: pre-operational", b"\x00")
        if spec.profile == "cia401":
            for idx, sub, value, what in ((0x6206, 1, b"\xff", "error mode outputs"),
                                          (0x6207, 1, b"\x00", "error value outputs")):
                if self._has(spec, idx, sub):
                    self._sdo(rn, spec, idx, sub, what, value)
            for sub in (1, 2, 3, 4):
                if self._has(spec, 0x6443, sub):
                    self._sdo(rn, spec, 0x6443, sub, "analog output error mode", b"\x01")
                if self._has(spec, 0x6444, sub):
                    self._sdo(rn, spec, 0x6444, sub, "analog output error value", u32.pack(0))
        if spec.profile == "cia402" and self._has(spec, 0x6007):
            # 2: disable voltage when the master's heartbeat is lost (the wheel coasts with
            # no torque; quick stop would brake it against the hub)
            self._sdo(rn, spec, 0x6007, 0, "abort connection option", struct.pack("<h", 2))
        for ref, value in spec.parameters:
            self._sdo(rn, spec, ref.index, ref.sub, f"parameter {ref.name}",
                      _pack_value(ref, value))
        if spec.mode_of_operation is not None and self._has(spec, 0x6502):
            supported = u32.unpack(self._sdo(rn, spec, 0x6502, 0, "supported drive modes"))[0]
            bit = MODE_BITS.get(spec.mode_of_operation)
            if bit is not None and not supported >> bit & 1:
                raise SetupError(f"{spec.label}: supported drive modes 0x6502 = "
                                 f"0x{supported:08X} on the device lack mode "
                                 f"{spec.mode_of_operation} "
                                 f"({MODE_NAMES[spec.mode_of_operation]}), the rig file's "
                                 f"devices.{spec.devices[0]}.mode_of_operation")
        if spec.mode_of_operation is not None and self._has(spec, 0x6060):
            self._sdo(rn, spec, 0x6060, 0, "modes of operation",
                      struct.pack("<b", spec.mode_of_operation))
        return {"node_id": spec.node_id, "devices": list(spec.devices),
                "device_type": f"0x{device_type:08X}",
                **{k: f"0x{v:08X}" for k, v in identity.items()},
                "scaling": scaling,
                "tpdos": {f"TPDO{p.number}": [e.label for e in p.codec.entries]
                          for p in spec.tpdos},
                "rpdos": {f"RPDO{p.number}": [e.label for e in p.codec.entries]
                          for p in spec.rpdos}}

    def _verify_pdos(self, rn: Any, spec: NodeSpec) -> None:
        """A DCF's node: the device's PDOs must be what the DCF says (COB-ID, transmission
        type, every mapped object), or the set-up stops naming the first difference."""
        u32 = struct.Struct("<I")
        for comm_base, map_base, pdos, kind in ((0x1800, 0x1A00, spec.tpdos, "TPDO"),
                                                (0x1400, 0x1600, spec.rpdos, "RPDO")):
            for p in pdos:
                comm, mapping = comm_base + p.number - 1, map_base + p.number - 1
                where = f"{spec.label}: {kind}{p.number}"
                cob = u32.unpack(self._sdo(rn, spec, comm, 1, f"{kind} COB-ID"))[0]
                if cob & 0x80000000 or cob & 0x7FF != p.cob_id:
                    raise SetupError(f"{where}: COB-ID 0x{cob:08X} on the device, the DCF says "
                                     f"0x{p.cob_id:03X} enabled")
                trans = self._sdo(rn, spec, comm, 2, f"{kind} transmission type")[0]
                if trans != p.trans_type:
                    raise SetupError(f"{where}: transmission type {trans} on the device, the "
                                     f"DCF says {p.trans_type}")
                count = self._sdo(rn, spec, mapping, 0, f"{kind} mapping count")[0]
                want = [e.mapping_entry for e in p.codec.entries]
                if count != len(want):
                    raise SetupError(f"{where}: {count} mapped objects on the device, the DCF "
                                     f"says {len(want)}")
                for i, w in enumerate(want, start=1):
                    got = u32.unpack(self._sdo(rn, spec, mapping, i, f"{kind} mapping"))[0]
                    if got != w:
                        raise SetupError(f"{where}: mapped object {i} is 0x{got:08X} on the "
                                         f"device, the DCF says 0x{w:08X}")

    def _enable_drive(self, rn: Any, spec: NodeSpec) -> None:
        """CiA 402: fault reset if needed, shutdown -> switch on -> enable operation, each
        step confirmed by the status word."""
        def status() -> int:
            return int(struct.unpack("<H", self._sdo(rn, spec, 0x6041, 0, "status word"))[0])

        def control(word: int, what: str, mask: int, value: int) -> None:
            self._sdo(rn, spec, 0x6040, 0, f"control word {what}", struct.pack("<H", word))
            deadline = time.monotonic() + SDO_TIMEOUT_S
            while True:
                sw = status()
                if sw & mask == value:
                    return
                if time.monotonic() > deadline:
                    raise SetupError(f"{spec.label}: CiA 402 {what}: status word 0x{sw:04X} "
                                     f"did not reach 0x{value:04X} (mask 0x{mask:04X})")
                time.sleep(0.002)

        if status() & 0x08:
            control(0x80, "fault reset", 0x4F, 0x40)
        control(0x06, "shutdown", 0x6F, 0x21)
        control(0x07, "switch on", 0x6F, 0x23)
        control(0x0F, "enable operation", 0x6F, 0x27)
        if not self._has(spec, 0x6061):
            return  # a drive of one mode: it shows none (CiA 402 makes 0x6061 optional)
        mode = struct.unpack("<b", self._sdo(rn, spec, 0x6061, 0, "mode display"))[0]
        if spec.mode_of_operation is not None and mode != spec.mode_of_operation:
            raise SetupError(f"{spec.label}: modes of operation display {mode}, expected "
                             f"{spec.mode_of_operation}")

    # ------------------------------------------------------------------ safe state
    def leave_safe(self) -> None:
        """Every node to pre-operational: PDOs stop, and the profiles' error behaviour has
        already taken the outputs and drives safe (the harness sends the safe PDOs first)."""
        try:
            self._send(nmt_frame(NMT_PREOP, 0))
        except can.CanError:
            pass


def _pack_value(ref: ObjRef, value: int) -> bytes:
    return struct.pack("<" + ref.code, value)


def heartbeat_state(data: bytes | bytearray) -> str:
    return NMT_STATES.get(data[0] & 0x7F, f"0x{data[0]:02X}") if data else "empty"


def is_heartbeat(cob_id: int) -> bool:
    return HEARTBEAT_BASE < cob_id <= HEARTBEAT_BASE + 127
