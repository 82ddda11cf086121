"""What the controller's own copy of the tick's state costs: slew-rw in lockstep with the
loop as shipped (``RigState.copy`` before every ``step()``, so a controller cannot edit what
the monitor and the recording read) against the same loop handing the controller the
interface's one state (the copy replaced by the identity), interleaved run by run; the
loop's CPU per tick and the ratio of the two, pair by pair (same machine load), and the
copy alone per call.

    .venv/bin/python benchmarks/bench_state_copy.py [--repeats 5]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
import timeit
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import harness.core.session as session  # noqa: E402
from harness.core.runs import load_run  # noqa: E402
from harness.state import RigState  # noqa: E402


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--repeats", type=int, default=5)
    a = p.parse_args()
    own_loop, own_copy = session.run_loop, RigState.copy
    loop_cpu: list[float] = []

    def timed_loop(*args, **kwargs):  # noqa: ANN002, ANN003, ANN202
        c0 = time.process_time()
        try:
            return own_loop(*args, **kwargs)
        finally:
            loop_cpu.append(time.process_time() - c0)

    cpu = {"copy": [], "shared": []}
    session.run_loop = timed_loop
    try:
        with tempfile.TemporaryDirectory() as tmp:
            for _ in range(a.repeats):
                for variant in ("copy", "shared"):
                    RigState.copy = own_copy if variant == "copy" else (lambda s: s)
                    res = session.execute_run(load_run("slew-rw"), out_dir=Path(tmp),
                                              show_progress=False)
                    cpu[variant].append(1e6 * loop_cpu[-1] / res.summary["ticks"])
    finally:
        session.run_loop, RigState.copy = own_loop, own_copy
    ratio = np.array(cpu["copy"]) / np.array(cpu["shared"])
    state = RigState()
    per_call = min(timeit.repeat(state.copy, number=100_000, repeat=5)) / 100_000 * 1e6
    print("| measure | value |")
    print("|---|---|")
    print(f"| loop CPU a tick, controller's own copy (median of {a.repeats}) | "
          f"{np.median(cpu['copy']):.1f} us |")
    print(f"| loop CPU a tick, one shared state (median of {a.repeats}) | "
          f"{np.median(cpu['shared']):.1f} us |")
    print(f"| ratio copy / shared, pair by pair (median, max) | {np.median(ratio):.3f}, "
          f"{np.max(ratio):.3f} |")
    print(f"| RigState.copy alone (best of 5 x 100 000) | {per_call:.2f} us |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
