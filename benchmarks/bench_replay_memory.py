"""Peak memory of `harness replay --check` against the capture's length.

Records slew-rw in lockstep for each duration (default 10 s and 60 s), then replays each
run's can.blf with ``--check`` in its own process, interleaved (short, long, short, long),
and prints a table of peak resident memory (ru_maxrss). A replay in bounded memory has the
same peak for every length.

    .venv/bin/python benchmarks/bench_replay_memory.py [--durations-s 10 60] [--repeats 1]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

REPLAY = """
import json, resource, sys
from harness.cli import main
code = main(["replay", sys.argv[1], "--check", "--json"])
print(json.dumps({"code": code,
                  "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}),
      file=sys.stderr)
"""


def record(duration_s: float, out: Path) -> Path:
    from harness.core.runs import load_run
    from harness.core.session import execute_run

    res = execute_run(load_run("slew-rw", {"duration_s": duration_s}), out_dir=out,
                      show_progress=False)
    return res.run_dir


def replay_peak_mb(run_dir: Path) -> tuple[float, int]:
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
    proc = subprocess.run([sys.executable, "-c", REPLAY, str(run_dir)], capture_output=True,
                          text=True, cwd=ROOT, env=env, timeout=600)
    last = proc.stderr.strip().splitlines()[-1]
    data = json.loads(last)
    return data["peak_mb"], data["code"]


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--durations-s", type=float, nargs="+", default=[10.0, 60.0])
    p.add_argument("--repeats", type=int, default=1)
    args = p.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        runs = {d: record(d, Path(tmp)) for d in args.durations_s}
        peaks: dict[float, list[float]] = {d: [] for d in args.durations_s}
        for _ in range(args.repeats):
            for d in args.durations_s:  # interleaved: the host's drift hits every length
                peak, code = replay_peak_mb(runs[d])
                peaks[d].append(peak)
        sizes = {d: (runs[d] / "can.blf").stat().st_size / 1e6 for d in args.durations_s}
    base = min(peaks[args.durations_s[0]])
    print("| capture (s) | can.blf (MB) | replay --check peak (MB) | ratio to the first |")
    print("|---|---|---|---|")
    for d in args.durations_s:
        peak = min(peaks[d])
        print(f"| {d:g} | {sizes[d]:.2f} | {peak:.1f} | {peak / base:.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
