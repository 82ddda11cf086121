"""The device binding: which frames (or CANopen objects) carry each device's quantities.

A layer of its own between the bus and the drivers' typed values: the drivers, RigState
and RigCommand see only quantities (``drivers.binding.quantities``), in SI; a rig file says
how each device speaks:

- ``sgsrt`` (the default): this project's ``drivers/sgsrt.dbc``;
- ``dbc``: any DBC file, with a map from each quantity to a message and signal and the
  conversion to SI (``scale``/``offset``: SI = value x scale + offset, or a sensor's
  ``sensitivity``/``offset``: value = offset + sensitivity x SI), both byte orders,
  extended ids, multiplexed messages, optional alive counters, and per message an optional
  end-to-end checksum (``checksums:``, ``drivers.binding.e2e``);
- ``canopen``: a node id, an EDS/DCF file and a CiA profile (``drivers.binding.canopen``);
- ``none``: the rig has no such device (a run that needs it is refused).

The same binding serves the harness (decode telemetry, encode commands) and the virtual rig
(the reverse), so CI tests the protocol the lab runs. Frame and signal names live in rig
files and DBC/EDS files, never in code (the sgsrt defaults below are the one exception: they
ARE the sgsrt protocol).

May import: ``drivers.dbc``, ``drivers.canopen_pdo``, ``drivers.device_file``, ``canopen``
(EDS parsing only), ``crccheck`` (through ``drivers.binding.e2e``). Never ``harness`` or
``rig_models``.
"""

from __future__ import annotations

import errno
import stat
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from drivers.binding.e2e import COVERS, SCHEMES, Checksum
from drivers.binding.frames import (
    BindingError,
    CommandMap,
    HeartbeatMap,
    SignalMap,
    SyncMap,
    TelemetryMap,
    linear_conversion,
)
from drivers.binding.quantities import (
    COMMANDS,
    DEVICES,
    REQUIRED_COMMANDS,
    REQUIRED_TELEMETRY,
    TELEMETRY,
)
from drivers.dbc import DBC_PATH, FrameCodec, Protocol, load_protocol
from drivers.device_file import kind_of

__all__ = ["BindingError", "RigBinding", "absolutize", "build_binding", "resolve_file", "KINDS"]

KINDS = ("sgsrt", "dbc", "canopen", "none")
FAULT_INSERTION_NAME = "FAULT_INSERTION"
"""The fault-insertion unit's frame as logs and reports name it (``bus.fault_insertion_id``)."""
DRIVERS_DIR = Path(__file__).resolve().parent.parent

# the sgsrt protocol: device -> (telemetry message, command message)
SGSRT_FRAMES: dict[str, tuple[str, str | None]] = {
    "hub_sensor": ("HUB_TLM", None),
    "accelerometer": ("ACCEL_TLM", None),
    "reaction_wheel": ("WHEEL_TLM", "WHEEL_CMD"),
    "thruster_valves": ("VALVE_TLM", "VALVE_CMD"),
    "piezo_amplifier": ("PIEZO_TLM", "PIEZO_CMD"),
    "disturbance_rotor": ("ROTOR_TLM", "ROTOR_CMD"),
}
# sgsrt telemetry counters checked for sequence by the drivers: none. The drivers' class
# attributes meant to check the wheel's and accelerometer's never took effect (a dataclass
# field's default shadowed them), and the monitor judges lost frames (2 of the last 20) and
# the accelerometer's sample counter (stuck, late) itself; a per-frame sequence fault would
# make one lost frame fatal. A DBC binding opts in per device (a counter with ``modulus``).
SGSRT_SEQUENCE: dict[str, tuple[str, int]] = {}


@dataclass(frozen=True)
class FrameInfo:
    """One frame of the binding, for replay and review: its name, device and direction."""

    key: tuple[int, bool]
    name: str
    device: str  # a device, or "harness" for SYNC / heartbeat
    kind: str  # "tlm", "cmd", "sync", "heartbeat"
    codec: FrameCodec


@dataclass
class RigBinding:
    """Every device's frames, both directions, built from a rig file."""

    kinds: dict[str, str]
    sync: Any  # SyncMap, or canopen.CanopenSync
    heartbeat: Any  # HeartbeatMap, canopen.CanopenHeartbeat, or None
    telemetry: dict[str, tuple[TelemetryMap, ...]]
    commands: dict[str, tuple[CommandMap, ...]]
    sequence: dict[str, tuple[str, int]] = field(default_factory=dict)
    files: dict[str, str] = field(default_factory=dict)  # device -> DBC/EDS path
    canopen: Any = None  # drivers.binding.canopen.CanopenBus when a device binds canopen
    # what is wrong in the device files but not in what the rig binds (a DBC's message no
    # device uses): a line each, the harness shows them before a run
    warnings: list[str] = field(default_factory=list)
    # the fault-insertion unit's frame (``bus.fault_insertion_id``), None: the rig has none
    fault_insertion: tuple[int, bool] | None = None

    @property
    def bound(self) -> tuple[str, ...]:
        """The devices the rig has (binding other than ``none``)."""
        return tuple(d for d in DEVICES if self.kinds[d] != "none")

    def telemetry_by_key(self) -> dict[tuple[int, bool], tuple[TelemetryMap, ...]]:
        out: dict[tuple[int, bool], list[TelemetryMap]] = {}
        for maps in self.telemetry.values():
            for m in maps:
                out.setdefault(m.key, []).append(m)
        return {k: tuple(v) for k, v in out.items()}

    def commands_by_key(self) -> dict[tuple[int, bool], tuple[CommandMap, ...]]:
        out: dict[tuple[int, bool], list[CommandMap]] = {}
        for maps in self.commands.values():
            for m in maps:
                out.setdefault(m.key, []).append(m)
        return {k: tuple(v) for k, v in out.items()}

    def frames(self) -> list[FrameInfo]:
        """Every frame the binding knows (a multiplexed message once per device)."""
        out = [FrameInfo(self.sync.key, self.sync.codec.name, "harness", "sync",
                         self.sync.codec)]
        if self.heartbeat is not None:
            out.append(FrameInfo(self.heartbeat.key, self.heartbeat.codec.name, "harness",
                                 "heartbeat", self.heartbeat.codec))
        seen: set[tuple[tuple[int, bool], str]] = set()
        for kind, table in (("tlm", self.telemetry), ("cmd", self.commands)):
            for device, maps in table.items():
                for m in maps:
                    if (m.key, device) not in seen:
                        seen.add((m.key, device))
                        out.append(FrameInfo(m.key, m.codec.name, device, kind, m.codec))
        return out

    def is_sgsrt(self) -> bool:
        return all(k in ("sgsrt", "none") for k in self.kinds.values())


def resolve_file(value: Any, key: str, base_dir: Path | None, subdir: str = "") -> Path:
    """A DBC/EDS path of a rig file: absolute, relative to the rig file's folder, or a file
    shipped in ``drivers/`` (``drivers/eds/`` for EDS files)."""
    if not isinstance(value, str) or not value:
        raise BindingError(f"{key}: expected a file path, got {value!r}")
    p = Path(value)
    candidates = [p] if p.is_absolute() else (
        ([base_dir / p] if base_dir is not None else []) + [DRIVERS_DIR / subdir / p,
                                                            DRIVERS_DIR / p])
    for c in candidates:
        try:
            mode = c.stat().st_mode
        except (OSError, ValueError) as exc:  # absent, or a name the file system refuses
            if isinstance(exc, OSError) and exc.errno == errno.ENAMETOOLONG:
                raise BindingError(f"{key}: the path is too long for the file system "
                                   f"({len(str(c))} characters)") from None
            continue
        if not stat.S_ISREG(mode):
            raise BindingError(f"{key}: {c.name}: {kind_of(mode)}, not a regular file")
        return c.resolve()
    raise BindingError(f"{key}: file {value!r} not found (looked in: "
                       f"{', '.join(str(c.parent) for c in candidates)})")


def _is_file(path: Path) -> bool:
    """``path.is_file()``, False for a name the file system refuses (too long, a NUL)."""
    try:
        return path.is_file()
    except (OSError, ValueError):
        return False


def absolutize(data: Mapping[str, Any], base_dir: Path | None) -> dict[str, Any]:
    """A copy of rig data whose DBC/EDS paths relative to the rig file's folder are made
    absolute, so the data stays valid wherever it goes (a run's config.yaml, a rig
    process, rig overrides). Anything else is left for ``build_binding`` to judge."""
    out = dict(data)
    if base_dir is None:
        return out

    def fix(cfg: Any) -> Any:
        if not isinstance(cfg, Mapping):
            return cfg
        cfg = dict(cfg)
        for k in ("dbc", "eds"):
            v = cfg.get(k)
            if isinstance(v, str) and v and not Path(v).is_absolute() and _is_file(base_dir / v):
                cfg[k] = str((base_dir / v).resolve())
        return cfg

    if isinstance(out.get("devices"), Mapping):
        out["devices"] = {d: fix(c) for d, c in out["devices"].items()}
    if isinstance(out.get("bus"), Mapping):
        out["bus"] = dict(out["bus"], **{k: fix(out["bus"][k]) for k in ("sync", "heartbeat")
                                         if k in out["bus"]})
    return out


def _mapping(value: Any, key: str) -> Mapping[str, Any]:
    if value is None:
        return {}
    if not isinstance(value, Mapping):
        raise BindingError(f"{key}: expected a mapping, got {value!r}")
    return value


def _load_dbc(path: Path, key: str) -> Protocol:
    try:
        return load_protocol(str(path))
    except BindingError:
        raise
    except Exception as exc:  # cantools raises many kinds for a bad file
        raise BindingError(f"{key}: {path.name}: cannot load the DBC ({exc})") from exc


def _message(protocol: Protocol, name: Any, key: str, path: Path) -> FrameCodec:
    if isinstance(name, str) and name in protocol.problems:
        raise BindingError(f"{key}.message: {name} of {path.name} is not exact: "
                           f"{protocol.problems[name]}")
    if not isinstance(name, str) or name not in protocol.by_name:
        known = ", ".join(sorted(protocol.by_name))
        raise BindingError(f"{key}.message: {name!r} is not a message of {path.name} "
                           f"(messages: {known})")
    return protocol.by_name[name]


def _signal(codec: FrameCodec, name: Any, key: str) -> str:
    if not isinstance(name, str) or name not in codec.signal_names:
        raise BindingError(f"{key}.signal: {name!r} is not a signal of {codec.name} "
                           f"(signals: {', '.join(codec.signal_names)})")
    return name


_SIGNAL_KEYS = {"message", "signal", "scale", "offset", "sensitivity", "mux", "modulus"}


def _signal_map(quantity: str, spec: Any, key: str, protocol: Protocol, path: Path
                ) -> tuple[FrameCodec, SignalMap, int | None, int | None]:
    spec = _mapping(spec, key)
    unknown = sorted(set(spec) - _SIGNAL_KEYS, key=str)
    if unknown:
        raise BindingError(f"{key}.{unknown[0]}: unknown key (expected one of: "
                           f"{', '.join(sorted(_SIGNAL_KEYS))})")
    codec = _message(protocol, spec.get("message"), key, path)
    signal = _signal(codec, spec.get("signal"), key)
    scale, offset = linear_conversion(spec, key, "DBC value")
    mux = spec.get("mux")
    mux_signal = getattr(codec, "multiplexer", None)
    if mux is not None:
        if mux_signal is None:
            raise BindingError(f"{key}.mux: {codec.name} is not multiplexed")
        if isinstance(mux, bool) or not isinstance(mux, int):
            raise BindingError(f"{key}.mux: expected an integer, got {mux!r}")
        sig = next(s for s in codec.signals if s.name == signal)
        pages = getattr(sig, "multiplexer_ids", None)
        if pages is not None and mux not in pages:
            raise BindingError(f"{key}: signal {signal} is not on {codec.name}'s page "
                               f"{mux_signal} = {mux} (it is on {list(pages)})")
    elif mux_signal is not None:
        raise BindingError(f"{key}.mux: {codec.name} is multiplexed by {mux_signal}: say "
                           "which page (mux value) carries this quantity")
    modulus = spec.get("modulus")
    if modulus is not None and (isinstance(modulus, bool) or not isinstance(modulus, int)
                                or modulus < 2):
        raise BindingError(f"{key}.modulus: expected an integer >= 2, got {modulus!r}")
    return codec, SignalMap(quantity, signal, scale, offset), mux, modulus


def _signal_length(codec: FrameCodec, name: str) -> int:
    return next(s.length for s in codec.signals if s.name == name)


def _dbc_device(device: str, cfg: Mapping[str, Any], key: str, base_dir: Path | None
                ) -> tuple[tuple[TelemetryMap, ...], tuple[CommandMap, ...],
                           tuple[str, int] | None, str]:
    allowed = {"binding", "dbc", "telemetry", "commands", "checksums"}
    unknown = sorted(set(cfg) - allowed, key=str)
    if unknown:
        raise BindingError(f"{key}.{unknown[0]}: unknown key (expected one of: "
                           f"{', '.join(sorted(allowed))})")
    path = resolve_file(cfg.get("dbc"), f"{key}.dbc", base_dir)
    protocol = _load_dbc(path, f"{key}.dbc")
    tlm_cfg = _mapping(cfg.get("telemetry"), f"{key}.telemetry")
    groups: dict[tuple[str, int | None], list[SignalMap]] = {}
    codecs: dict[str, FrameCodec] = {}
    sequence: tuple[str, int] | None = None
    for q, spec in tlm_cfg.items():
        qkey = f"{key}.telemetry.{q}"
        if q not in TELEMETRY[device]:
            raise BindingError(f"{qkey}: unknown quantity of {device} (expected one of: "
                               f"{', '.join(TELEMETRY[device])})")
        codec, sm, mux, modulus = _signal_map(q, spec, qkey, protocol, path)
        if q in ("counter", "sample_counter"):  # a counter wraps at its signal's width
            sm = SignalMap(sm.quantity, sm.signal, sm.scale, sm.offset,
                           modulus or 1 << _signal_length(codec, sm.signal))
        codecs[codec.name] = codec
        groups.setdefault((codec.name, mux), []).append(sm)
        if q == "counter" and modulus is not None:
            sequence = (q, modulus)
    missing = [q for q in REQUIRED_TELEMETRY[device] if q not in tlm_cfg]
    if missing:
        raise BindingError(f"{key}.telemetry.{missing[0]}: missing; the harness needs "
                           f"{', '.join(REQUIRED_TELEMETRY[device])} of the {device}")
    cgroups: dict[tuple[str, int | None], list[SignalMap]] = {}
    counter: dict[str, tuple[str, int]] = {}
    if device in COMMANDS:
        cmd_cfg = dict(_mapping(cfg.get("commands"), f"{key}.commands"))
        counter_cfg = cmd_cfg.pop("counter", None)
        for q, spec in cmd_cfg.items():
            qkey = f"{key}.commands.{q}"
            if q not in COMMANDS[device]:
                raise BindingError(f"{qkey}: unknown command of {device} (expected one of: "
                                   f"{', '.join(list(COMMANDS[device]) + ['counter'])})")
            codec, sm, mux, _ = _signal_map(q, spec, qkey, protocol, path)
            codecs[codec.name] = codec
            cgroups.setdefault((codec.name, mux), []).append(sm)
        missing = [q for q in REQUIRED_COMMANDS[device] if q not in cmd_cfg]
        if missing:
            raise BindingError(f"{key}.commands.{missing[0]}: missing; the harness commands "
                               f"{', '.join(REQUIRED_COMMANDS[device])} of the {device}")
        if counter_cfg is not None:
            ckey = f"{key}.commands.counter"
            codec, sm, _, modulus = _signal_map("counter", counter_cfg, ckey, protocol, path)
            if (codec.name, None) not in cgroups and not any(n == codec.name for n, _ in cgroups):
                raise BindingError(f"{ckey}.message: {codec.name} carries no command of the "
                                   f"{device}")
            counter[codec.name] = (sm.signal, modulus or 1 << _signal_length(codec, sm.signal))
    elif cfg.get("commands"):
        raise BindingError(f"{key}.commands: the {device} takes no commands")
    # each bound message's checksum, if declared: set last, over what the maps encode
    used: dict[str, set[str]] = {}  # message -> the signals the device maps in it
    for (name, _), fields in (*groups.items(), *cgroups.items()):
        used.setdefault(name, set()).update(f.signal for f in fields)
    for name, (sig, _) in counter.items():
        used[name].add(sig)
    sums = _checksums(device, cfg.get("checksums"), f"{key}.checksums", protocol, used)
    tlm = tuple(TelemetryMap(device, codecs[name], tuple(fields), mux, sums.get(name))
                for (name, mux), fields in groups.items())
    cmds = tuple(CommandMap(device, codecs[name], tuple(fields), counter.get(name), mux,
                            sums.get(name))
                 for (name, mux), fields in cgroups.items())
    return tlm, cmds, sequence, str(path)


_CHECKSUM_KEYS = {"signal", "scheme", "data_id", "covers"}


def _checksums(device: str, raw: Any, key: str, protocol: Protocol,
               used: Mapping[str, set[str]]) -> dict[str, Checksum]:
    """A DBC device's ``checksums:``: message name -> {signal, scheme, data_id?, covers?},
    for messages the device binds (telemetry or command). Raises BindingError naming the
    key."""
    out: dict[str, Checksum] = {}
    for name, spec in _mapping(raw, key).items():
        mkey = f"{key}.{name}"
        if name not in used:
            raise BindingError(f"{mkey}: {name!r} is not a message the {device} binds (its "
                               f"messages: {', '.join(sorted(used))})")
        codec = protocol.by_name[name]
        spec = _mapping(spec, mkey)
        unknown = sorted(set(spec) - _CHECKSUM_KEYS, key=str)
        if unknown:
            raise BindingError(f"{mkey}.{unknown[0]}: unknown key (expected one of: "
                               f"{', '.join(sorted(_CHECKSUM_KEYS))})")
        scheme = spec.get("scheme")
        if scheme not in SCHEMES:
            raise BindingError(f"{mkey}.scheme: unknown checksum scheme {scheme!r} (expected "
                               f"one of: {', '.join(SCHEMES)})")
        signal = _signal(codec, spec.get("signal"), mkey)
        if signal in used[name]:
            raise BindingError(f"{mkey}.signal: {signal} already carries a quantity or counter "
                               f"of the {device}")
        sig = next(s for s in codec.signals if s.name == signal)
        aligned = sig.start % 8 == (7 if sig.byte_order == "big_endian" else 0)
        if (sig.length != 8 or not aligned or sig.signed or sig.is_float or sig.scale != 1
                or sig.offset != 0):
            raise BindingError(f"{mkey}.signal: {signal} of {name} must be one whole byte (8 "
                               "bits, unsigned, on a byte boundary, scale 1, offset 0) for an "
                               "8-bit checksum")
        byte = sig.start // 8
        covers = spec.get("covers", "payload")
        if covers not in COVERS:
            raise BindingError(f"{mkey}.covers: expected one of {', '.join(COVERS)}, got "
                               f"{covers!r}")
        if "covers" in spec and scheme.startswith("autosar"):
            raise BindingError(f"{mkey}.covers: the AUTOSAR profiles fix what they cover "
                               "(every byte but the checksum's own, with the data id)")
        data_id = spec.get("data_id")
        if scheme.startswith("autosar"):
            data_id = _data_id(scheme, data_id, f"{mkey}.data_id", byte, codec.length)
        elif data_id is not None:
            raise BindingError(f"{mkey}.data_id: {scheme} takes no data id (only autosar_p1 "
                               "and autosar_p2 do)")
        out[name] = Checksum(scheme, signal, byte, name, data_id, covers, codec.length)
    return out


def _data_id(scheme: str, value: Any, key: str, byte: int, length: int) -> int | list[int]:
    """An AUTOSAR profile's data id: Profile 1 a 16-bit id; Profile 2 an 8-bit id, or the
    profile's list of 16 chosen by the counter in byte 1 (checksum in byte 0)."""
    top = 0xFFFF if scheme == "autosar_p1" else 0xFF

    def one(v: Any) -> int:
        if isinstance(v, bool) or not isinstance(v, int) or not 0 <= v <= top:
            raise BindingError(f"{key}: expected an integer 0..0x{top:X}, got {v!r}")
        return v

    if value is None:
        raise BindingError(f"{key}: missing; {scheme} needs the message's data id")
    if scheme == "autosar_p2" and isinstance(value, list):
        if len(value) != 16:
            raise BindingError(f"{key}: a list of 16 data ids (one per counter value), got "
                               f"{len(value)}")
        if byte != 0 or length < 2:
            raise BindingError(f"{key}: a list of data ids needs Profile 2's layout (the "
                               "checksum in byte 0, the counter in byte 1's low nibble)")
        return [one(v) for v in value]
    return one(value)


def _sgsrt_device(device: str, protocol: Protocol
                  ) -> tuple[tuple[TelemetryMap, ...], tuple[CommandMap, ...]]:
    tlm_name, cmd_name = SGSRT_FRAMES[device]
    codec = protocol[tlm_name]
    tlm = (TelemetryMap(device, codec, tuple(SignalMap(s, s) for s in codec.signal_names)),)
    cmds: tuple[CommandMap, ...] = ()
    if cmd_name is not None:
        c = protocol[cmd_name]
        cmds = (CommandMap(device, c, tuple(SignalMap(s, s) for s in c.signal_names
                                            if s != "counter"), counter=("counter", 256)),)
    return tlm, cmds


def _sync_and_heartbeat(bus: Mapping[str, Any], base_dir: Path | None, sgsrt: Protocol
                        ) -> tuple[SyncMap, HeartbeatMap | None, bool]:
    """(SYNC, heartbeat, whether the SYNC is sgsrt's)."""
    sync_cfg = bus.get("sync")
    hb_cfg = bus.get("heartbeat")
    if sync_cfg is None or sync_cfg == "sgsrt":
        sync, sgsrt_sync = SyncMap(sgsrt["SYNC"], "tick"), True
    else:
        cfg = _mapping(sync_cfg, "bus.sync")
        unknown = sorted(set(cfg) - {"dbc", "message", "signal"}, key=str)
        if unknown:
            raise BindingError(f"bus.sync.{unknown[0]}: unknown key (expected dbc, message, "
                               "signal)")
        path = resolve_file(cfg.get("dbc"), "bus.sync.dbc", base_dir)
        p = _load_dbc(path, "bus.sync.dbc")
        codec = _message(p, cfg.get("message"), "bus.sync", path)
        sync, sgsrt_sync = SyncMap(codec, _signal(codec, cfg.get("signal"), "bus.sync")), False
    if hb_cfg is None or hb_cfg == "sgsrt":
        hb = HeartbeatMap(sgsrt["HEARTBEAT"], "counter", "armed")
    else:
        cfg = _mapping(hb_cfg, "bus.heartbeat")
        unknown = sorted(set(cfg) - {"dbc", "message", "counter", "armed"}, key=str)
        if unknown:
            raise BindingError(f"bus.heartbeat.{unknown[0]}: unknown key (expected dbc, "
                               "message, counter, armed)")
        path = resolve_file(cfg.get("dbc"), "bus.heartbeat.dbc", base_dir)
        p = _load_dbc(path, "bus.heartbeat.dbc")
        codec = _message(p, cfg.get("message"), "bus.heartbeat", path)
        counter = cfg.get("counter")
        if counter is not None:
            _signal(codec, counter, "bus.heartbeat.counter")
        armed = _signal(codec, cfg.get("armed"), "bus.heartbeat.armed")
        hb = HeartbeatMap(codec, counter, armed)
    return sync, hb, sgsrt_sync


def build_binding(data: Mapping[str, Any], base_dir: Path | None = None) -> RigBinding:
    """The binding of a validated rig file's data (``devices:`` and ``bus.sync`` /
    ``bus.heartbeat``). Raises BindingError naming the key."""
    sgsrt = load_protocol(str(DBC_PATH))
    devices = _mapping(data.get("devices"), "devices")
    unknown = sorted(set(devices) - set(DEVICES), key=str)
    if unknown:
        raise BindingError(f"devices.{unknown[0]}: unknown device (expected one of: "
                           f"{', '.join(DEVICES)})")
    kinds: dict[str, str] = {}
    telemetry: dict[str, tuple[TelemetryMap, ...]] = {}
    commands: dict[str, tuple[CommandMap, ...]] = {}
    sequence: dict[str, tuple[str, int]] = {}
    files: dict[str, str] = {}
    co_cfgs: dict[str, Mapping[str, Any]] = {}
    for device in DEVICES:
        key = f"devices.{device}"
        cfg = devices.get(device)
        if cfg is None or cfg == "sgsrt":
            cfg = {"binding": "sgsrt"}
        elif cfg == "none":
            cfg = {"binding": "none"}
        cfg = _mapping(cfg, key)
        kind = cfg.get("binding", "sgsrt")
        if kind not in KINDS:
            raise BindingError(f"{key}.binding: expected one of {', '.join(KINDS)}, got "
                               f"{kind!r}")
        kinds[device] = kind
        if kind == "none":
            telemetry[device], commands[device] = (), ()
        elif kind == "sgsrt":
            if set(cfg) - {"binding"}:
                raise BindingError(f"{key}.{sorted(set(cfg) - {'binding'})[0]}: unknown key "
                                   "(an sgsrt device takes only binding: sgsrt)")
            telemetry[device], commands[device] = _sgsrt_device(device, sgsrt)
            if device in SGSRT_SEQUENCE:
                sequence[device] = SGSRT_SEQUENCE[device]
            files[device] = str(DBC_PATH)
        elif kind == "dbc":
            tlm, cmds, seq, path = _dbc_device(device, cfg, key, base_dir)
            telemetry[device], commands[device] = tlm, cmds
            if seq is not None:
                sequence[device] = seq
            files[device] = path
        else:
            co_cfgs[device] = cfg
    bus = _mapping(data.get("bus"), "bus")
    canopen_bus = None
    if co_cfgs:
        from drivers.binding.canopen import (  # EDS parsing: only when a device binds it
            CanopenHeartbeat,
            CanopenSync,
            build_canopen,
        )

        canopen_bus, tlm_maps, cmd_maps, co_files = build_canopen(
            co_cfgs, bus.get("sync_divider") or {}, int(bus.get("master_node_id", 127)),
            base_dir, int(bus.get("heartbeat_consumer_ms", 200)))
        telemetry.update(tlm_maps)
        commands.update(cmd_maps)
        files.update(co_files)
        if bus.get("sync") not in (None, "canopen"):
            raise BindingError("bus.sync: CANopen devices answer the CiA 301 SYNC: drop "
                               "bus.sync (or say canopen)")
        sync: Any = CanopenSync()
        heartbeat: Any = CanopenHeartbeat(canopen_bus.master_id)
        sgsrt_sync = False
    else:
        if bus.get("sync") == "canopen":
            raise BindingError("bus.sync: canopen, but no device binds canopen")
        sync, heartbeat, sgsrt_sync = _sync_and_heartbeat(bus, base_dir, sgsrt)
    sg = [d for d, k in kinds.items() if k == "sgsrt"]
    if sg and not sgsrt_sync:
        raise BindingError(f"bus.sync: {', '.join(sg)} bind sgsrt, whose devices answer the "
                           "sgsrt SYNC only: bind them to the DBC or to CANopen too (or "
                           "none)")
    binding = RigBinding(kinds, sync, heartbeat, telemetry, commands, sequence, files,
                         canopen_bus)
    _check_distinct(binding)
    fid = bus.get("fault_insertion_id")
    if fid is not None:
        binding.fault_insertion = (int(fid), False)
        _check_fault_insertion(binding)
    binding.warnings = _unbound_problems(binding)
    return binding


def _unbound_problems(b: RigBinding) -> list[str]:
    """A line per message of a bound DBC that is not exact but that no device uses: the
    file loads as real ones are (non-strict), only what the rig binds must be exact."""
    used: dict[str, set[str]] = {}
    for device, kind in b.kinds.items():
        if kind == "dbc":
            names = used.setdefault(b.files[device], set())
            names.update(m.codec.name for m in (*b.telemetry[device], *b.commands[device]))
    out = []
    for path, names in used.items():
        for name, why in load_protocol(path).problems.items():
            if name not in names:
                out.append(f"{Path(path).name}: message {name}: {why} (not bound by this "
                           "rig: ignored)")
    return out


def _check_distinct(b: RigBinding) -> None:
    """No frame means two things: a telemetry page is one device's, a command frame is not
    also telemetry, SYNC and heartbeat are frames of their own."""
    owner: dict[tuple[tuple[int, bool], int | None], str] = {}
    for device, maps in b.telemetry.items():
        for m in maps:
            k = (m.key, m.mux)
            if k in owner and owner[k] != device:
                raise BindingError(f"devices.{device}.telemetry: {m.codec.name}"
                                   f"{'' if m.mux is None else f' (mux {m.mux})'} already "
                                   f"carries the {owner[k]}'s telemetry")
            owner[k] = device
    tlm_keys = {k for k, _ in owner}
    for device, cmaps in b.commands.items():
        for c in cmaps:
            if c.key in tlm_keys:
                raise BindingError(f"devices.{device}.commands: {c.codec.name} "
                                   f"(0x{c.key[0]:X}) is also a telemetry frame")
    special = [b.sync.key] + ([b.heartbeat.key] if b.heartbeat is not None else [])
    for device, cmaps in b.commands.items():
        for c in cmaps:
            if c.key in special:
                raise BindingError(f"devices.{device}.commands: {c.codec.name} has the id of "
                                   "the SYNC or heartbeat")
    if b.heartbeat is not None and b.heartbeat.key == b.sync.key:
        raise BindingError("bus.heartbeat: the same frame id as bus.sync")
    for k in tlm_keys:
        if k in special:
            raise BindingError(f"devices: a telemetry frame (0x{k[0]:X}) has the id of the SYNC "
                               "or heartbeat")


def _canopen_reserved(co: Any) -> dict[int, str]:
    """id -> what it is, for every COB-ID a CANopen network with these nodes uses or
    reserves by its predefined connection set (CiA 301), and every PDO's own COB-ID."""
    out = {0x000: "the NMT command", 0x080: "the CANopen SYNC", 0x100: "the CANopen TIME",
           0x7E4: "LSS", 0x7E5: "LSS"}
    names = {0x080: "EMCY", 0x180: "TPDO1", 0x200: "RPDO1", 0x280: "TPDO2", 0x300: "RPDO2",
             0x380: "TPDO3", 0x400: "RPDO3", 0x480: "TPDO4", 0x500: "RPDO4",
             0x580: "SDO response", 0x600: "SDO request", 0x700: "heartbeat"}
    for nid, node in co.nodes.items():
        for base, what in names.items():
            out.setdefault(base + nid, f"{what} of CANopen node {nid}")
        for p in (*node.tpdos, *node.rpdos):
            out.setdefault(p.cob_id, f"a PDO of CANopen node {nid}")
    out.setdefault(0x700 + co.master_id, "the master's heartbeat")
    return out


def _check_fault_insertion(b: RigBinding) -> None:
    """The fault-insertion frame's id is no frame of the binding: not a device's telemetry
    or command, not the SYNC or heartbeat, no message of a DBC file the rig binds, no
    COB-ID of its CANopen network."""
    assert b.fault_insertion is not None
    key = b.fault_insertion
    fid = key[0]
    where = f"bus.fault_insertion_id: 0x{fid:03X}"
    if key == b.sync.key:
        raise BindingError(f"{where} is the SYNC's id")
    if b.heartbeat is not None and key == b.heartbeat.key:
        raise BindingError(f"{where} is the master heartbeat's id")
    for kind, table in (("telemetry", b.telemetry), ("commands", b.commands)):
        for device, maps in table.items():
            for m in maps:
                if m.key == key:
                    raise BindingError(f"{where} is {m.codec.name}'s id "
                                       f"(devices.{device}.{kind})")
    for path in sorted({p for p in b.files.values() if p.lower().endswith(".dbc")}):
        for codec in load_protocol(path).by_id.values():
            if codec.frame_id == fid and not codec.is_extended:
                raise BindingError(f"{where} is message {codec.name}'s id in "
                                   f"{Path(path).name}")
    if b.canopen is not None:
        what = _canopen_reserved(b.canopen).get(fid)
        if what is not None:
            raise BindingError(f"{where} is {what}'s COB-ID")
