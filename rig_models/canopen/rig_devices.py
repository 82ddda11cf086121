"""The virtual rig's CANopen devices: the rig file's nodes, fed by the physics.

The rig file's binding (``drivers.binding.canopen``) says which node, EDS and profile each
device is and which object carries each quantity with its conversion. This module builds a
``VirtualNode`` per node from the same EDS, puts the profile on it (CiA 402 drive, CiA 401
I/O module, CiA 406 encoder) and, each SYNC, writes the physics' telemetry into the objects
(raw values through the same conversions the harness decodes with) before the nodes send
their TPDOs; the physics reads its commands back from the objects the RPDOs wrote, gated by
the profile (a CiA 402 drive not in Operation Enabled produces no torque). The nodes do the
protocol: NMT, SDO, PDO mapping, heartbeat, EMCY, error behaviour.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from drivers.binding.canopen import CanopenBus, Conversion, ObjRef, QuantityRef
from rig_models.canopen.node import NmtState, VirtualNode
from rig_models.canopen.profiles import Cia401Io, Cia402Drive, Cia406Encoder

STATUSWORD = 0x6041  # CiA 402: the drive's own; the profile publishes it

Send = Callable[[int, bytes], None]


class CanopenDevices:
    def __init__(self, co: CanopenBus, send: Send) -> None:
        self.co = co
        self.nodes: dict[int, VirtualNode] = {}
        self.profiles: dict[int, Any] = {}
        for nid, spec in co.nodes.items():
            node = VirtualNode(nid, spec.eds, send)
            self.nodes[nid] = node
            if spec.profile == "cia402":
                self.profiles[nid] = Cia402Drive(node, spec.mode_of_operation or 10)
            elif spec.profile == "cia401":
                self.profiles[nid] = Cia401Io(node)
            else:
                self.profiles[nid] = Cia406Encoder(node)
        # device -> (node, its telemetry writes, its command reads)
        self._tlm: dict[str, tuple[VirtualNode, tuple[tuple[str, ObjRef, Conversion], ...]]] = {}
        self._cmd: dict[str, tuple[VirtualNode, tuple[QuantityRef, ...]]] = {}
        for nid, spec in co.nodes.items():
            node = self.nodes[nid]
            for device, qrefs in spec.telemetry.items():
                writes = tuple((q.quantity, q.ref, q.conv) for q in qrefs
                               if q.conv.mask is None and not (
                                   spec.profile == "cia402" and q.ref.index == STATUSWORD))
                self._tlm[device] = (node, writes)
            for device, qrefs in spec.commands.items():
                self._cmd[device] = (node, qrefs)
        self.sdo_aborts: list[tuple[int, int]] = []

    def boot(self, now_s: float) -> None:
        """Power on: every node boots (boot-up frame) into pre-operational."""
        for node in self.nodes.values():
            node.poll(now_s)

    def handle(self, can_id: int, data: bytes, now_s: float) -> None:
        for node in self.nodes.values():
            node.handle(can_id, data, now_s)

    def poll(self, now_s: float) -> None:
        for node in self.nodes.values():
            node.poll(now_s)

    def write_telemetry(self, device: str, values: dict[str, float]) -> None:
        """The device's quantities into its node's objects (raw, as its TPDOs carry them)."""
        entry = self._tlm.get(device)
        if entry is None:
            return
        node, writes = entry
        bits: dict[tuple[int, int], int] = {}
        for q, ref, conv in writes:
            si = values.get(q)
            if si is None:
                continue
            raw = conv.to_raw(si, ref)
            if conv.bit is not None:
                key = (ref.index, ref.sub)
                bits[key] = bits.get(key, 0) | raw
            else:
                node.values[(ref.index, ref.sub)] = raw
        for (index, sub), v in bits.items():
            node.values[(index, sub)] = v

    def commands(self, device: str) -> dict[str, float] | None:
        """What the device is commanded now (its objects, through the conversions); a CiA
        402 drive not in Operation Enabled commands nothing. None: not a CANopen device."""
        entry = self._cmd.get(device)
        if entry is None:
            return None
        node, qrefs = entry
        values = node.values
        out = {q.quantity: q.conv.to_si(values.get((q.ref.index, q.ref.sub), 0))
               for q in qrefs}
        prof = self.profiles[node.id]
        if isinstance(prof, Cia402Drive):
            on = prof.operation_enabled and node.state == NmtState.OPERATIONAL
            out["enable"] = float(on)
            if not on:
                for k in ("torque_cmd", "speed_cmd"):
                    if k in out:
                        out[k] = 0.0
        return out

    def drive(self, device: str) -> Cia402Drive | None:
        nid = self.co.node_of.get(device)
        prof = self.profiles.get(nid) if nid is not None else None
        return prof if isinstance(prof, Cia402Drive) else None

    def node_of(self, device: str) -> VirtualNode | None:
        nid = self.co.node_of.get(device)
        return self.nodes.get(nid) if nid is not None else None
