"""The command line's start-up: whole ``harness`` processes, timed from their start to their
exit, for ``--help``, ``cases`` and ``run --help``; prints a table of the median and the
spread (lowest to highest) over ``--runs`` runs of each, and the median CPU time
(user + system) of the process.

Runs are interleaved (every command of every tree, then again), so a busy moment of the
machine falls on all of them alike, after one warm-up run of each that is not counted (it
writes the bytecode cache, as any first start does; this machine's environment turns the
cache off with PYTHONDONTWRITEBYTECODE, which is unset for the children here). ``--tree
LABEL=DIR`` (repeatable) times the harness of another checkout, e.g. ``before=/tmp/old``
from ``git archive COMMIT | tar -x -C /tmp/old``; default: this checkout.

    .venv/bin/python benchmarks/bench_startup.py [--runs 15] [--tree LABEL=DIR ...] [--json]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
COMMANDS = (("--help",), ("cases",), ("run", "--help"))


def start(tree: Path, args: tuple[str, ...]) -> tuple[float, float]:
    """(wall time, CPU time user + system) in s of one ``python -m harness ARGS`` process
    with ``tree`` first on the path. The CPU time hardly depends on what else the machine
    runs; the wall time does."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    env["PYTHONPATH"] = str(tree)
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "harness", *args], cwd=tree, env=env, check=True,
                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def measure(trees: dict[str, Path], runs: int) -> dict[tuple[str, str], list[tuple[float, float]]]:
    times: dict[tuple[str, str], list[tuple[float, float]]] = {}
    for label, tree in trees.items():  # warm-up: the bytecode cache written, not counted
        for args in COMMANDS:
            start(tree, args)
            times[(label, " ".join(args))] = []
    for _ in range(runs):
        for label, tree in trees.items():
            for args in COMMANDS:
                times[(label, " ".join(args))].append(start(tree, args))
    return times


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=15, help="counted runs of each (default 15)")
    ap.add_argument("--tree", action="append", default=[], metavar="LABEL=DIR",
                    help="a checkout to time (default: this one)")
    ap.add_argument("--json", action="store_true", help="the times as JSON")
    args = ap.parse_args()
    trees = {"this tree": ROOT}
    if args.tree:
        trees = {}
        for spec in args.tree:
            label, _, folder = spec.partition("=")
            trees[label] = Path(folder).resolve()
    times = measure(trees, args.runs)
    if args.json:
        print(json.dumps({f"{k[0]}: harness {k[1]}": v for k, v in times.items()}, indent=2))
        return 0
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"{time.strftime('%Y-%m-%d', time.gmtime())}, {platform.node() or 'this machine'}: "
          f"{os.cpu_count()} CPUs, Python {platform.python_version()}, {args.runs} runs each, "
          f"interleaved, load average {load:.1f} at the end")
    print()
    print("| tree | command | wall median (s) | wall, lowest to highest (s) | CPU median (s) |")
    print("|---|---|---|---|---|")
    for (label, cmd), ts in times.items():
        wall = [w for w, _ in ts]
        cpu = [c for _, c in ts]
        print(f"| {label} | `harness {cmd}` | {statistics.median(wall):.3f} | "
              f"{min(wall):.3f} to {max(wall):.3f} | {statistics.median(cpu):.3f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
