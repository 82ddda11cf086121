"""`harness test [NAME|PATH ...]`: run suites of run files, probes, identifications and
studies as tests, judged by their criteria, in parallel.

A suite (built-ins in ``harness/suites/``, ``--list``; or a YAML path) lists tests; a run
file (a path, or a built-in run's name) runs as a one-test suite. Each run
test expands to its variants and parameter matrix (format: docs/suites.md). The tests are
collected by pytest (a plugin, ``harness.testing.plugin``), so ``-k EXPR`` selects by name,
``-x`` stops at the first failure, ``--lf`` re-runs only what failed last time (remembered
under ``--out``), and ``--junit FILE`` writes JUnit XML (one testcase per run / variant,
the failed criterion in the failure message).

Virtual-rig tests run in parallel on every core (``--workers N``), or on a Dask cluster
(``--cluster tcp://HOST:8786`` or ``$SGSRT_CLUSTER``). Naming a real bus (``--bus
socketcan:can0``) runs the same suite against the rig: a probe first (nothing is armed if
it fails), then one test at a time; fault-injection tests are skipped there.

Writes ``<out>/<UTC time>-<suite>/`` with each test's run directory, ``results.json``,
``report.md`` and ``report.html`` (self-contained: verdicts, criteria against their limits,
plots of the checked channels with their bands, links to run.rrd and can.blf).

Exit status, the most severe test's (as ``harness run``'s variants): 130 interrupted, 2
refused (bad suite file, no test selected, the pre-flight probe failed), 3 an ERROR by a
fault nobody expected, 4 another ERROR, 1 a FAIL (a test without criteria FAILs unless the
suite says ``require_criteria: false``), 6 INCONCLUSIVE (a real-time run the bench did not
hold in time; JUnit ``<skipped>`` with the reason), 5 the worst is MARGINAL, 0 all PASS (or
NO CRITERIA allowed).
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
from dataclasses import replace
from pathlib import Path

from harness.commands import examples
from harness.engine import CLUSTER_ENV
from rig_models.schema import ConfigError


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("test", help="run suites of tests (runs, variants, probes, studies) "
                       "with verdicts, JUnit XML and an HTML report",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("suites", nargs="*", metavar="NAME|PATH",
                   help="built-in suite name (--list) or a suite file")
    p.add_argument("--list", action="store_true", help="list the built-in suites and exit")
    p.add_argument("-k", metavar="EXPR", dest="keyword",
                   help="only tests whose name matches (pytest -k syntax: 'slew and not fault')")
    p.add_argument("-x", "--exitfirst", action="store_true",
                   help="stop at the first test that does not pass")
    p.add_argument("--lf", "--last-failed", action="store_true", dest="last_failed",
                   help="re-run only the tests that failed last time (in --out)")
    p.add_argument("--junit", type=Path, metavar="FILE", help="write JUnit XML here")
    p.add_argument("--out", type=Path, default=Path("logs"),
                   help="parent of the suite's output folder (default ./logs)")
    p.add_argument("--bus", help="run every test on this bus; a real one (socketcan:can0, "
                   "socketcand:127.0.0.1:PORT, loopback only) means the lab rig: probe "
                   "first, one test at a time")
    p.add_argument("--clock", choices=("lockstep", "realtime"),
                   help="on a --bus that is not the in-process one the tests run in real "
                        "time; lockstep runs them as fast as the rig answers, only against "
                        "a virtual rig started with 'harness virtual-rig --lockstep' (CI over "
                        "vcan0), never the lab rig")
    p.add_argument("--devices-rig", metavar="R2",
                   help="on the virtual bus, every run's virtual rig has the devices and "
                   "physics of rig file R2 while the harness reads them through --rig's")
    p.add_argument("--rig", metavar="R",
                   help="run every test on this rig file (built-in name or path) instead of "
                        "the run files' own, e.g. sgsrt-canopen: the same tests over the "
                        "lab's CANopen devices")
    p.add_argument("--workers", type=int, help="local processes (default: every core; 1 runs "
                   "in this process)")
    p.add_argument("--cluster", metavar="tcp://HOST:8786",
                   help=f"run on a Dask scheduler's workers (default ${CLUSTER_ENV}, if set)")
    p.add_argument("--collect-only", action="store_true",
                   help="list the tests that would run, run nothing")
    p.add_argument("-v", "--verbose", action="store_true", help="pytest's verbose output")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.epilog = examples(
        "harness test --list",
        "harness test acceptance",
        "harness test paper003 -k identify --workers 2 --junit junit.xml",
        "harness test acceptance --bus socketcan:can0")
    p.set_defaults(func=cmd_test)


def _terminate(signum: int, frame: object) -> None:
    raise KeyboardInterrupt


def cmd_test(args: argparse.Namespace) -> int:
    # pytest, the loop, python-can and Rerun only when testing (start-up of `harness --help`)
    import pytest

    from harness.bus import BusSpecError, parse_bus
    from harness.core.paths import safe_name
    from harness.core.session import make_run_dir
    from harness.engine import EngineError, InlineEngine, make_engine
    from harness.testing.outcome import exit_code
    from harness.testing.plugin import SuitePlugin
    from harness.testing.suite import list_suites, load_suite
    from rig_models.rig_file import load_rig

    if args.list:
        for name, desc in list_suites():
            print(f"{name:<16} {desc}")
        return 0
    if not args.suites:
        print("harness test: name a suite (built-in: "
              f"{', '.join(n for n, _ in list_suites())}) or a suite file", file=sys.stderr)
        return 2
    try:
        suites = [load_suite(s) for s in args.suites]
        if args.rig:
            load_rig(args.rig)  # a bad rig file is bad input, before anything runs
            for suite in suites:
                suite.cases[:] = [
                    replace(c, overrides={**c.overrides, "rig": args.rig}) if c.kind == "run"
                    else replace(c, probe={**c.probe, "rig": args.rig}) if c.kind == "probe"
                    else c for c in suite.cases]
        if args.devices_rig:
            from rig_models.rig_file import load_rig

            load_rig(args.devices_rig)
            for suite in suites:
                suite.cases[:] = [
                    replace(c, overrides={**c.overrides, "devices_rig": args.devices_rig})
                    if c.kind == "run" else c for c in suite.cases]
        real_bus = False
        if args.bus:
            real_bus = not parse_bus(args.bus).in_process
        if args.clock and not real_bus:
            raise ConfigError(f"--clock {args.clock}: only with a --bus other than the "
                              "in-process virtual one (whose rig runs in lockstep already)")
        if real_bus and (args.cluster or os.environ.get(CLUSTER_ENV)):
            raise ConfigError(f"--bus {args.bus}: a real rig runs its tests one at a time "
                              "from this machine, not on a cluster")
        if args.workers is not None and args.workers < 1:
            raise ConfigError(f"--workers: expected an integer >= 1, got {args.workers}")
    except (ConfigError, BusSpecError) as exc:
        print(f"harness test: {exc}", file=sys.stderr)
        return 2
    names = "+".join(s.name for s in suites)
    paths = [str(s.source.resolve()) for s in suites]
    if len(set(paths)) != len(paths):
        print("harness test: the same suite is named twice", file=sys.stderr)
        return 2
    cache = args.out / ".harness-test-cache"
    cache.mkdir(parents=True, exist_ok=True)
    ini = cache / "pytest.ini"
    ini.write_text("[pytest]\n")
    out_dir = args.out if args.collect_only else make_run_dir(args.out, safe_name(names))

    cluster = None
    if not args.collect_only and not real_bus and (args.cluster or os.environ.get(CLUSTER_ENV)):
        try:  # a bad --cluster address is bad input: say so before collecting anything
            cluster = make_engine(args.cluster)
        except EngineError as exc:
            print(f"harness test: {exc}", file=sys.stderr)
            return 2

    def factory():  # noqa: ANN202 - an Engine
        if real_bus:
            return InlineEngine()
        return cluster or make_engine(None, args.workers)
    plugin = SuitePlugin(suites, out_dir, factory, bus=args.bus, real_bus=real_bus,
                         progress=not args.quiet, clock=args.clock)
    pargs = [*paths, "-c", str(ini), "--rootdir", str(Path(paths[0]).parent),
             "-o", f"cache_dir={cache.resolve()}", "-o", f"junit_suite_name={names}",
             "-o", "junit_family=xunit1",
             "-s", "-rfE", "--no-header", "-W", "ignore::pytest.PytestAssertRewriteWarning"]
    pargs.append("-v" if args.verbose else "-q")
    if args.keyword:
        pargs += ["-k", args.keyword]
    if args.exitfirst:
        pargs.append("-x")
    if args.last_failed:
        pargs.append("--lf")
    if args.junit:
        pargs.append(f"--junitxml={args.junit}")
    if args.collect_only:
        pargs.append("--collect-only")
    previous = signal.signal(signal.SIGTERM, _terminate)  # SIGTERM stops the suite as Ctrl-C
    # Ctrl-C (or kill -INT) stops the suite even when this process was started with SIGINT
    # ignored (a background job of a non-interactive shell is; Python then installs no
    # handler of its own)
    previous_int = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        ret = pytest.main(pargs, plugins=[plugin])
    finally:
        signal.signal(signal.SIGTERM, previous)
        signal.signal(signal.SIGINT, previous_int)
    if ret == pytest.ExitCode.INTERRUPTED:
        return 130
    if ret == pytest.ExitCode.USAGE_ERROR:
        return 2
    if args.collect_only:
        return 0 if ret == pytest.ExitCode.OK else 2
    if ret == pytest.ExitCode.NO_TESTS_COLLECTED or not plugin.selected:
        print("harness test: no test selected", file=sys.stderr)
        return 2
    if ret == pytest.ExitCode.INTERNAL_ERROR:
        return 4
    code = exit_code(plugin.records) if plugin.records else (2 if plugin.refused else 4)
    if code == 0 and ret != pytest.ExitCode.OK:
        code = 4  # a failure outside any verdict (the plugin itself)
    verdicts = [r["verdict"] for r in plugin.records if r.get("reported", True)]
    counts = ", ".join(f"{v} {verdicts.count(v)}" for v in
                       ("PASS", "MARGINAL", "INCONCLUSIVE", "FAIL", "ERROR", "SKIPPED")
                       if v in verdicts)
    print(f"harness test: {names}: {counts or 'nothing run'}; exit {code}; report "
          f"{out_dir / 'report.html'}" + (f"; JUnit {args.junit}" if args.junit else ""),
          file=sys.stderr)
    return code
