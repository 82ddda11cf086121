"""Time and peak memory of ``harness frf`` on a 600 s and a 60 s record of the same run.

The two records are ``frf-wheel`` (a wheel-torque multisine on the virtual rig): 600 s
(period 40 s, 1 settling and 14 measured periods) and 60 s (period 20 s, 1 settling and 2
measured). Each analysis runs in a fresh process (``harness.core.frf.analyse`` with its
plots, as ``harness frf RUN``), the two records interleaved ``--repeats`` times (the shared
machine's speed drifts: only ratios measured together compare). Per process: the wall time
of the analysis, its peak resident memory (``resource`` ru_maxrss, Rerun's and numpy's
native allocations included) above the memory after the imports, and the peak of Python's
own allocations (``tracemalloc``).

Run: .venv/bin/python benchmarks/bench_frf.py [--repeats 3] [--keep DIR]
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
RECORDS = {"600 s": (40.0, 14), "60 s": (20.0, 2)}  # period_s, measured periods

CHILD = r"""
import json, resource, sys, time, tracemalloc
from pathlib import Path
from harness.core.frf import analyse
import harness.review.bode, matplotlib.pyplot  # noqa: F401 - imports outside the measure
base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
tracemalloc.start()
t0 = time.perf_counter()
analyse(Path(sys.argv[1]))
wall = time.perf_counter() - t0
peak_py = tracemalloc.get_traced_memory()[1]
rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
print(json.dumps({"wall_s": wall, "rss_mb": rss / 1024, "rss_above_imports_mb":
                  (rss - base) / 1024, "python_peak_mb": peak_py / 2**20}))
"""


def make_record(out: Path, label: str, period_s: float, periods: int) -> Path:
    raw = yaml.safe_load((ROOT / "harness/runs/frf-wheel.yaml").read_text())
    raw["name"] = f"frf-bench-{label.split()[0]}s"
    raw["controller"].update(period_s=period_s, periods=periods, settle_periods=1)
    raw["duration_s"] = 0.5 + period_s * (1 + periods) + 0.5
    raw["expect"] = {k: v for k, v in raw["expect"].items() if "frf" not in v}
    path = out / f"{raw['name']}.yaml"
    path.write_text(yaml.safe_dump(raw))
    subprocess.run([sys.executable, "-m", "harness", "run", str(path), "--out", str(out),
                    "--quiet"], cwd=ROOT, check=True, stdout=subprocess.DEVNULL)
    (run_dir,) = out.glob(f"*-{raw['name']}")
    return run_dir


def measure(run_dir: Path) -> dict[str, float]:
    res = subprocess.run([sys.executable, "-c", CHILD, str(run_dir)], cwd=ROOT, check=True,
                         capture_output=True, text=True)
    return json.loads(res.stdout.strip().splitlines()[-1])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--keep", type=Path, help="keep the records in this folder")
    args = ap.parse_args()
    out = args.keep or Path(tempfile.mkdtemp(prefix="bench_frf_"))
    out.mkdir(parents=True, exist_ok=True)
    runs = {label: make_record(out, label, *spec) for label, spec in RECORDS.items()}
    got: dict[str, list[dict[str, float]]] = {label: [] for label in runs}
    for _ in range(args.repeats):
        for label, run_dir in runs.items():
            got[label].append(measure(run_dir))
    rrd_mb = {label: (d / "run.rrd").stat().st_size / 2**20 for label, d in runs.items()}
    print("| record | run.rrd (MB) | wall (s), median [min, max] | peak RSS (MB) | "
          "RSS above imports (MB) | Python peak (MB) |")
    print("|---|---|---|---|---|---|")
    med = {}
    for label, rows in got.items():
        w = [r["wall_s"] for r in rows]
        med[label] = {k: statistics.median(r[k] for r in rows) for k in rows[0]}
        m = med[label]
        print(f"| {label} | {rrd_mb[label]:.0f} | {m['wall_s']:.2f} [{min(w):.2f}, "
              f"{max(w):.2f}] | {m['rss_mb']:.0f} | {m['rss_above_imports_mb']:.0f} | "
              f"{m['python_peak_mb']:.1f} |")
    a, b = med["600 s"], med["60 s"]
    ratios = [x["wall_s"] / y["wall_s"] for x, y in zip(got["600 s"], got["60 s"],
                                                       strict=True)]
    print(f"| 600 s / 60 s | {rrd_mb['600 s'] / rrd_mb['60 s']:.1f} | "
          f"{statistics.median(ratios):.2f} (pairs {', '.join(f'{r:.2f}' for r in ratios)}) | "
          f"{a['rss_mb'] / b['rss_mb']:.2f} | "
          f"{a['rss_above_imports_mb'] / max(b['rss_above_imports_mb'], 1e-9):.2f} | "
          f"{a['python_peak_mb'] / b['python_peak_mb']:.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
