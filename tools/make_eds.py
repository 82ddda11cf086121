"""Writes the virtual rig's CANopen EDS files (drivers/eds/*.eds, CiA 306 format).

The four devices are fakes of the lab's devices: the vendor id 0x53475254 ("SGRT" in ASCII)
is NOT assigned by CiA; it only marks the files as the virtual rig's. One table per device
here keeps the communication objects of the four files identical; the EDS files are
committed, and tests/test_canopen_node.py checks that they match this script's output.

    .venv/bin/python tools/make_eds.py          # rewrite drivers/eds/*.eds
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from pathlib import Path

EDS_DIR = Path(__file__).resolve().parent.parent / "drivers" / "eds"
FAKE_VENDOR_ID = 0x53475254  # "SGRT": not a CiA-assigned vendor id
FILE_DATE = "11-25-2026"

POSITION_COUNTS_PER_REV = 16384  # a 14-bit motor encoder
POSITION_RAD_PER_COUNT = 2 * 3.141592653589793 / POSITION_COUNTS_PER_REV

BOOLEAN, INTEGER8, INTEGER16, INTEGER32 = 0x1, 0x2, 0x3, 0x4
UNSIGNED8, UNSIGNED16, UNSIGNED32, VISIBLE_STRING = 0x5, 0x6, 0x7, 0x9


@dataclass
class Var:
    name: str
    data_type: int
    access: str = "ro"
    default: str | int = 0
    pdo: bool = False
    low: int | None = None
    high: int | None = None
    unit: str = ""
    factor: float | None = None
    description: str = ""


@dataclass
class Obj:
    index: int
    name: str
    kind: str  # "var", "array", "record"
    var: Var | None = None
    subs: list[Var] = field(default_factory=list)
    # sub0 of a PDO mapping holds the number of mapped entries, not the highest sub-index
    sub0_value: int | None = None


def _value(v: str | int) -> str:
    return v if isinstance(v, str) else (f"0x{v:X}" if v >= 0 else str(v))


def _var_lines(section: str, v: Var) -> list[str]:
    lines = [f"[{section}]", f"ParameterName={v.name}", "ObjectType=0x7",
             f"DataType=0x{v.data_type:04X}", f"AccessType={v.access}",
             f"DefaultValue={_value(v.default)}", f"PDOMapping={int(v.pdo)}"]
    if v.low is not None:
        lines.append(f"LowLimit={_value(v.low)}")
    if v.high is not None:
        lines.append(f"HighLimit={_value(v.high)}")
    # Unit, Factor and Description are not CiA 306 keys; the canopen library reads them
    # and other tools ignore them, so the units travel with the file.
    if v.unit:
        lines.append(f"Unit={v.unit}")
    if v.factor is not None:
        lines.append(f"Factor={v.factor!r}")
    if v.description:
        lines.append(f"Description={v.description}")
    return lines + [""]


def _obj_lines(o: Obj) -> list[str]:
    sec = f"{o.index:04X}"
    if o.kind == "var":
        assert o.var is not None
        return _var_lines(sec, o.var)
    lines = [f"[{sec}]", f"ParameterName={o.name}",
             f"ObjectType={'0x8' if o.kind == 'array' else '0x9'}",
             f"SubNumber=0x{len(o.subs) + 1:X}", ""]
    sub0_access = "rw" if o.index in range(0x1600, 0x1800) or o.index in range(0x1A00, 0x1C00) \
        or o.index == 0x1003 else "ro"
    sub0 = len(o.subs) if o.sub0_value is None else o.sub0_value
    lines += _var_lines(f"{sec}sub0", Var("Highest sub-index supported", UNSIGNED8, sub0_access,
                                          sub0))
    for i, v in enumerate(o.subs, start=1):
        lines += _var_lines(f"{sec}sub{i:X}", v)
    return lines


def var(index: int, v: Var) -> Obj:
    return Obj(index, v.name, "var", var=v)


def comm_objects(device_type: int, name: str, product: int, serial: int, error_behaviour_subs:
                 list[Var], rpdo_maps: list[tuple[bool, list[int]]],
                 tpdo_maps: list[tuple[bool, list[int]]]) -> list[Obj]:
    """The CiA 301 objects every device shares. A PDO map is (enabled, [entries]) with each
    entry index << 16 | sub << 8 | bits."""
    objs = [
        var(0x1000, Var("Device type", UNSIGNED32, "ro", device_type)),
        var(0x1001, Var("Error register", UNSIGNED8, "ro", 0, pdo=True)),
        Obj(0x1003, "Pre-defined error field", "array",
            subs=[Var(f"Standard error field {i}", UNSIGNED32, "ro", 0) for i in range(1, 9)],
            sub0_value=0),
        var(0x1005, Var("COB-ID SYNC message", UNSIGNED32, "rw", 0x80)),
        var(0x1008, Var("Manufacturer device name", VISIBLE_STRING, "const", name)),
        var(0x1009, Var("Manufacturer hardware version", VISIBLE_STRING, "const", "virtual")),
        var(0x100A, Var("Manufacturer software version", VISIBLE_STRING, "const",
                        "sgsrt-harness 0.1")),
        var(0x1014, Var("COB-ID EMCY", UNSIGNED32, "rw", "$NODEID+0x80")),
        Obj(0x1016, "Consumer heartbeat time", "array",
            subs=[Var("Consumer heartbeat time 1", UNSIGNED32, "rw", 0,
                      description="bits 16-23 producer node-ID, bits 0-15 time in ms")]),
        var(0x1017, Var("Producer heartbeat time", UNSIGNED16, "rw", 0, unit="ms")),
        Obj(0x1018, "Identity object", "record", subs=[
            Var("Vendor-ID", UNSIGNED32, "ro", FAKE_VENDOR_ID,
                description="fake: not assigned by CiA"),
            Var("Product code", UNSIGNED32, "ro", product),
            Var("Revision number", UNSIGNED32, "ro", 0x00010000),
            Var("Serial number", UNSIGNED32, "ro", serial)]),
        Obj(0x1029, "Error behaviour object", "array", subs=error_behaviour_subs),
    ]
    for base_com, base_map, cob_base, maps in ((0x1400, 0x1600, 0x200, rpdo_maps),
                                                (0x1800, 0x1A00, 0x180, tpdo_maps)):
        direction = "RPDO" if base_com == 0x1400 else "TPDO"
        for n in range(4):
            enabled, entries = maps[n] if n < len(maps) else (False, [])
            # TPDOs answer no RTR (bit 30); a disabled PDO carries bit 31 (not valid)
            cob = cob_base + 0x100 * n + (0x40000000 if direction == "TPDO" else 0) \
                + (0 if enabled else 0x80000000)
            subs = [Var("COB-ID", UNSIGNED32, "rw", f"$NODEID+0x{cob:X}"),
                    Var("Transmission type", UNSIGNED8, "rw", 1)]
            if direction == "TPDO":
                # CiA 301 sub 3..6: inhibit time, reserved, event timer, SYNC start value (the
                # SYNC whose counter equals it is the first counted: the master aligns the
                # every-n-th-SYNC phase with it)
                subs += [Var("Inhibit time", UNSIGNED16, "rw", 0),
                         Var("Compatibility entry", UNSIGNED8, "rw", 0),
                         Var("Event timer", UNSIGNED16, "rw", 0),
                         Var("SYNC start value", UNSIGNED8, "rw", 0)]
            objs.append(Obj(base_com + n, f"{direction}{n + 1} communication parameter",
                            "record", subs=subs))
            mapping = [Var(f"Mapped object {i}", UNSIGNED32, "rw",
                           entries[i - 1] if i <= len(entries) else 0) for i in range(1, 9)]
            objs.append(Obj(base_map + n, f"{direction}{n + 1} mapping parameter", "record",
                            subs=mapping, sub0_value=len(entries)))
    objs += [
        var(0x2000, Var("Station label", VISIBLE_STRING, "rw", "unlabelled",
                        description="free text the lab may write (up to 255 characters)")),
        var(0x2001, Var("Vendor command", UNSIGNED32, "wo", 0,
                        description="write-only, accepted and ignored by the virtual device")),
    ]
    return objs


def m(index: int, sub: int, bits: int) -> int:
    return index << 16 | sub << 8 | bits


def ds402(name: str, product: int, serial: int, modes: list[int], mode: int,
          rpdos: list[tuple[bool, list[int]]], tpdos: list[tuple[bool, list[int]]],
          torque: bool) -> list[Obj]:
    supported = sum(1 << {9: 8, 10: 9}[x] for x in modes)
    vel = dict(unit="rad/s", factor=0.001,
               description="vendor velocity unit: 0.001 rad/s (1 mrad/s) per count")
    objs = comm_objects(0x00020192, name, product, serial, [
        Var("Communication error", UNSIGNED8, "rw", 0, high=2,
            description="0 pre-operational, 1 no state change, 2 stopped")], rpdos, tpdos)
    objs += [
        var(0x603F, Var("Error code", UNSIGNED16, "ro", 0, pdo=True)),
        var(0x6040, Var("Controlword", UNSIGNED16, "rw", 0, pdo=True)),
        var(0x6041, Var("Statusword", UNSIGNED16, "ro", 0, pdo=True)),
        var(0x6007, Var("Abort connection option code", INTEGER16, "rw", 1, low=0, high=3,
                        description="0 no action, 1 fault, 2 disable voltage, 3 quick stop")),
        var(0x6060, Var("Modes of operation", INTEGER8, "rw", mode, pdo=True,
                        description="supported: " + ", ".join(
                            {9: "9 cyclic synchronous velocity",
                             10: "10 cyclic synchronous torque"}[x] for x in modes))),
        var(0x6061, Var("Modes of operation display", INTEGER8, "ro", 0, pdo=True)),
        var(0x6064, Var("Position actual value", INTEGER32, "ro", 0, pdo=True,
                        unit="counts", factor=POSITION_RAD_PER_COUNT,
                        description=f"{POSITION_COUNTS_PER_REV} counts per revolution")),
        var(0x606C, Var("Velocity actual value", INTEGER32, "ro", 0, pdo=True, **vel)),
        var(0x60FF, Var("Target velocity", INTEGER32, "rw", 0, pdo=True, **vel)),
        var(0x6502, Var("Supported drive modes", UNSIGNED32, "ro", supported)),
    ]
    if torque:
        objs += [
            var(0x6071, Var("Target torque", INTEGER16, "rw", 0, pdo=True, low=-1000,
                            high=1000, unit="per mille of 0x6076")),
            var(0x6072, Var("Max torque", UNSIGNED16, "rw", 1000, high=1000,
                            unit="per mille of 0x6076")),
            var(0x6076, Var("Motor rated torque", UNSIGNED32, "ro", 65, unit="mN.m",
                            factor=0.001, description="0.065 N.m, the wheel's torque limit")),
            var(0x6077, Var("Torque actual value", INTEGER16, "ro", 0, pdo=True,
                            unit="per mille of 0x6076")),
        ]
    return objs


def wheel_drive() -> tuple[list[Obj], list[str]]:
    objs = ds402("SGSRT reaction wheel drive", 0x04020001, 1, [9, 10], 10,
                 rpdos=[(True, [m(0x6040, 0, 16), m(0x6071, 0, 16)]),
                        (False, [m(0x6040, 0, 16), m(0x60FF, 0, 32)])],
                 tpdos=[(True, [m(0x6041, 0, 16), m(0x6077, 0, 16), m(0x606C, 0, 32)]),
                        (False, [m(0x6061, 0, 8), m(0x603F, 0, 16)])],
                 torque=True)
    return objs, [
        "Virtual CiA 402 servo drive of the SGSRT reaction wheel (fake vendor 0x53475254).",
        "Cyclic synchronous torque (mode 10, default) and velocity (mode 9).",
        "Torque: per mille of 0x6076 rated torque 65 mN.m, so 1 count = 6.5e-5 N.m.",
        "Velocity 0x606C and 0x60FF: vendor unit 0.001 rad/s per count.",
    ]


def rotor_drive() -> tuple[list[Obj], list[str]]:
    objs = ds402("SGSRT disturbance rotor drive", 0x04020002, 2, [9], 9,
                 rpdos=[(True, [m(0x6040, 0, 16), m(0x60FF, 0, 32)])],
                 tpdos=[(True, [m(0x6041, 0, 16), m(0x606C, 0, 32)]),
                        (False, [m(0x6061, 0, 8), m(0x603F, 0, 16)])],
                 torque=False)
    return objs, [
        "Virtual CiA 402 drive of the SGSRT disturbance rotor (fake vendor 0x53475254).",
        "Cyclic synchronous velocity (mode 9) only.",
        "Velocity 0x606C and 0x60FF: vendor unit 0.001 rad/s per count.",
        "Position 0x6064: 16384 counts per revolution.",
    ]


def io_module() -> tuple[list[Obj], list[str]]:
    volts = dict(unit="V", factor=10.0 / 32768,
                 description="+-32768 counts = +-10 V (305.2 uV per count)")
    objs = comm_objects(0x000F0191, "SGSRT I/O module", 0x04010001, 3, [
        Var("Communication error", UNSIGNED8, "rw", 0, high=2,
            description="0 pre-operational, 1 no state change, 2 stopped")],
        rpdo_maps=[(True, [m(0x6200, 1, 8)]),
                   (True, [m(0x6411, 1, 16), m(0x6411, 2, 16)])],
        tpdo_maps=[(True, [m(0x6401, 1, 16), m(0x6401, 2, 16), m(0x6401, 3, 16)]),
                   (True, [m(0x6000, 1, 8)])])
    objs += [
        Obj(0x6000, "Read input 8-bit", "array", subs=[
            Var("Read input 1h to 8h", UNSIGNED8, "ro", 0, pdo=True,
                description="bit 0 valve + open, bit 1 valve - open")]),
        Obj(0x6200, "Write output 8-bit", "array", subs=[
            Var("Write output 1h to 8h", UNSIGNED8, "rw", 0, pdo=True,
                description="bit 0 valve +, bit 1 valve -")]),
        Obj(0x6206, "Error mode output 8-bit", "array", subs=[
            Var("Error mode output 1h to 8h", UNSIGNED8, "rw", 0xFF,
                description="bit set: that output takes its 0x6207 value on an error")]),
        Obj(0x6207, "Error value output 8-bit", "array", subs=[
            Var("Error value output 1h to 8h", UNSIGNED8, "rw", 0,
                description="0: both valves closed")]),
        Obj(0x6401, "Read analog input 16-bit", "array", subs=[
            Var(f"Analog input {i} ({what})", INTEGER16, "ro", 0, pdo=True, **volts)
            for i, what in ((1, "tip accelerometer"), (2, "piezo sensor 1"),
                            (3, "piezo sensor 2"))]),
        Obj(0x6411, "Write analog output 16-bit", "array", subs=[
            Var(f"Analog output {i} (piezo amplifier input {i})", INTEGER16, "rw", 0, pdo=True,
                **volts) for i in (1, 2)]),
        Obj(0x6443, "Analog output error mode", "array", subs=[
            Var(f"Analog output {i} error mode", UNSIGNED8, "rw", 1, high=1,
                description="1: the output takes its 0x6444 value on an error")
            for i in (1, 2)]),
        Obj(0x6444, "Analog output error value", "array", subs=[
            Var(f"Analog output {i} error value", INTEGER32, "rw", 0, low=-32768, high=32767)
            for i in (1, 2)]),
    ]
    return objs, [
        "Virtual CiA 401 I/O module of the SGSRT (fake vendor 0x53475254).",
        "Digital outputs 0x6200.1: bit 0 valve +, bit 1 valve -. Inputs 0x6000.1: valve state.",
        "Analog inputs 0x6401.1-3: tip accelerometer, piezo sensors 1 and 2.",
        "Analog outputs 0x6411.1-2: piezo amplifier inputs. All analog: 10/32768 V per count.",
    ]


def encoder() -> tuple[list[Obj], list[str]]:
    objs = comm_objects(0x00020196, "SGSRT hub encoder", 0x04060001, 4, [
        Var("Communication error", UNSIGNED8, "rw", 0, high=2,
            description="0 pre-operational, 1 no state change, 2 stopped")],
        rpdo_maps=[], tpdo_maps=[(True, [m(0x6004, 0, 32), m(0x6030, 1, 32)])])
    objs += [
        var(0x6000, Var("Operating parameters", UNSIGNED16, "rw", 0)),
        var(0x6001, Var("Measuring units per revolution", UNSIGNED32, "ro", 62831853,
                        description="2 pi / 62831853 rad = 1.0e-7 rad per count")),
        var(0x6002, Var("Total measuring range in measuring units", UNSIGNED32, "ro",
                        0xFFFFFFFF)),
        var(0x6004, Var("Position value", INTEGER32, "ro", 0, pdo=True, unit="rad",
                        factor=1e-7, description="signed counts (CiA 406 has UNSIGNED32)")),
        Obj(0x6030, "Speed value", "array", subs=[
            Var("Speed value channel 1", INTEGER32, "ro", 0, pdo=True, unit="rad/s",
                factor=1e-7, description="position counts per second")]),
    ]
    return objs, [
        "Virtual CiA 406 multi-turn absolute rotary encoder of the SGSRT hub",
        "(fake vendor 0x53475254). Position 0x6004: signed counts of 1e-7 rad",
        "(INTEGER32, where CiA 406 has UNSIGNED32). Speed 0x6030.1: counts per second.",
    ]


DEVICES = {
    "sgsrt_wheel_drive.eds": ("SGSRT reaction wheel drive", wheel_drive),
    "sgsrt_rotor_drive.eds": ("SGSRT disturbance rotor drive", rotor_drive),
    "sgsrt_io_module.eds": ("SGSRT I/O module", io_module),
    "sgsrt_encoder.eds": ("SGSRT hub encoder", encoder),
}


def render(file_name: str) -> str:
    product_name, build = DEVICES[file_name]
    objs, comments = build()
    by_index = {o.index: o for o in objs}
    n_rpdo = sum(1 for i in range(0x1400, 0x1404) if i in by_index)
    n_tpdo = sum(1 for i in range(0x1800, 0x1804) if i in by_index)
    ident = by_index[0x1018].subs
    out = [
        "[FileInfo]", f"FileName={file_name}", "FileVersion=1", "FileRevision=0",
        "EDSVersion=4.0", f"Description={product_name} (virtual device of the SGSRT harness)",
        "CreationTime=12:00PM", f"CreationDate={FILE_DATE}", "CreatedBy=tools/make_eds.py",
        "ModificationTime=12:00PM", f"ModificationDate={FILE_DATE}",
        "ModifiedBy=tools/make_eds.py", "",
        "[DeviceInfo]", "VendorName=SGSRT virtual devices (not a CiA-assigned vendor)",
        f"VendorNumber=0x{FAKE_VENDOR_ID:08X}", f"ProductName={product_name}",
        f"ProductNumber=0x{ident[1].default:08X}", f"RevisionNumber=0x{ident[2].default:08X}",
        "OrderCode=virtual",
    ]
    out += [f"BaudRate_{r}={int(r == 1000)}" for r in (10, 20, 50, 125, 250, 500, 800, 1000)]
    out += ["SimpleBootUpMaster=0", "SimpleBootUpSlave=1", "Granularity=8",
            "DynamicChannelsSupported=0", "GroupMessaging=0", f"NrOfRXPDO={n_rpdo}",
            f"NrOfTXPDO={n_tpdo}", "LSS_Supported=0", "",
            "[DummyUsage]"] + [f"Dummy000{i}=0" for i in range(1, 8)] + [""]
    out += ["[Comments]", f"Lines={len(comments)}"]
    out += [f"Line{i}={c}" for i, c in enumerate(comments, start=1)] + [""]
    mandatory = [i for i in sorted(by_index) if i in (0x1000, 0x1001, 0x1018)]
    optional = [i for i in sorted(by_index) if i not in mandatory and not 0x2000 <= i < 0x6000]
    manufacturer = [i for i in sorted(by_index) if 0x2000 <= i < 0x6000]
    for section, indices in (("MandatoryObjects", mandatory), ("OptionalObjects", optional),
                             ("ManufacturerObjects", manufacturer)):
        out += [f"[{section}]", f"SupportedObjects={len(indices)}"]
        out += [f"{k}=0x{i:04X}" for k, i in enumerate(indices, start=1)] + [""]
    for i in sorted(by_index):
        out += _obj_lines(by_index[i])
    return "\r\n".join(out)


def main(argv: list[str]) -> int:
    EDS_DIR.mkdir(parents=True, exist_ok=True)
    for name in DEVICES:
        (EDS_DIR / name).write_bytes(render(name).encode("ascii"))
        print(EDS_DIR / name)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
