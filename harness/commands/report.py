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

from harness.testing.results_docs import PAPER_SUITES, suite_markdown

# Paper 003 (Xu 2018), Table 2: tip acceleration amplitude (m/s^2). Comparison only.
PAPER_TABLE2 = {
    "case-a": {0.6: 0.020, 0.8: 0.025, 1.0: 0.041},
    "case-b": {0.6: 0.043, 0.8: 0.046, 1.0: 0.072},
    "case-c": {0.6: 0.018, 0.8: 0.023, 1.0: 0.037},
}


def collect(logs: Path) -> dict[str, dict[float, dict]]:
    found: dict[str, dict[float, dict]] = {}
    for path in sorted(logs.glob("*/summary.json")):  # names start with UTC time: newest last
        try:
            s = json.loads(path.read_text())
        except (OSError, json.JSONDecodeError):
            continue
        case = next((c for c in PAPER_TABLE2 if str(s.get("run", "")).startswith(c)), None)
        if case is None or s.get("steady_tip_accel_amplitude_m_s2") is None:
            continue
        if s.get("stopped_by") != "completed":
            continue
        found.setdefault(case, {})[round(float(s["beta"]), 3)] = s | {"dir": str(path.parent)}
    return found


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("report", help="print our results beside a paper's table",
                       description=__doc__)
    p.add_argument("table", choices=["table2", "docs"],
                   help="table2: paper 003 cases A/B/C; docs: regenerate docs/results/*.md "
                   "from the paper suites' results.json")
    p.add_argument("--logs", type=Path, default=Path("logs"), help="logs directory (./logs)")
    p.add_argument("--from", dest="sources", type=Path, action="append", metavar="DIR",
                   help="docs: a suite output folder or results.json (repeatable)")
    p.add_argument("--docs", type=Path, default=Path("docs/results"),
                   help="docs: where the generated pages go (docs/results)")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_report)


def _load_results(path: Path) -> dict | None:
    f = path / "results.json" if path.is_dir() else path
    try:
        doc = json.loads(f.read_text())
    except (OSError, json.JSONDecodeError):
        return None
    return doc if isinstance(doc, dict) and isinstance(doc.get("tests"), list) else None


def newest_results(sources: list[Path]) -> dict[str, tuple[Path, dict]]:
    """For each paper suite, the newest results.json (by created_utc) that holds it."""
    found: dict[str, tuple[Path, dict]] = {}
    for path in sources:
        doc = _load_results(path)
        if doc is None:
            continue
        names = {r.get("suite") for r in doc["tests"]}
        for suite in PAPER_SUITES:
            if suite in names and (suite not in found or str(doc.get("created_utc", "")) >
                                   str(found[suite][1].get("created_utc", ""))):
                found[suite] = (path, doc)
    return found


def cmd_docs(args: argparse.Namespace) -> int:
    if args.sources:
        for src in args.sources:
            if _load_results(src) is None:
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
    args.docs.mkdir(parents=True, exist_ok=True)
    for suite in PAPER_SUITES:
        if suite not in found:
            print(f"harness report docs: {suite}: no results; {args.docs / suite}.md left as "
                  "it is", file=sys.stderr)
            continue
        path, doc = found[suite]
        src = path if path.is_dir() else path.parent
        text = suite_markdown(doc, suite, f"`{src.name}/results.json`")
        (args.docs / f"{suite}.md").write_text(text)
        print(f"harness report docs: {args.docs / suite}.md from {src}", file=sys.stderr)
    return 0


def cmd_report(args: argparse.Namespace) -> int:
    if args.table == "docs":
        return cmd_docs(args)
    found = collect(args.logs)
    if not found:
        print(f"harness report: no case-a/b/c runs under {args.logs}; run "
              "'harness run case-a' (and case-b, case-c) first", file=sys.stderr)
        return 1
    rows = []
    for case, paper in PAPER_TABLE2.items():
        for beta, p_val in paper.items():
            s = found.get(case, {}).get(beta)
            rows.append({"case": case, "beta": beta, "paper_m_s2": p_val,
                         "ours_m_s2": None if s is None else s["steady_tip_accel_amplitude_m_s2"],
                         "frequency_ratio": None if s is None else s["frequency_ratio"],
                         "rotor_speed_rad_s": None if s is None else s["rotor_speed_rad_s"],
                         "run_dir": None if s is None else s["dir"]})
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
