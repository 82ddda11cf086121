"""Peak resident memory of `harness export` against the run's length: a short and a long
lockstep slew-rw run exported to every format, each export in a fresh process (its peak
from the kernel's accounting, ``wait4``'s ``ru_maxrss``). Memory that does not grow with
the run shows as a long/short ratio near 1 while the recording grows many times.

    .venv/bin/python benchmarks/bench_export_memory.py [--short-s 20] [--mid-s 200]
        [--long-s 600] [--out /tmp/bench-export] [--formats mat parquet mf4 csv]

The runs are made once into --out (reused when there: ``<out>/runs/short``, ``mid``,
``long``). The writers buffer up to a fixed number of rows (a Parquet row group, an MDF4
data block) that a short run never fills: the mid run shows whether the peak still grows
once the buffers are full.
Results: docs/benchmarks.md, "harness export: memory against the run's length".
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
FORMATS = ("mat", "parquet", "mf4", "csv")


def _env() -> dict[str, str]:
    return dict(os.environ, PYTHONPATH=str(ROOT), OPENBLAS_NUM_THREADS="1",
                OMP_NUM_THREADS="1")


def measured(cmd: list[str], quiet: bool = False) -> tuple[int, float, float]:
    """(exit code, peak resident MB, wall s) of ``cmd`` in its own process."""
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, env=_env(), stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE)
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    err = proc.stderr.read().decode() if proc.stderr else ""
    code = os.waitstatus_to_exitcode(status)
    if code != 0 and not quiet:
        print(f"  {' '.join(cmd[-6:])}: exit {code}: {err.strip()[-300:]}", file=sys.stderr)
    return code, usage.ru_maxrss / 1024.0, wall


def make_run(out: Path, name: str, seconds: float) -> Path:
    folder = out / "runs" / name
    found = sorted(folder.glob("*-slew-rw"))
    if found and (found[-1] / "summary.json").is_file():
        return found[-1]
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir(parents=True)
    print(f"making a {seconds:g} s lockstep slew-rw run ...", file=sys.stderr)
    code, peak, wall = measured([sys.executable, "-m", "harness", "run", "slew-rw",
                                 "--duration-s", str(seconds), "--out", str(folder),
                                 "--quiet"], quiet=True)
    found = sorted(folder.glob("*-slew-rw"))
    # its verdict does not matter (a 20 s slew cannot settle: ERROR, missing data): the
    # recording does
    if code in (2, 130) or not found or not (found[-1] / "run.rrd").is_file():
        raise SystemExit(f"the {name} run failed (exit {code})")
    print(f"  done in {wall:.0f} s (peak {peak:.0f} MB)", file=sys.stderr)
    return sorted(folder.glob("*-slew-rw"))[-1]


def size_mb(paths: list[Path]) -> float:
    return sum(p.stat().st_size for p in paths if p.is_file()) / 1e6


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--short-s", type=float, default=20.0)
    ap.add_argument("--mid-s", type=float, default=200.0)
    ap.add_argument("--long-s", type=float, default=600.0)
    ap.add_argument("--out", type=Path, default=Path("/tmp/bench-export"))
    ap.add_argument("--formats", nargs="+", choices=FORMATS, default=list(FORMATS))
    args = ap.parse_args()
    runs = {"short": make_run(args.out, "short", args.short_s),
            "mid": make_run(args.out, "mid", args.mid_s),
            "long": make_run(args.out, "long", args.long_s)}
    inputs = {k: size_mb([d / "run.rrd", d / "can.blf"]) for k, d in runs.items()}
    print(f"run.rrd + can.blf: short ({args.short_s:g} s) {inputs['short']:.1f} MB, mid "
          f"({args.mid_s:g} s) {inputs['mid']:.1f} MB, long ({args.long_s:g} s) "
          f"{inputs['long']:.1f} MB ({inputs['long'] / inputs['short']:.1f}x the short)")
    # the floor: the same interpreter with the export's imports and nothing read
    _, floor, _ = measured([sys.executable, "-c",
                            "import harness.export.writers, harness.export.source, "
                            "harness.record.reader, pyarrow.parquet, asammdf, scipy.io"])
    print(f"imports alone: peak {floor:.1f} MB\n")
    print("| format | peak MB: short | mid | long | long / short | long / mid | time s: short "
          "| long | long: output MB |")
    print("|---|---|---|---|---|---|---|---|---|")
    for fmt in args.formats:
        row: dict[str, tuple[float, float, float]] = {}
        for kind, run_dir in runs.items():
            dest = args.out / "export" / kind / fmt
            shutil.rmtree(dest, ignore_errors=True)
            code, peak, wall = measured([sys.executable, "-m", "harness", "export",
                                         str(run_dir), "--to", fmt, "--out", str(dest)])
            if code != 0:
                return code
            row[kind] = (peak, wall, size_mb(list(dest.iterdir())))
        (ps, ws, _), (pm, _, _), (pl, wl, sl) = row["short"], row["mid"], row["long"]
        print(f"| {fmt} | {ps:.1f} | {pm:.1f} | {pl:.1f} | {pl / ps:.3f} | {pl / pm:.3f} | "
              f"{ws:.1f} | {wl:.1f} | {sl:.1f} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
