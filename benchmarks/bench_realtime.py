"""Does the harness add anything to what the host already does? The bare floor loop and the
harness at 500 Hz in real time, in one run, interleaved in blocks so that both see the same
host.

Each pair of blocks runs the floor loop (``harness.realtime.floor``: the harness's clock and
real-time measures, ``--work-us`` of busy work a tick) and a real-time harness run of
slew-rw with every actuator of the virtual rig commanded (wheel, valves, piezo, rotor; every
device answers every SYNC) and the rig as a real-time run has it by default (its own process
over a Unix-domain socket, on the other CPU). The order inside a pair alternates. The
harness runs in this process, so its resident memory (VmRSS) is sampled after every block:
at minute 1 and at the end.

Prints overruns, lateness p50/p99/max of both, the ratios harness/floor, the harness's
missing telemetry frames (all, and those in ticks the loop itself held: started on time and
no overrun), resident memory, and the issue's criteria.

    .venv/bin/python benchmarks/bench_realtime.py [--duration-s 600] [--block-s 30] [--json]
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

from harness.realtime.floor import DEFAULT_WORK_S, FloorResult, run_floor
from harness.runs import ACTUATORS, load_run
from harness.session import execute_run
from harness.streaming import LatencyHistogram


def rss_mb() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def harness_block(seconds: float, rate_hz: float, out: Path) -> Any:
    run = load_run("slew-rw", {"duration_s": seconds, "rate_hz": rate_hz,
                               "actuators": list(ACTUATORS),
                               "monitor": {"realtime_grace_s": 1.0}})
    return execute_run(run, out_dir=out, clock="realtime", show_progress=False)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration-s", type=float, default=600.0,
                    help="total wall time of the benchmark (default 600)")
    ap.add_argument("--block-s", type=float, default=30.0, help="one block (default 30)")
    ap.add_argument("--rate-hz", type=float, default=500.0)
    ap.add_argument("--work-us", type=float, default=DEFAULT_WORK_S * 1e6)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    pairs = max(1, round(args.duration_s / (2 * args.block_s)))
    floor = FloorResult(args.rate_hz)
    h_lat, h_work = LatencyHistogram(), LatencyHistogram()
    h: dict[str, Any] = {"ticks": 0, "overruns": 0, "missing": 0, "missing_on_time": 0,
                         "stopped_by": [], "refused": set(), "mode": set()}
    rss: list[tuple[float, float]] = []
    t0 = time.monotonic()
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(pairs):
            order = ("floor", "harness") if i % 2 == 0 else ("harness", "floor")
            for what in order:
                print(f"bench_realtime: pair {i + 1}/{pairs}, {what} ...", file=sys.stderr)
                if what == "floor":
                    run_floor(args.rate_hz, args.block_s, args.work_us * 1e-6, result=floor)
                else:
                    res = harness_block(args.block_s, args.rate_hz, Path(tmp))
                    st, s = res.stats, res.summary
                    h_lat.merge(st.lateness_s)
                    h_work.merge(st.work_s)
                    h["ticks"] += st.ticks
                    h["overruns"] += st.overruns
                    h["missing"] += st.missing_frames
                    h["missing_on_time"] += st.missing_frames_on_time
                    h["stopped_by"].append(s["stopped_by"])
                    h["refused"].update(s["realtime_measures"]["refused"])
                    h["mode"].add(s["virtual_rig_mode"])
                    for f in Path(tmp).iterdir():  # keep the disk use bounded
                        for g in f.iterdir():
                            g.unlink()
                        f.rmdir()
                rss.append((time.monotonic() - t0, rss_mb()))
    fl, hl = floor.lateness.percentiles_ms(), h_lat.percentiles_ms()
    minute1 = next((r for t, r in rss if t >= 60.0), rss[0][1])
    end_rss = rss[-1][1]
    ratio = {k: (hl[k] / fl[k] if fl[k] > 0 else float("inf")) for k in ("p50", "p99", "max")}
    crit = {
        "overruns_within_floor_plus_0.01pct": h["overruns"] <= floor.overruns
        + 1e-4 * h["ticks"],
        "p99_within_1.5x_floor": ratio["p99"] <= 1.5,
        "no_missing_frame_in_ticks_held": h["missing_on_time"] == 0,
        "rss_growth_below_5_mb": end_rss - minute1 < 5.0,
    }
    result = {
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "python": platform.python_version(), "machine": platform.machine(),
        "pairs": pairs, "block_s": args.block_s, "rate_hz": args.rate_hz,
        "work_us": args.work_us,
        "floor": {"ticks": floor.ticks, "overruns": floor.overruns, "lateness_ms": fl,
                  "work_ms": floor.work.percentiles_ms(), "measures": floor.measures},
        "harness": {"ticks": h["ticks"], "overruns": h["overruns"], "lateness_ms": hl,
                    "work_ms": h_work.percentiles_ms(), "missing_frames": h["missing"],
                    "missing_frames_in_ticks_held": h["missing_on_time"],
                    "stopped_by": h["stopped_by"], "refused": sorted(h["refused"]),
                    "virtual_rig_mode": sorted(h["mode"])},
        "ratio_harness_over_floor": ratio,
        "rss_mb": {"minute_1": minute1, "end": end_rss, "samples": rss},
        "criteria": crit,
    }
    if args.json:
        print(json.dumps(result, indent=2))
        return 0
    print(f"bench_realtime ({result['date']}, Python {result['python']}): {pairs} x "
          f"({args.block_s:g} s floor + {args.block_s:g} s harness) at {args.rate_hz:g} Hz, "
          f"interleaved; rig: {', '.join(sorted(h['mode']))}")
    print("| | floor loop | harness | harness / floor |")
    print("|---|---|---|---|")
    print(f"| overruns / ticks | {floor.overruns} / {floor.ticks} | {h['overruns']} / "
          f"{h['ticks']} | |")
    for k in ("p50", "p99", "max"):
        print(f"| lateness {k} (ms) | {fl[k]:.3f} | {hl[k]:.3f} | {ratio[k]:.2f} |")
    print(f"| work p50 (ms) | {floor.work.percentiles_ms()['p50']:.3f} | "
          f"{h_work.percentiles_ms()['p50']:.3f} | |")
    print(f"| telemetry frames missing (in ticks the loop held) | | {h['missing']} "
          f"({h['missing_on_time']}) | |")
    print(f"| resident memory, minute 1 -> end (MB) | | {minute1:.1f} -> {end_rss:.1f} "
          f"({end_rss - minute1:+.1f}) | |")
    for k, v in crit.items():
        print(f"criterion {k}: {'met' if v else 'NOT met'}")
    if h["refused"]:
        print(f"refused measures: {sorted(h['refused'])}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
