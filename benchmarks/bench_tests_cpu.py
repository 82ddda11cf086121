"""The CPU time of test files, every process they start counted, interleaved across trees.

    python benchmarks/bench_tests_cpu.py [--tree NAME=PATH ...] [--rounds N] [-m EXPR]
        [--by-file N] [--workers N ...] GROUP ...

A GROUP is one pytest session: a test file or node id, or several joined by commas (session
fixtures are shared within a group, as in the README's whole run). Each round runs every group
in every tree, alternating trees (same load for both), with this interpreter
(``sys.executable``; run it with the project's ``.venv/bin/python``), ``-p no:cacheprovider``.

``--workers N`` (repeatable): each group also with pytest-xdist's ``-n N`` (0: without
xdist), interleaved with the others like the trees: the inner loop's wall time against the
CPU it costs.

Why not ``/usr/bin/time``: it counts the processes the command waited for. ``harness test``'s
workers come from a multiprocessing forkserver, which the harness never waits for (it ends
when the harness does); so do the workers of an in-process ``harness test`` in pytest. Their
CPU time is missed (a 9 s suite shows as 3.6 s). This script makes itself the sub-reaper of
what it starts (``PR_SET_CHILD_SUBREAPER``): orphans are re-parented to it, it waits for every
one, and ``RUSAGE_CHILDREN`` then holds all of them. Printed per group and tree: the total
CPU (user + system), the part ``time`` would have shown (the pytest process and the children
it waited for), and pytest's result line. Linux only.

``--by-file N``: where the CPU goes, by test file (the last round of each group and tree):
each test's CPU, the pytest process's and its waited-for children's
(``benchmarks/_test_cpu_plugin.py``), summed by file, the N largest files listed; what is left
of the total is not attributed to a test (a suite's forkserver workers, which nobody in the
test waits for, and pytest's collection and start).
"""

from __future__ import annotations

import argparse
import ctypes
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

PR_SET_CHILD_SUBREAPER = 36


def _cpu(r: resource.struct_rusage) -> float:
    return r.ru_utime + r.ru_stime


PLUGIN_DIR = Path(__file__).resolve().parent


def measure(tree: Path, group: str, marker: str | None,
            per_test: Path | None = None, workers: int = 0) -> tuple[float, float, float, str]:
    """(all CPU s, waited-for CPU s, wall s, pytest's last line) of one pytest session;
    with ``per_test``, each test's CPU is written there as JSON (_test_cpu_plugin)."""
    args = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", *group.split(",")]
    if marker:
        args += ["-m", marker]
    if workers:
        args += ["-n", str(workers)]
    # the tree's code in every process the tests start, whatever the venv's editable
    # install points at (python -m harness, a suite's workers, a study's process)
    path = os.pathsep.join(p for p in (str(tree), os.environ.get("PYTHONPATH", "")) if p)
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", PYTHONPATH=path)
    if per_test is not None:
        args += ["-p", "_test_cpu_plugin"]
        env["PYTHONPATH"] = os.pathsep.join((path, str(PLUGIN_DIR)))
        env["SGSRT_TEST_CPU_OUT"] = str(per_test)
    before = _cpu(resource.getrusage(resource.RUSAGE_CHILDREN))
    start = time.monotonic()
    proc = subprocess.Popen(args, cwd=tree, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    out, _ = proc.communicate()
    # the pytest process's own rusage is in RUSAGE_CHILDREN now; orphans follow
    waited = _cpu(resource.getrusage(resource.RUSAGE_CHILDREN)) - before
    while True:  # the orphans re-parented to us (forkserver, its workers): wait for all
        try:
            os.wait()
        except ChildProcessError:
            break
    wall = time.monotonic() - start
    total = _cpu(resource.getrusage(resource.RUSAGE_CHILDREN)) - before
    lines = [ln for ln in out.splitlines() if ln.strip()]
    return total, waited, wall, (lines[-1] if lines else "")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("groups", nargs="+", metavar="GROUP")
    p.add_argument("--tree", action="append", metavar="NAME=PATH",
                   help="a checkout to run the groups in (repeatable; default: this one)")
    p.add_argument("--rounds", type=int, default=1)
    p.add_argument("-m", dest="marker", help="pytest -m EXPR")
    p.add_argument("--by-file", type=int, default=0, metavar="N",
                   help="also where the CPU goes: the N test files that take the most")
    p.add_argument("--workers", type=int, action="append", metavar="N",
                   help="pytest-xdist workers (-n N; 0: no xdist); repeatable, each a variant "
                        "interleaved with the others (default: 0)")
    args = p.parse_args(argv)
    if args.rounds < 1:
        p.error("--rounds: expected >= 1")
    if args.by_file < 0:
        p.error("--by-file: expected N >= 0 (files listed)")
    workers = args.workers or [0]
    if min(workers) < 0:
        p.error("--workers: expected N >= 0")
    trees: list[tuple[str, Path]] = []
    for spec in args.tree or [f"here={Path(__file__).resolve().parent.parent}"]:
        name, sep, path = spec.partition("=")
        if not sep or not Path(path).is_dir():
            p.error(f"--tree {spec}: expected NAME=PATH of a directory")
        trees.append((name, Path(path)))
    variants = [(f"{name}" + (f" -n {w}" if w else ""), path, w)
                for name, path in trees for w in workers]
    libc = ctypes.CDLL(None, use_errno=True)
    if libc.prctl(PR_SET_CHILD_SUBREAPER, 1, 0, 0, 0) != 0:
        print("cannot become a sub-reaper (Linux only)", file=sys.stderr)
        return 1
    rows: dict[tuple[str, str], list[tuple[float, float, float, str]]] = {}
    tests: dict[tuple[str, str], list[dict[str, float | str]]] = {}
    tmp = Path(tempfile.mkdtemp(prefix="bench-tests-cpu-"))
    for r in range(args.rounds):
        for group in args.groups:
            order = variants if r % 2 == 0 else list(reversed(variants))
            for name, path, w in order:
                per_test = tmp / f"{len(rows)}-{r}.json" if args.by_file and not w else None
                res = measure(path, group, args.marker, per_test, w)
                rows.setdefault((group, name), []).append(res)
                if per_test is not None and per_test.exists():
                    tests[(group, name)] = json.loads(per_test.read_text())
                print(f"round {r + 1} {name:>12} {res[0]:7.1f} s CPU ({res[1]:.1f} s waited) "
                      f"{res[2]:6.1f} s wall  {group}: {res[3]}", file=sys.stderr, flush=True)
    print("\n| group | tree | CPU s (all processes) | CPU s /usr/bin/time sees | wall s | "
          "result |\n|---|---|---|---|---|---|")
    for (group, name), res in rows.items():
        best = min(res, key=lambda x: x[0])  # least disturbed by the machine's other load
        print(f"| {group.replace(',', ', ')} | {name} | {best[0]:.1f} | {best[1]:.1f} | "
              f"{best[2]:.1f} | {best[3]} |")
    for (group, name), per in tests.items():
        print(_by_file_table(group, name, per, rows[(group, name)][-1][0], args.by_file))
    return 0


def _by_file_table(group: str, tree: str, per: list[dict[str, float | str]], total: float,
                   n_files: int) -> str:
    """The CPU of one pytest session by test file (its last round), largest first."""
    cpu: dict[str, float] = defaultdict(float)
    waited: dict[str, float] = defaultdict(float)
    count: dict[str, int] = defaultdict(int)
    for t in per:
        f = str(t["test"]).split("::")[0]
        cpu[f] += float(t["cpu_s"]) + float(t["children_cpu_s"])
        waited[f] += float(t["children_cpu_s"])
        count[f] += 1
    ranked = sorted(cpu, key=lambda f: -cpu[f])
    attributed = sum(cpu.values())
    lines = [f"\nWhere the CPU goes: {group.replace(',', ', ')} on {tree} ({total:.1f} s with "
             "every process, the last round)",
             "\n| test file | tests | CPU s (pytest process + children it waited for) | "
             "of which children | share of the total |\n|---|---|---|---|---|"]
    for f in ranked[:n_files]:
        lines.append(f"| {f} | {count[f]} | {cpu[f]:.1f} | {waited[f]:.1f} | "
                     f"{100 * cpu[f] / total:.1f} % |")
    rest = ranked[n_files:]
    if rest:
        r_cpu = sum(cpu[f] for f in rest)
        lines.append(f"| the other {len(rest)} files | {sum(count[f] for f in rest)} | "
                     f"{r_cpu:.1f} | {sum(waited[f] for f in rest):.1f} | "
                     f"{100 * r_cpu / total:.1f} % |")
    lines.append(f"| not attributed to a test: suites' forkserver workers, collection, "
                 f"start | | {total - attributed:.1f} | | "
                 f"{100 * (total - attributed) / total:.1f} % |")
    return "\n".join(lines)


if __name__ == "__main__":
    raise SystemExit(main())
