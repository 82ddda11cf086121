"""Round-trip latency of one CAN frame: python-can socketcand client -> SocketcandServerBus
-> echoed back to the client, over 127.0.0.1.

Four set-ups: the echoing server in this process (a thread) or in its own process (as the
virtual rig runs), and the client with or without ``tcp_tune`` (TCP_NODELAY + TCP_QUICKACK
on the client side; the server always sets TCP_NODELAY).

    .venv/bin/python benchmarks/bench_socketcand.py [--round-trips 2000] [--json]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import textwrap
import threading
import time
from dataclasses import asdict, dataclass

import can
import numpy as np

from drivers.socketcand_server import SocketcandServerBus

HOST = "127.0.0.1"
STOP_ID = 0x7FF
STOP_DATA = b"stop"
REPLY_TIMEOUT_S = 2.0

_ECHO_PROCESS = textwrap.dedent(
    """
    import sys, time
    import can
    from drivers.socketcand_server import SocketcandServerBus
    srv = SocketcandServerBus(port=0)
    print(srv.port, flush=True)
    deadline = time.monotonic() + float(sys.argv[1])
    try:
        while time.monotonic() < deadline:
            msg = srv.recv(timeout=0.2)
            if msg is None:
                continue
            if msg.arbitration_id == 0x7FF and bytes(msg.data) == b"stop":
                break
            srv.send(msg)
    finally:
        srv.shutdown()
    """
)


@dataclass(frozen=True)
class LatencyRow:
    setup: str
    round_trips: int
    p50_us: float
    p90_us: float
    p99_us: float
    max_us: float


def _echo_thread(srv: SocketcandServerBus, stop: threading.Event) -> None:
    while not stop.is_set():
        try:
            msg = srv.recv(timeout=0.1)
        except can.CanOperationError:
            return
        if msg is not None:
            srv.send(msg)


def _measure(port: int, tcp_tune: bool, round_trips: int, warmup: int) -> np.ndarray:
    bus = can.Bus(interface="socketcand", host=HOST, port=port, channel="can0", tcp_tune=tcp_tune)
    try:
        samples = np.empty(round_trips)
        for i in range(-warmup, round_trips):
            payload = (i % 2**32).to_bytes(4, "big") + b"\x5a\x5a\x5a\x5a"
            msg = can.Message(arbitration_id=0x123, is_extended_id=False, data=payload)
            # the first reply waits out the server's handshake settle
            timeout_s = REPLY_TIMEOUT_S + (1.0 if i == -warmup else 0.0)
            start = time.perf_counter()
            bus.send(msg)
            while True:
                reply = bus.recv(timeout=timeout_s)
                if reply is None:
                    raise TimeoutError(f"no echo within {timeout_s} s (round trip {i})")
                if bytes(reply.data) == payload:
                    break
            if i >= 0:
                samples[i] = time.perf_counter() - start
        return samples
    finally:
        bus.shutdown()


def _row(setup: str, seconds: np.ndarray) -> LatencyRow:
    us = seconds * 1e6
    return LatencyRow(
        setup=setup,
        round_trips=len(us),
        p50_us=float(np.percentile(us, 50)),
        p90_us=float(np.percentile(us, 90)),
        p99_us=float(np.percentile(us, 99)),
        max_us=float(us.max()),
    )


def bench_in_process(tcp_tune: bool, round_trips: int, warmup: int) -> LatencyRow:
    srv = SocketcandServerBus(port=0)
    stop = threading.Event()
    echo = threading.Thread(target=_echo_thread, args=(srv, stop), daemon=True)
    echo.start()
    try:
        samples = _measure(srv.port, tcp_tune, round_trips, warmup)
    finally:
        stop.set()
        echo.join(timeout=5.0)
        srv.shutdown()
    return _row(f"server thread, client tcp_tune={tcp_tune}", samples)


def bench_other_process(tcp_tune: bool, round_trips: int, warmup: int) -> LatencyRow:
    proc = subprocess.Popen(
        [sys.executable, "-c", _ECHO_PROCESS, "120"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()  # the child prints its port first, or exits
        if not line.strip().isdigit():
            raise RuntimeError(f"echo server did not start: {line!r} {proc.stderr.read()}")
        port = int(line)
        samples = _measure(port, tcp_tune, round_trips, warmup)
        stopper = can.Bus(interface="socketcand", host=HOST, port=port, channel="can0")
        try:
            stopper.send(can.Message(arbitration_id=STOP_ID, is_extended_id=False, data=STOP_DATA))
        finally:
            stopper.shutdown()
        proc.wait(timeout=10.0)
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.communicate(timeout=10.0)
    return _row(f"server process, client tcp_tune={tcp_tune}", samples)


def format_table(rows: list[LatencyRow]) -> str:
    header = f"{'set-up':<38} {'n':>6} {'p50 us':>9} {'p90 us':>9} {'p99 us':>9} {'max us':>9}"
    lines = [header, "-" * len(header)]
    for r in rows:
        lines.append(
            f"{r.setup:<38} {r.round_trips:>6d} {r.p50_us:>9.1f} {r.p90_us:>9.1f} "
            f"{r.p99_us:>9.1f} {r.max_us:>9.1f}"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--round-trips", type=int, default=2000)
    parser.add_argument("--warmup", type=int, default=100)
    parser.add_argument("--json", action="store_true", help="print rows as JSON on stdout")
    args = parser.parse_args(argv)
    if args.round_trips < 1:
        parser.error("--round-trips: expected >= 1")
    if args.warmup < 1:
        parser.error("--warmup: expected >= 1")
    rows = []
    for tcp_tune in (True, False):
        print(f"in-process, tcp_tune={tcp_tune} ...", file=sys.stderr)
        rows.append(bench_in_process(tcp_tune, args.round_trips, args.warmup))
    for tcp_tune in (True, False):
        print(f"other process, tcp_tune={tcp_tune} ...", file=sys.stderr)
        rows.append(bench_other_process(tcp_tune, args.round_trips, args.warmup))
    if args.json:
        print(json.dumps([asdict(r) for r in rows], indent=2))
    else:
        print(format_table(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
