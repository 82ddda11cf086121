"""`harness test` wall time: one process (inline) against a local process pool, interleaved.

A suite of N lockstep slew-rw runs (a matrix over torque_fraction, ``--duration-s`` each,
judged by their own run file's criteria replaced by a left-safe check) is run end to end by
``harness test`` (collection, runs, judging, reports), alternately with ``--workers 1`` and
``--workers W`` (default every core), ``--repeats`` times each; prints a table of wall times
and the ratio of the medians. On a shared machine only the ratio within one run means much.

    .venv/bin/python benchmarks/bench_suite.py [--runs 4] [--duration-s 10] [--repeats 2]
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=4)
    ap.add_argument("--duration-s", type=float, default=10.0)
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    args = ap.parse_args()
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
    fractions = [round(0.5 + 0.3 * i / max(1, args.runs - 1), 3) for i in range(args.runs)]
    times: dict[int, list[float]] = {1: [], args.workers: []}
    with tempfile.TemporaryDirectory() as tmp:
        suite = Path(tmp) / "bench.yaml"
        suite.write_text(yaml.safe_dump({"name": "bench", "tests": [{
            "run": "slew-rw", "duration_s": args.duration_s, "own_expect": False,
            "expect": {"safe": {"left_safe": True}},
            "matrix": {"controller.torque_fraction": fractions}}]}))
        for _ in range(args.repeats):
            for workers in (1, args.workers):
                t0 = time.perf_counter()
                proc = subprocess.run([sys.executable, "-m", "harness", "test", str(suite),
                                       "--workers", str(workers), "--quiet", "--out", tmp],
                                      capture_output=True, text=True, env=env, check=False)
                wall = time.perf_counter() - t0
                if proc.returncode != 0:
                    print(proc.stderr[-2000:], file=sys.stderr)
                    return 1
                times[workers].append(wall)
    print(f"| suite of {args.runs} x slew-rw {args.duration_s:g} s (lockstep) | wall s "
          f"(each repeat) | median |")
    print("|---|---|---|")
    for w, ts in times.items():
        print(f"| --workers {w} | {' / '.join(f'{t:.1f}' for t in ts)} | "
              f"{statistics.median(ts):.1f} |")
    ratio = statistics.median(times[1]) / statistics.median(times[args.workers])
    print(f"| speed-up, {args.workers} workers / 1 | | {ratio:.2f}x |")
    print(f"(load average at the end: {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
