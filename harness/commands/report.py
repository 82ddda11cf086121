"""`harness report table2|docs`: our results beside the papers'.

``table2``: our case A/B/C amplitudes beside paper 003's Table 2, from the newest
``summary.json`` of every ``case-X-beta-B`` run under ``--logs`` (run them first with
``harness run case-a`` etc.).

``docs``: regenerates the docs' result tables, ``docs/results/paper00N.md``, from the paper
suites' ``results.json`` (``harness test paper001 paper002 paper003 paper004``): every
criterion as claim | ours | limit | verdict, and paper 003's Tables 1 and 2. ``--from DIR``
(repeatable: a suite's output folder or its results.json) says which; without it, the newest
results.json under ``--logs`` that holds each paper suite. ``--docs DIR`` (``docs/results``)
is where the pages go; a suite with no results is left as it is (and named on stderr).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from harness.commands import examples


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("report", help="print our results beside a paper's table",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter,
                       epilog=examples(
                           "harness report table2 --logs logs",
                           "harness report docs --from logs/20260101T120000.000000Z-paper003"))
    p.add_argument("table", choices=["table2", "docs"],
                   help="table2: paper 003 cases A/B/C; docs: regenerate docs/results/*.md "
                   "from the paper suites' results.json")
    p.add_argument("--logs", type=Path, default=Path("logs"), help="logs directory (./logs)")
    p.add_argument("--from", dest="sources", type=Path, action="append", metavar="DIR",
                   help="docs: a suite output folder or results.json (repeatable)")
    p.add_argument("--docs", type=Path, default=Path("docs/results"),
                   help="docs: where the generated pages go (docs/results)")
    p.add_argument("--json", action="store_true", help="table2: the rows as JSON on stdout")
    p.set_defaults(func=cmd_report)


def cmd_docs(args: argparse.Namespace) -> int:
    # imported when used: start-up of `harness --help`
    from harness.testing.paper_tables import (
        PAPER_SUITES,
        load_results,
        newest_results,
        write_results_docs,
    )

    if args.sources:
        for src in args.sources:
            if load_results(src) is None:
                print(f"harness report docs: {src}: no results.json of a suite there",
                      file=sys.stderr)
                return 2
        sources = list(args.sources)
    else:
        sources = sorted(args.logs.glob("*/results.json"))
    found = newest_results(sources)
    if not found:
        print("harness report docs: no results of a paper suite found; run 'harness test "
              f"{' '.join(PAPER_SUITES)}' first (or give --from DIR)", file=sys.stderr)
        return 1
    write_results_docs(found, args.docs,
                       lambda line: print(f"harness report docs: {line}", file=sys.stderr))
    return 0


def cmd_report(args: argparse.Namespace) -> int:
    if args.table == "docs":
        return cmd_docs(args)
    # imported when used: start-up of `harness --help`
    from harness.testing.paper_tables import PAPER_TABLE2, collect, table2_rows

    found = collect(args.logs)
    if not found:
        print(f"harness report: no case-a/b/c runs under {args.logs}; run "
              "'harness run case-a' (and case-b, case-c) first", file=sys.stderr)
        return 1
    rows = table2_rows(found)
    if args.json:
        print(json.dumps(rows, indent=2))
        return 0
    print("Tip acceleration amplitude, steady state (m/s^2): ours (virtual rig over CAN) "
          "beside paper 003 Table 2")
    print(f"{'case':<7} {'lambda':>6} {'w_m rad/s':>9} {'beta':>5} {'paper':>7} {'ours':>8} "
          f"{'ours/paper':>10}")
    for r in rows:
        ours = r["ours_m_s2"]
        print(f"{r['case']:<7} {r['frequency_ratio'] or float('nan'):>6.2f} "
              f"{r['rotor_speed_rad_s'] or float('nan'):>9.3f} {r['beta']:>5.1f} "
              f"{r['paper_m_s2']:>7.3f} "
              + (f"{ours:>8.4f} {ours / r['paper_m_s2']:>10.2f}" if ours is not None
                 else f"{'(no run)':>8}"))
    for case in PAPER_TABLE2:
        vals = {b: s["steady_tip_accel_amplitude_m_s2"] for b, s in found.get(case, {}).items()}
        if len(vals) == 3:
            largest = max(vals, key=vals.get)
            print(f"{case}: largest at beta {largest:g} (paper: beta 1.0)")
    return 0
