"""The cost of decoding a run's CAN log into run.rrd (harness.review.bus) against the run.

One lockstep slew-rw of ``--duration-s`` is made; then, interleaved ``--repeats`` times,
(a) only reading its can.blf with python-can's BLF reader and (b) the whole bus pass
(read, decode with the DBC, send into a recording), each timed. Prints a table with the
run's own wall time, the medians and their ratios. On a shared machine only the ratios
within one run mean much.

    .venv/bin/python benchmarks/bench_review_bus.py [--duration-s 20] [--repeats 3]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import can
import rerun as rr

from harness.core.runs import load_run
from harness.core.session import execute_run
from harness.review.bus import write_bus


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--duration-s", type=float, default=20.0)
    ap.add_argument("--repeats", type=int, default=3)
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp)
        run = load_run("slew-rw", {"duration_s": a.duration_s})
        t0 = time.perf_counter()
        res = execute_run(run, out_dir=out, show_progress=False)
        run_wall = time.perf_counter() - t0
        blf = res.run_dir / "can.blf"
        dividers = run.rig.data["bus"]["sync_divider"]
        read_only, bus_pass = [], []
        frames = 0
        for k in range(a.repeats):
            t0 = time.perf_counter()
            with can.BLFReader(str(blf)) as reader:
                frames = sum(1 for _ in reader)
            read_only.append(time.perf_counter() - t0)
            rec = rr.RecordingStream("bench", recording_id=f"bus{k}")
            rec.save(str(out / f"bus{k}.rrd"))
            t0 = time.perf_counter()
            write_bus(rec, blf, run.dt_s, False, dividers)
            rec.flush()
            bus_pass.append(time.perf_counter() - t0)
            rec.disconnect()
    r, b = statistics.median(read_only), statistics.median(bus_pass)
    print(f"slew-rw {a.duration_s:g} s lockstep: {frames} frames in can.blf")
    print(f"{'what':<38} {'median s':>9} {'per frame us':>13}")
    print(f"{'the run (loop, summary, bus pass)':<38} {run_wall:>9.2f} {'':>13}")
    print(f"{'read can.blf only':<38} {r:>9.2f} {1e6 * r / frames:>13.1f}")
    print(f"{'bus pass (read, decode, send)':<38} {b:>9.2f} {1e6 * b / frames:>13.1f}")
    print(f"bus pass / read only: {b / r:.2f}; bus pass / run: {b / run_wall:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
