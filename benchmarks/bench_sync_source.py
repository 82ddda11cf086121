"""SYNC jitter on the wire: SYNC sent by the loop against SYNC sent by the kernel's
broadcast manager (run file ``sync_source: loop | kernel``), over a SocketCAN channel.

The virtual rig runs as its own process on the channel (``harness virtual-rig --bus
socketcan:CHANNEL``); each round runs slew-rw at ``--rate-hz`` for ``--duration-s`` once
with each SYNC source, alternating (the machine's load drifts: interleaved rounds keep it
out of the comparison). From each run's summary.json: the SYNC period jitter on the wire
(the kernel's time stamps of the SYNC's echo or of the broadcast manager's frame read back),
the hub sensor's answer latency after SYNC, the command margin before the next SYNC, and
the loop's own lateness and overruns. Needs Linux with a vcan (or can) channel up; in CI's
VM: ``tools/vcan_vm/run-in-vm .venv/bin/python benchmarks/bench_sync_source.py``.

    .venv/bin/python benchmarks/bench_sync_source.py [--channel vcan0] [--rate-hz 500]
        [--duration-s 10] [--rounds 3] [--json]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import yaml

from harness.core.runs import run_path

SOURCES = ("loop", "kernel")
START_TIMEOUT_S = 600.0  # an emulated machine imports the harness in about 30 s


def _start_rig(channel: str, rate_hz: float, log: Path) -> subprocess.Popen[bytes]:
    with log.open("w") as err:
        proc = subprocess.Popen(
            [sys.executable, "-m", "harness", "virtual-rig", "--bus", f"socketcan:{channel}",
             "--rate-hz", f"{rate_hz:g}"], stdout=subprocess.DEVNULL, stderr=err,
            start_new_session=True)
    deadline = time.monotonic() + START_TIMEOUT_S
    while "Ctrl-C to stop" not in log.read_text():
        if proc.poll() is not None or time.monotonic() > deadline:
            raise SystemExit(f"bench_sync_source: the virtual rig did not start:\n"
                             f"{log.read_text()[-2000:]}")
        time.sleep(0.2)
    return proc


def _stop(proc: subprocess.Popen[bytes]) -> None:
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(timeout=60)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def one_run(channel: str, rate_hz: float, duration_s: float, source: str, grace_s: float,
            work: Path) -> dict[str, Any]:
    """One slew with ``source`` sending SYNC, against a fresh rig; its figures."""
    raw: dict[str, Any] = yaml.safe_load(run_path("slew-rw").read_text())
    raw.update(name=f"bench-sync-{source}", rate_hz=rate_hz, duration_s=duration_s,
               sync_source=source)
    raw.setdefault("monitor", {}).update({"realtime_grace_s": grace_s, "startup_s": grace_s})
    path = work / f"{source}.yaml"
    path.write_text(yaml.safe_dump(raw, sort_keys=False))
    rig = _start_rig(channel, rate_hz, work / f"rig-{source}.log")
    try:
        out = subprocess.run(
            [sys.executable, "-m", "harness", "run", str(path), "--bus", f"socketcan:{channel}",
             "--clock", "realtime", "--out", str(work / "logs"), "--json", "--quiet"],
            capture_output=True, text=True, timeout=duration_s * 20 + START_TIMEOUT_S)
    finally:
        _stop(rig)
    try:  # a run the monitor stopped (exit 3) still has its summary
        s = json.loads(out.stdout)
    except ValueError:
        raise SystemExit(f"bench_sync_source: the {source} run failed ({out.returncode}):\n"
                         f"{out.stderr[-3000:]}") from None
    w = s["wire_timing"]
    return {"sync_source": source, "stopped_by": s["stopped_by"], "ticks": s["ticks"],
            "faults": [f"{f.get('device')}: {f.get('kind')} at {f.get('time_s')} s"
                       for f in s.get("faults") or []],
            "overruns": s["overruns"], "lateness_ms": s["lateness_ms"],
            "source": w["source"], "sync_period_jitter_ms": w["sync_period_jitter_ms"],
            "hub_answer_latency_ms": (w["answer_latency_ms"] or {}).get("hub_sensor"),
            "command_margin_ms": w["command_margin_ms"]}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--channel", default="vcan0")
    parser.add_argument("--rate-hz", type=float, default=500.0)
    parser.add_argument("--duration-s", type=float, default=10.0)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--grace-s", type=float, default=10.0,
                        help="the monitor's realtime_grace_s and startup_s (a slow machine)")
    parser.add_argument("--json", action="store_true", help="print rows as JSON on stdout")
    args = parser.parse_args(argv)
    if not Path(f"/sys/class/net/{args.channel}").exists():
        print(f"bench_sync_source: no {args.channel} interface (docs/socketcan.md)",
              file=sys.stderr)
        return 2
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench-sync-",
                                     dir=os.environ.get("TMPDIR")) as tmp:
        for r in range(args.rounds):
            for source in (SOURCES if r % 2 == 0 else SOURCES[::-1]):
                row = one_run(args.channel, args.rate_hz, args.duration_s, source,
                              args.grace_s, Path(tmp))
                row["round"] = r
                rows.append(row)
                if not args.json:
                    j, h = row["sync_period_jitter_ms"] or {}, row["hub_answer_latency_ms"] or {}
                    print(f"round {r} {source:6s}: {row['stopped_by']}, {row['ticks']} ticks, "
                          f"{row['overruns']} overruns; SYNC jitter p50 {j.get('p50', 0):.3f} "
                          f"p99 {j.get('p99', 0):.3f} max {j.get('max', 0):.3f} ms; hub answer "
                          f"p50 {h.get('p50', 0):.3f} p99 {h.get('p99', 0):.3f} ms; lateness "
                          f"p99 {row['lateness_ms']['p99']:.3f} ms", flush=True)
    if args.json:
        print(json.dumps({"channel": args.channel, "rate_hz": args.rate_hz,
                          "duration_s": args.duration_s, "rows": rows}, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
