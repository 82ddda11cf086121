"""What a test sequence costs in the tick: a 10 deg wheel slew in lockstep, its controller
alone against the same controller driven by a ten-step sequence with five live conditions
every tick (two verifies, two when:s, an until), interleaved run by run. Printed: the loop's
CPU a tick of each (median), the sequence's own time a tick (the controller's step() time
with the sequence minus without it), and that as a fraction of the tick's cost, pair by pair
(same machine load).

    .venv/bin/python benchmarks/bench_sequence.py [--repeats 5]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import harness.core.session as session  # noqa: E402
from harness.core.runs import run_from_dict  # noqa: E402

STEPS = 10
STEP_S = 4.0


def run_file(sequence: bool) -> dict:
    raw = {"name": "bench-sequence", "duration_s": STEPS * STEP_S,
           "actuators": ["reaction_wheel"],
           "controller": {"type": "pd_wheel", "angle_deg": 10.0, "start_s": 0.0}}
    if sequence:
        raw["controller"]["angle_deg"] = 0.0
        steps = []
        for i in range(STEPS):
            step = {
                "name": f"step {i + 1}",
                "verify": ["abs(hub.rate_deg_s) < 5",
                           "abs(wheel.torque_cmd_n_m) <= 0.065 n_m"],
                "when": [{"if": "wheel.speed_rad_s < -100 becomes true",
                          "do": {"mark": f"fast{i}"}},
                         {"if": "abs(hub.angle_deg - 10) < 0.05 for 2 s",
                          "do": {"mark": f"settled{i}"}}],
                "until": "tip.accel_m_s2 > 50",
                "for_s": STEP_S,
            }
            if i == 0:
                step["slew"] = {"angle_deg": 10.0}
            steps.append(step)
        raw["sequence"] = {"steps": steps}
    return raw


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--repeats", type=int, default=5)
    a = p.parse_args()
    own_loop = session.run_loop
    loop_cpu: list[float] = []

    def timed_loop(*args, **kwargs):  # noqa: ANN002, ANN003, ANN202
        c0 = time.process_time()
        try:
            return own_loop(*args, **kwargs)
        finally:
            loop_cpu.append(time.process_time() - c0)

    cpu: dict[str, list[float]] = {"controller": [], "sequence": []}
    step: dict[str, list[float]] = {"controller": [], "sequence": []}
    session.run_loop = timed_loop
    try:
        with tempfile.TemporaryDirectory() as tmp:
            for _ in range(a.repeats):
                for variant in ("controller", "sequence"):
                    run = run_from_dict(run_file(variant == "sequence"), source="bench")
                    res = session.execute_run(run, out_dir=Path(tmp), show_progress=False)
                    ticks = res.summary["ticks"]
                    cpu[variant].append(1e6 * loop_cpu[-1] / ticks)
                    step[variant].append(1e6 * res.stats.step_total_s / ticks)
                    if variant == "sequence":
                        seq = res.summary["sequence"]
                        assert [s["outcome"] for s in seq["steps"]] == ["PASS"] * STEPS, seq
    finally:
        session.run_loop = own_loop
    own = np.array(step["sequence"]) - np.array(step["controller"])
    fraction = own / np.array(cpu["sequence"])
    print(f"| measure ({STEPS} steps, 5 live conditions a tick, lockstep, median of "
          f"{a.repeats}) | value |")
    print("|---|---|")
    print(f"| loop CPU a tick, the controller alone | {np.median(cpu['controller']):.1f} us |")
    print(f"| loop CPU a tick, driven by the sequence | {np.median(cpu['sequence']):.1f} us |")
    print(f"| step() a tick, the controller alone | {np.median(step['controller']):.2f} us |")
    print(f"| step() a tick, with the sequence | {np.median(step['sequence']):.2f} us |")
    print(f"| the sequence's own time a tick | {np.median(own):.2f} us |")
    print(f"| ... as a fraction of the tick's CPU (pair by pair: median, max) | "
          f"{100 * np.median(fraction):.1f} %, {100 * np.max(fraction):.1f} % |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
