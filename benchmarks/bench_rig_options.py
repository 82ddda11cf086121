"""How to run the virtual rig in a real-time run so that it does not take the loop's time:
the options measured in one run, interleaved (each repeat runs every option once, in turn).

Options (slew-rw at 500 Hz on the virtual bus, real-time measures on unless said):
  thread            the rig as a thread of the harness (shares the interpreter lock)
  thread-switch     the same with sys.setswitchinterval(0.5 ms) (default 5 ms)
  process-tcp       the rig in its own process over socketcand (TCP loopback), pinned to
                    the other CPU at SCHED_FIFO 49
  process-tcp-free  the same, nothing pinned (CPU affinity off for loop and rig)
  process-unix      the rig in its own process over a Unix-domain socket (harness.bus.unix),
                    pinned to the other CPU at SCHED_FIFO 49
  process-unix-free the same, nothing pinned

    .venv/bin/python benchmarks/bench_rig_options.py [--seconds 20] [--repeats 2] [--json]
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from harness.core.runs import load_run
from harness.core.session import execute_run

OPTIONS: dict[str, dict[str, Any]] = {
    "thread": {"virtual_rig": "thread"},
    "thread-switch": {"virtual_rig": "thread"},
    "process-tcp": {"virtual_rig": "process-tcp"},
    "process-tcp-free": {"virtual_rig": "process-tcp", "pin_cpu": False},
    "process-unix": {"virtual_rig": "process-unix"},
    "process-unix-free": {"virtual_rig": "process-unix", "pin_cpu": False},
}


def one(option: str, seconds: float, out: Path) -> dict[str, Any]:
    run = load_run("slew-rw", {"duration_s": seconds, "monitor": {"realtime_grace_s": 1.0},
                               "realtime": OPTIONS[option]})
    old = sys.getswitchinterval()
    if option == "thread-switch":
        sys.setswitchinterval(0.0005)
    try:
        s = execute_run(run, out_dir=out, clock="realtime", show_progress=False).summary
    finally:
        sys.setswitchinterval(old)
    return {"ticks": s["ticks"], "overruns": s["overruns"], "lateness_ms": s["lateness_ms"],
            "work_ms": s["work_ms"], "missing": s["frames"]["missing"],
            "missing_on_time": s["frames"]["missing_in_ticks_on_time"],
            "stopped_by": s["stopped_by"], "refused": s["realtime_measures"]["refused"]}


def merge(rows: list[dict[str, Any]]) -> dict[str, Any]:
    return {"ticks": sum(r["ticks"] for r in rows),
            "overruns": sum(r["overruns"] for r in rows),
            "missing": sum(r["missing"] for r in rows),
            "missing_on_time": sum(r["missing_on_time"] for r in rows),
            # per-run percentiles: the worst run's p99 and max, the median run's p50
            "p50_ms": sorted(r["lateness_ms"]["p50"] for r in rows)[len(rows) // 2],
            "p99_ms": max(r["lateness_ms"]["p99"] for r in rows),
            "max_ms": max(r["lateness_ms"]["max"] for r in rows),
            "work_p50_ms": sorted(r["work_ms"]["p50"] for r in rows)[len(rows) // 2],
            "stopped_by": sorted({r["stopped_by"] for r in rows}),
            "refused": sorted({x for r in rows for x in r["refused"]})}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--options", default=",".join(OPTIONS))
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    names = args.options.split(",")
    runs: dict[str, list[dict[str, Any]]] = {n: [] for n in names}
    with tempfile.TemporaryDirectory() as tmp:
        for rep in range(args.repeats):
            order = names if rep % 2 == 0 else names[::-1]
            for n in order:
                print(f"bench_rig_options: repeat {rep + 1}, {n} ...", file=sys.stderr)
                runs[n].append(one(n, args.seconds, Path(tmp)))
    res = {n: merge(r) for n, r in runs.items()}
    meta = {"date": time.strftime("%Y-%m-%d"), "python": platform.python_version(),
            "seconds": args.seconds, "repeats": args.repeats}
    if args.json:
        print(json.dumps({"meta": meta, "options": res, "runs": runs}, indent=2))
        return 0
    print(f"rig options, slew-rw 500 Hz real time, {args.repeats} x {args.seconds:g} s each, "
          f"interleaved ({meta['date']}, Python {meta['python']})")
    print("| option | overruns / ticks | lateness p50 / p99 / max (ms) | missing frames "
          "(in ticks on time) | work p50 (ms) |")
    print("|---|---|---|---|---|")
    for n, r in res.items():
        print(f"| {n} | {r['overruns']} / {r['ticks']} | {r['p50_ms']:.3f} / {r['p99_ms']:.3f} "
              f"/ {r['max_ms']:.2f} | {r['missing']} ({r['missing_on_time']}) | "
              f"{r['work_p50_ms']:.3f} |" + (f" refused: {r['refused']}" if r['refused'] else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
