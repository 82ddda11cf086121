"""Memory and threads over many runs in one process: a suite worker or a
benchmark makes many runs; each must leave nothing behind. Prints one table row per run:
resident memory (MB, from /proc/self/status) and the process's thread count after the run.

    .venv/bin/python benchmarks/bench_many_runs.py [--runs 50] [--case slew-rw]
        [--duration-s 0.2] [--json]

The criterion: after the 5th run, resident memory stays within 10 MB and the
thread count within a few threads of the 5th run's.
"""

from __future__ import annotations

import argparse
import gc
import json
import sys
import tempfile
import threading
from pathlib import Path


def footprint() -> tuple[float, int]:
    """(resident memory in MB, OS threads of this process)."""
    rss_kb = 0
    threads = 0
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            rss_kb = int(line.split()[1])
        elif line.startswith("Threads:"):
            threads = int(line.split()[1])
    return rss_kb / 1024.0, threads


def many_runs(n_runs: int, case: str, duration_s: float, out: Path) -> list[dict[str, float]]:
    from harness.core.runs import load_run
    from harness.core.session import execute_run

    rows = []
    for i in range(n_runs):
        run = load_run(case, {"duration_s": duration_s})
        execute_run(run, out_dir=out, show_progress=False)
        gc.collect()
        rss_mb, threads = footprint()
        rows.append({"run": i + 1, "rss_mb": rss_mb, "threads": threads,
                     "python_threads": threading.active_count()})
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=50)
    ap.add_argument("--case", default="slew-rw")
    ap.add_argument("--duration-s", type=float, default=0.2)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        rows = many_runs(args.runs, args.case, args.duration_s, Path(tmp))
    ref = rows[min(4, len(rows) - 1)]
    last = rows[-1]
    result = {"runs": rows, "rss_growth_after_5th_mb": last["rss_mb"] - ref["rss_mb"],
              "thread_growth_after_5th": last["threads"] - ref["threads"]}
    if args.json:
        print(json.dumps(result, indent=2))
        return 0
    print(f"| run ({args.case}, {args.duration_s:g} s each) | resident MB | threads "
          f"(OS / Python) |")
    print("|---|---|---|")
    for r in rows:
        print(f"| {r['run']} | {r['rss_mb']:.1f} | {r['threads']} / {r['python_threads']} |")
    print(f"| after the 5th run | {result['rss_growth_after_5th_mb']:+.1f} MB | "
          f"{result['thread_growth_after_5th']:+d} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
