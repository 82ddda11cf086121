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
from typing import Any, cast

from drivers.binding.canopen import CanopenBus, Conversion, ObjRef, QuantityRef
from rig_models.canopen.node import NmtState, VirtualNode
from rig_models.canopen.profiles import Cia401Io, Cia402Drive, Cia406Encoder
from rig_models.schema import ConfigError

STATUSWORD = 0x6041  # CiA 402: the drive's own; the profile publishes it

Send = Callable[[int, bytes], None]
_ONE_NODE = frozenset((0x200, 0x300, 0x400, 0x500, 0x600))  # RPDO1-4, SDO request


def _write_nothing(*values: float) -> None:
    """A device with no CANopen telemetry."""


class EmulationError(ConfigError):
    """The virtual rig cannot be this device (names the rig file's key and the EDS's
    object); the run is refused before anything is sent."""


def _emulate(nid: int, spec: Any, send: Send) -> tuple[VirtualNode, Any]:
    """The node and its profile, or EmulationError naming the key and the file's object."""
    key = f"devices.{spec.devices[0]}"
    try:
        node = VirtualNode(nid, spec.eds, send)
    except (ValueError, OSError) as exc:
        raise EmulationError(f"{key}.eds: the virtual rig cannot emulate it: {exc}") from None
    try:
        if spec.profile == "cia402":
            return node, Cia402Drive(node, spec.mode_of_operation or 10)
        if spec.profile == "cia401":
            return node, Cia401Io(node)
        return node, Cia406Encoder(node)
    except ValueError as exc:
        where = ".mode_of_operation" if str(exc).startswith("mode:") else ".profile"
        raise EmulationError(f"{key}{where}: the virtual rig cannot emulate "
                             f"{node.eds_path.name} as {spec.profile}: {exc}") from None


def check_emulation(co: CanopenBus) -> None:
    """EmulationError if the virtual rig cannot be one of the rig file's CANopen devices
    (before a run on the virtual bus, so it is refused with nothing sent)."""
    CanopenDevices(co, lambda _can_id, _data: None)


class CanopenDevices:
    def __init__(self, co: CanopenBus, send: Send) -> None:
        self.co = co
        self.nodes: dict[int, VirtualNode] = {}
        self.profiles: dict[int, Any] = {}
        for nid, spec in co.nodes.items():
            self.nodes[nid], self.profiles[nid] = _emulate(nid, spec, send)
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
        # a device's command is read again only when something that decides it changed: a
        # master's write of one of its objects, the node's NMT state, a reset, a
        # communication error (the profile's reaction), an injected fault (``touch``)
        self._dirty: set[str] = set(self._cmd)
        for device, (node, qrefs) in self._cmd.items():
            def mark(*_: object, d: str = device) -> None:
                self._dirty.add(d)
            for q in qrefs:
                node.add_write_listener(q.ref.index, q.ref.sub, mark)
            node.add_nmt_listener(mark)
            node.add_reset_listener(mark)
            node.on_comm_error.append(mark)
        self.sdo_aborts: list[tuple[int, int]] = []

    def boot(self, now_s: float) -> None:
        """Power on: every node boots (boot-up frame) into pre-operational."""
        for node in self.nodes.values():
            node.poll(now_s)

    def handle(self, can_id: int, data: bytes, now_s: float) -> None:
        """One frame from the bus to the nodes it concerns: an RPDO or SDO request (default
        COB-IDs: function code and node id) to its node only, anything else (NMT, SYNC,
        heartbeats, other COB-IDs) to every node."""
        if can_id & 0x780 in _ONE_NODE:
            node = self.nodes.get(can_id & 0x7F)
            if node is not None and node.addressed(can_id):
                node.handle(can_id, data, now_s)
                return
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

    def telemetry_writer(self, device: str, names: tuple[str, ...]) -> Callable[..., None]:
        """``telemetry_writer(device, names)(v0, v1, ...)`` is ``write_telemetry(device,
        dict(zip(names, (v0, v1, ...))))``, compiled once into one function of assignments
        (no dict, no conversion calls in the tick)."""
        entry = self._tlm.get(device)
        if entry is None:
            return _write_nothing
        node, writes = entry
        arg = {q: f"p{k}" for k, q in enumerate(names)}  # a repeated name: the last
        namespace: dict[str, Any] = {"_node": node}
        plain: list[tuple[tuple[int, int], str]] = []
        bits: dict[tuple[int, int], list[str]] = {}
        for n, (q, ref, conv) in enumerate(writes):
            x = arg.get(q)
            if x is None:
                continue
            expr = conv.raw_expression(x, ref, f"r{n}")
            if expr is None:
                namespace[f"_c{n}"], namespace[f"_ref{n}"] = conv, ref
                expr = f"_c{n}.to_raw({x}, _ref{n})"
            key = (ref.index, ref.sub)
            if conv.bit is not None:
                bits.setdefault(key, []).append(expr)
            else:
                plain.append((key, expr))
        # as write_telemetry: the plain values in order, then each bit-packed object whole
        lines = [f"def write({''.join(f'p{k}, ' for k in range(len(names)))}):",
                 "    v = _node.values"]
        lines += [f"    v[{key!r}] = {expr}" for key, expr in plain]
        lines += [f"    v[{key!r}] = {' | '.join(exprs)}" for key, exprs in bits.items()]
        exec(compile("\n".join(lines) + "\n", f"<telemetry of {device} into node {node.id}>",  # noqa: S102
                     "exec"), namespace)
        return cast(Callable[..., None], namespace["write"])

    def touch(self) -> None:
        """Something changed every device's command (an injected fault): read them again."""
        self._dirty.update(self._cmd)

    def changed_commands(self, device: str) -> dict[str, float] | None:
        """``commands(device)`` if it may have changed since the last call, else None."""
        if device not in self._dirty:
            return None
        self._dirty.discard(device)
        return self.commands(device)

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
