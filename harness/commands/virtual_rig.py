"""`harness virtual-rig`: the virtual SGSRT as its own process.

On a Linux lab machine it joins a SocketCAN channel (``--bus socketcan:vcan0``); on a machine
without SocketCAN it serves the socketcand protocol on 127.0.0.1 (``--serve-socketcand
PORT``) and the harness connects with ``--bus socketcand:127.0.0.1:PORT``; ``--serve-unix
NAME`` serves a Unix-domain socket of this machine (``--bus unix:NAME``, the cheaper
transport a real-time run uses for its own rig process, see docs/realtime.md).
"""

from __future__ import annotations

import argparse
import gc
import json
import signal
import sys
import threading
from collections.abc import Callable

from harness.commands import examples
from rig_models.faults import parse_fault
from rig_models.schema import ConfigError


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("virtual-rig", help="run the virtual rig as its own process",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--rig", default="sgsrt", help="rig name or YAML path (default sgsrt)")
    where = p.add_mutually_exclusive_group(required=True)
    where.add_argument("--bus", help="INTERFACE:CHANNEL to join, e.g. socketcan:vcan0")
    where.add_argument("--serve-socketcand", type=int, metavar="PORT",
                       help="serve socketcand on 127.0.0.1:PORT (0: pick a free port)")
    where.add_argument("--serve-unix", metavar="NAME",
                       help="serve a Unix-domain socket bus NAME (abstract namespace)")
    p.add_argument("--rate-hz", type=float, default=500.0,
                   help="the harness loop rate: one physics step per SYNC (default 500)")
    p.add_argument("--duration-s", type=float, default=0.0,
                   help="exit after this many seconds of wall time (0: until Ctrl-C/SIGTERM)")
    p.add_argument("--fault", action="append", metavar="KIND@AT_S[+DURATION_S][:DEVICE][=VALUE]",
                   help="inject a fault at rig time AT_S (repeatable; see 'harness faults')")
    p.add_argument("--realtime", action="store_true",
                   help="take the memory measures of a real-time run in this process "
                        "(mlockall, the collector off and run in the slack after a SYNC); "
                        "the harness sets the CPU and SCHED_FIFO from outside")
    p.add_argument("--lockstep", action="store_true",
                   help="for a harness in lockstep over this bus (harness run/test --clock "
                        "lockstep): the devices' timers (CANopen heartbeats) on the rig's "
                        "time, which advances one step per SYNC; the wall-clock watchdog "
                        "10 s later, as a backstop")
    p.epilog = examples(
        "harness virtual-rig --serve-socketcand 29536",
        "harness virtual-rig --bus socketcan:vcan0 --lockstep",
        "harness virtual-rig --serve-unix rig1 --realtime")
    p.add_argument("--parent-fd", type=int, default=-1, help=argparse.SUPPRESS)
    p.set_defaults(func=cmd_virtual_rig)


def watch_parent(fd: int, stop: threading.Event) -> Callable[[], bool]:
    """A ``stop`` test for the rig's loop that is also true once the pipe ``fd`` reaches its
    end: the process holding its write end (the harness that started this rig) has ended,
    even by SIGKILL. The loop looks at the pipe itself (at most every 0.1 s, one ``select``):
    a thread waiting on it could be starved of the CPU by the loop's own SCHED_FIFO thread
    pinned to the same core (it saw the end seconds late)."""
    import os
    import select
    import time

    next_look = 0.0

    def wait() -> None:
        try:
            while os.read(fd, 1):
                pass
        except OSError:
            pass
        stop.set()

    def should_stop() -> bool:
        nonlocal next_look
        if stop.is_set():
            return True
        now = time.monotonic()
        if now >= next_look:
            next_look = now + 0.1
            if select.select([fd], [], [], 0)[0]:  # the harness never writes: its end
                stop.set()
        return stop.is_set()

    threading.Thread(target=wait, name="parent-watch", daemon=True).start()
    return should_stop


def cmd_virtual_rig(args: argparse.Namespace) -> int:
    # python-can, numpy and scipy only when the rig runs (start-up of `harness --help`)
    from harness.bus import BusSpecError, open_bus, parse_bus
    from harness.bus.rig_process import TIMING_PREFIX
    from rig_models.rig_file import load_rig
    from rig_models.virtual_rig import SyncTiming, VirtualRig, check_virtual_rig

    try:
        rig_cfg = load_rig(args.rig)
        faults = [parse_fault(f) for f in args.fault or []]
        # a device it cannot be, a fault it cannot inject: refused before any bus opens
        check_virtual_rig(rig_cfg, faults)
        if args.serve_socketcand is not None:
            from drivers.socketcand_server import SocketcandServerBus

            bus = SocketcandServerBus(host="127.0.0.1", port=args.serve_socketcand)
            where = f"socketcand:127.0.0.1:{bus.port}"
        elif args.serve_unix is not None:
            from harness.bus.unix import UnixCanServerBus

            bus = UnixCanServerBus(args.serve_unix)
            where = f"unix:{args.serve_unix}"
        else:
            spec = parse_bus(args.bus)
            if spec.in_process:
                raise BusSpecError("--bus virtual:... links buses of one process only; use "
                                   "socketcan:vcan0 or --serve-socketcand PORT")
            bus = open_bus(spec)
            where = str(spec)
    except (ConfigError, BusSpecError, ValueError, OSError) as exc:
        print(f"harness virtual-rig: {exc}", file=sys.stderr)
        return 2
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    should_stop = watch_parent(args.parent_fd, stop) if args.parent_fd >= 0 else stop.is_set
    if args.duration_s > 0:
        timer = threading.Timer(args.duration_s, stop.set)
        timer.daemon = True
        timer.start()
    rig = VirtualRig(rig_cfg, bus, 1.0 / args.rate_hz, faults=faults)
    # faults taken at run time by its fault-insertion unit: a line each in the log
    rig.on_fault_inserted = lambda text: print(f"harness virtual-rig: {text}", file=sys.stderr,
                                               flush=True)
    measures: dict[str, list[str]] = {}
    if args.realtime:
        from harness.core.clock import RealTimeSetup

        measures = RealTimeSetup().apply(sched_fifo=False, priority=0, cpu=-1,
                                         lock_memory=True, gc_freeze=True,
                                         pin_cpu=False).to_dict()
    else:
        gc.collect()
        gc.freeze()  # keep the collector's pauses small while serving the bus
    # a SYNC woken later than a quarter period is kept with its tick (SyncTiming)
    timing = SyncTiming(late_s=0.25 / args.rate_hz)
    print(f"harness virtual-rig: {rig_cfg.name} on {where} at {args.rate_hz:g} Hz"
          f"{' in lockstep' if args.lockstep else ''}; Ctrl-C to stop", file=sys.stderr,
          flush=True)
    try:
        rig.run_forever(should_stop, timing=timing, lockstep=args.lockstep)
    except KeyboardInterrupt:
        pass
    finally:
        rig.make_safe()
        bus.shutdown()
        print(TIMING_PREFIX + json.dumps({**timing.to_dict(), "measures": measures}),
              file=sys.stderr, flush=True)
    c = rig.counters
    print(f"harness virtual-rig: stopped after {c.steps} steps; frames in {c.frames_in}, out "
          f"{c.frames_out}, malformed {c.malformed}, unknown {c.unknown}, watchdog trips "
          f"{c.watchdog_trips}", file=sys.stderr)
    return 0
