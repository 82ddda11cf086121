"""`harness probe [--bus I:C] [--rig R] [--rate-hz F] [--duration-s S] [--json]`: pre-flight
check that every device of the rig answers on the bus, without arming anything.

Sends SYNC at ``--rate-hz`` (default 100 Hz) for ``--settle-s`` (default 0.5 s, not counted:
a socketcand server settles its connection first) and then ``--duration-s`` (default 2 s) with
the heartbeat disarmed and no command frame, reads the telemetry through the harness's drivers
and prints one line per device: its frame, SYNC divider, frames received, SYNCs it did not
answer within the tick, malformed frames, sequence errors, status, and its last values (so
a wheel that reports a fault flag or a hub angle that makes no sense shows up before a run).
Unknown ids and error frames on the bus are reported too.

On the default in-process virtual bus (``virtual:RIG``, named after the rig) the virtual rig
answers in this process (pumped after each SYNC, as fast as it can); ``--fault
KIND@AT_S[:DEVICE]`` injects a fault there, to see what the probe reports. On
``socketcan:can0`` (the lab rig), ``socketcan:vcan0`` or ``socketcand:127.0.0.1:PORT`` the
probe runs in real time against whatever answers.

Exit status: 0 every device answered every due SYNC with well-formed frames and the bus was
clean; 3 a device is silent, late, malformed or out of sequence, or the bus carried unknown
ids or error frames; 2 bad input (unknown rig, bus that cannot be opened).
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import TYPE_CHECKING

from harness.commands import examples

if TYPE_CHECKING:
    from harness.core.probe import ProbeResult

EXIT_PROBLEM = 3


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("probe", help="check that every device answers (never arms the rig)",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter,
                       epilog=examples("harness probe",
                                       "harness probe --fault silent_sensor@0.5:hub_sensor",
                                       "harness probe --bus socketcan:can0 --rig sgsrt --json"))
    p.add_argument("--bus",
                   help="INTERFACE:CHANNEL (default virtual:RIG, the in-process virtual rig "
                   "named after the rig; "
                   "socketcan:can0 the lab rig; socketcand:127.0.0.1:PORT, loopback only)")
    p.add_argument("--rig", default="sgsrt", help="rig name or YAML path (default sgsrt)")
    p.add_argument("--rate-hz", type=float, default=100.0, help="SYNC rate (default 100 Hz)")
    p.add_argument("--duration-s", type=float, default=2.0, help="how long (default 2 s)")
    p.add_argument("--settle-s", type=float, default=0.5,
                   help="SYNCs sent first and not counted (default 0.5 s)")
    p.add_argument("--receive-timeout-ms", type=float, default=5.0,
                   help="real time: how long to wait for a tick's telemetry (default 5 ms; "
                   "never more than 70 %% of the period)")
    p.add_argument("--fault", action="append", metavar="KIND@AT_S[+DURATION_S][:DEVICE][=VALUE]",
                   help="virtual bus only: inject a fault in the in-process virtual rig")
    p.add_argument("--json", action="store_true", help="the report as JSON on stdout")
    p.set_defaults(func=cmd_probe)


def cmd_probe(args: argparse.Namespace) -> int:
    # python-can, numpy and the drivers only when the probe runs (start-up of `harness --help`)
    from harness.bus import BusSpecError, open_bus, parse_bus
    from harness.core.probe import probe
    from rig_models.faults import parse_fault
    from rig_models.rig_file import load_rig
    from rig_models.schema import ConfigError
    from rig_models.virtual_rig import VirtualRig

    rig = None
    buses = []
    try:
        if not args.rate_hz > 0:
            raise ValueError(f"--rate-hz: expected a number > 0 (Hz), got {args.rate_hz}")
        if not args.duration_s > 0:
            raise ValueError(f"--duration-s: expected a number > 0 (s), got {args.duration_s}")
        if not args.settle_s >= 0:
            raise ValueError(f"--settle-s: expected a number >= 0 (s), got {args.settle_s}")
        if not args.receive_timeout_ms > 0:
            raise ValueError("--receive-timeout-ms: expected a number > 0 (ms), got "
                             f"{args.receive_timeout_ms}")
        from harness.core.runs import virtual_bus

        rig_cfg = load_rig(args.rig)
        spec = parse_bus(args.bus or virtual_bus(rig_cfg.name))
        faults = [parse_fault(f) for f in args.fault or []]
        if faults and not spec.in_process:
            raise ValueError("--fault: only with an in-process virtual bus (virtual:NAME); for "
                             "a rig in its own process pass --fault to 'harness virtual-rig'")
        bus = open_bus(spec)
        buses.append(bus)
        pump = None
        if spec.in_process:
            rig_bus = open_bus(spec)
            buses.append(rig_bus)
            rig = VirtualRig(rig_cfg, rig_bus, 1.0 / args.rate_hz, faults=faults)
            pump = rig.service
        print(f"harness probe: {args.duration_s:g} s of SYNC at {args.rate_hz:g} Hz on {spec}, "
              f"rig {rig_cfg.name} (heartbeat disarmed, no commands) ...", file=sys.stderr,
              flush=True)
        result = probe(bus, rig_cfg, args.rate_hz, args.duration_s, bus_name=str(spec),
                       pump=pump, realtime=pump is None,
                       receive_timeout_s=args.receive_timeout_ms / 1e3, settle_s=args.settle_s)
    except (ConfigError, BusSpecError, ValueError, OSError) as exc:
        print(f"harness probe: {exc}", file=sys.stderr)
        return 2
    finally:
        for b in buses:
            b.shutdown()
    if args.json:
        print(json.dumps(result.to_dict(), indent=2))
    else:
        print_report(result)
    return 0 if result.ok else EXIT_PROBLEM


VALUE_UNITS = {"angle": "rad", "rate": "rad/s", "accel": "m/s²", "speed": "rad/s",
               "torque": "N m", "sensor_ch1": "V", "sensor_ch2": "V", "voltage_ch1": "V",
               "voltage_ch2": "V", "on_time": "s"}
"""The SI unit of each quantity the drivers decode (the rest are counters and flags)."""


def _values(values: dict[str, float]) -> str:
    """Each last value with its unit, as in verdicts (``angle 1.2e-06 rad``)."""
    return ", ".join(f"{k} {v:.6g}" + (f" {VALUE_UNITS[k]}" if k in VALUE_UNITS else "")
                     for k, v in values.items()) or "-"


def print_report(r: ProbeResult) -> None:
    from rig_models.rig_file import identity_text

    print(identity_text(r.rig))
    if r.setup_error:
        print(f"{r.bus}: CANopen set-up failed: {r.setup_error}")
        return
    for n in r.nodes:
        print(f"CANopen node {n['node_id']} ({', '.join(n['devices'])}): device type "
              f"{n['device_type']}, vendor {n.get('vendor_id', '?')}, product "
              f"{n.get('product_code', '?')}, revision {n.get('revision', '?')}; mapping "
              "written: " + "; ".join(f"{k} {' '.join(v)}" for k, v in
                                       {**n['tpdos'], **n['rpdos']}.items()))
    print(f"{r.bus}: {r.ticks} SYNCs counted at {r.rate_hz:g} Hz")
    print(f"{'device':<18} {'frame':<10} {'id':>5} {'div':>3} {'due':>5} {'got':>5} "
          f"{'missed':>6} {'frames':>6} {'bad':>4} {'seq':>4}  status")
    for d in r.devices:
        print(f"{d.device:<18} {d.frame:<10} 0x{d.frame_id:03X} {d.sync_divider:>3} "
              f"{d.due:>5} {d.received:>5} {d.missing:>6} {d.frames:>6} {d.malformed:>4} "
              f"{d.sequence_errors:>4}  {d.status}")
    print("(due: SYNCs counted; got: answered within the tick; frames: all, settling and late "
          "ones included)")
    print("last values:")
    for d in r.devices:
        print(f"  {d.device:<18} {_values(d.last_values)}")
        if d.last_error:
            print(f"  {'':<18} last error: {d.last_error}")
    bus = f"unknown ids {r.unknown}"
    if r.unknown:
        bus += f" (last 0x{r.last_unknown_id:03X})"
    bus += f", error frames {r.error_frames}" + (", BUS-OFF" if r.bus_off else "")
    print(f"bus: {bus}")
    print("probe: OK, every device answered" if r.ok else "probe: PROBLEM (see above)")
