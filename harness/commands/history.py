"""`harness history`: the rig's health over time, from the results database.

Every judged run (``harness run``, ``harness judge``), suite result (``harness test``),
identification (``harness identify`` of a run directory) and calibration (``harness
calibrate``) is recorded in ``history.sqlite`` beside the logs (or the database of
``--db URL`` / ``$SGSRT_HISTORY_DB``: an SQLite path or ``postgresql://...``). Sub-commands:

  list                      the series recorded, by rig: (test, criterion) and (test, mode)
                            on one rig under one run configuration
  show TEST --criterion C   one criterion's value, limits, margin and verdict across runs
  show TEST --mode N        identified mode N (1 = lowest) with its 1 sigma across runs
  drift                     the alarms of every series (a change beyond k x its combined
                            uncertainty, a trend, a margin shrinking, a mode outside the band
                            the calibrated shaper was designed for, flaky verdicts)
  import                    record the results already under --logs (each once)
  scatter RUN_DIR           the virtual rig's predicted scatter of the run's criteria (seeds
                            of its noise, cached under --logs) and whether each value is
                            within it: a failure beyond it is a real change, within it noise

A series is one test on one rig (its name, real or virtual) under one run configuration (the
run file's data): ``show`` and ``drift`` take each rig's series on its own, and every alarm
names its rig. Filters: ``--rig NAME``, ``--real`` / ``--virtual``, ``--since`` /
``--until`` (ISO 8601 dates or times: 20260101, 2026-01-01, 2026-01-01T10:00+02:00; UTC
unless they name an offset; compared as instants). ``show`` prints a table (``--json``:
JSON), ``--png FILE`` a plot and ``--page FILE`` a self-contained HTML page. Exit 0, 1 when
an alarm fires (``show``, ``drift``) or a value is beyond the predicted scatter
(``scatter``), 2 bad input.
docs/history.md explains the statistics.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from harness.commands import examples
from harness.history import DEFAULT_K, DEFAULT_N_REF, DEFAULT_N_TREND


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("history", help="results across runs: series, drift alarms, scatter",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    hs = p.add_subparsers(dest="history_command", metavar="SUBCOMMAND")

    def common(q: argparse.ArgumentParser, filters: bool = True) -> None:
        q.add_argument("--logs", type=Path, default=Path("logs"),
                       help="the logs folder (its history.sqlite; default ./logs)")
        q.add_argument("--db", help="database: an SQLite file or postgresql://... URL "
                       "(default $SGSRT_HISTORY_DB, else LOGS/history.sqlite)")
        q.add_argument("--json", action="store_true", help="JSON on stdout")
        if filters:
            q.add_argument("--rig", help="only runs on this rig (its name)")
            g = q.add_mutually_exclusive_group()
            g.add_argument("--real", action="store_true", help="only runs on the real rig")
            g.add_argument("--virtual", action="store_true", help="only runs on virtual rigs")
            q.add_argument("--since", help="only runs from this date/time (ISO 8601: "
                           "20260101, 2026-01-01T10:00, 2026-01-01T10:00+02:00; UTC unless "
                           "it names an offset)")
            q.add_argument("--until", help="only runs before this date/time (as --since)")

    def stats(q: argparse.ArgumentParser) -> None:
        q.add_argument("--k", type=float, default=DEFAULT_K,
                       help="coverage factor: alarm beyond k x the combined 1 sigma (3)")
        q.add_argument("--n-ref", type=int, default=DEFAULT_N_REF,
                       help="runs that set a criterion's control limits (5)")
        q.add_argument("--n-trend", type=int, default=DEFAULT_N_TREND,
                       help="runs of the trend rule (5)")
        q.add_argument("--recommended", type=Path,
                       help="a calibrated run file (recommended.yaml) whose mode bands the "
                       "modes are checked against (default: the newest calibration recorded)")

    q = hs.add_parser("list", help="the series recorded")
    common(q)
    q = hs.add_parser("show", help="one series across runs")
    common(q)
    stats(q)
    q.add_argument("test", help="the test's name (a run's name, a suite item, identify[RUN])")
    g = q.add_mutually_exclusive_group(required=True)
    g.add_argument("--criterion", help="a criterion's name")
    g.add_argument("--mode", type=int, help="an identified mode (1 = lowest)")
    q.add_argument("--reference", type=int, default=0,
                   help="a mode's reference run (index in the series, default 0: the first)")
    q.add_argument("--png", type=Path, help="write the plot here")
    q.add_argument("--page", type=Path, help="write a self-contained HTML page here")
    q = hs.add_parser("drift", help="the alarms of every series")
    common(q)
    stats(q)
    q = hs.add_parser("import", help="record the results already under --logs")
    common(q, filters=False)
    q = hs.add_parser("scatter", help="a run's criteria against the virtual rig's scatter")
    common(q, filters=False)
    q.add_argument("run_dir", type=Path, help="a judged run directory")
    q.add_argument("--model-rig", help="the rig file the virtual rig is built from (default: "
                   "the run's own, from its config.yaml)")
    q.add_argument("--seeds", type=int, default=5, help="noise seeds of the prediction (5)")
    q.add_argument("--k", type=float, default=DEFAULT_K,
                   help="within the scatter: |value - mean| <= k x its std (3)")
    p.epilog = examples(
        "harness history list",
        "harness history drift --json",
        "harness history import --logs logs",
        "harness history scatter logs/20260101T120000.000000Z-slew-rw")
    p.set_defaults(func=cmd_history)


def _filters(args: argparse.Namespace) -> Any:
    # imported when used: start-up of `harness --help`
    from harness.history.db import Filters
    from harness.history.times import TimeError, utc_text

    times = {}
    for name in ("since", "until"):
        v = getattr(args, name, None)
        try:
            times[name] = None if v is None else utc_text(v)
        except TimeError as exc:
            raise ValueError(f"--{name}: {exc}") from exc
    real = True if getattr(args, "real", False) else (False if getattr(args, "virtual", False)
                                                     else None)
    return Filters(rig=getattr(args, "rig", None), real=real, since=times["since"],
                   until=times["until"])


def cmd_history(args: argparse.Namespace) -> int:
    # imported when used: start-up of `harness --help`
    from harness.history.db import HistoryError, open_db

    if args.history_command is None:
        print("harness history: expected a sub-command: list, show, drift, import, scatter",
              file=sys.stderr)
        return 2
    try:
        if getattr(args, "k", 1.0) <= 0:
            raise ValueError(f"--k: expected a positive factor, got {args.k}")
        for name in ("n_ref", "n_trend", "seeds"):
            if getattr(args, name, 3) < (1 if name == "n_ref" else 2):
                raise ValueError(f"--{name.replace('_', '-')}: too small: "
                                 f"{getattr(args, name)}")
        if args.history_command == "scatter":
            return _scatter(args)
        filters = _filters(args) if args.history_command != "import" else None
        if args.db is None and not (args.logs / "history.sqlite").exists() \
                and args.history_command != "import":
            import os

            # imported when used: start-up of `harness --help`
            from harness.history.db import ENV_URL

            if not os.environ.get(ENV_URL):
                raise ValueError(f"{args.logs}: no history.sqlite (no result recorded there; "
                                 f"'harness history import --logs {args.logs}' records the "
                                 "runs already on disk)")
        with open_db(args.db, logs=args.logs) as db:
            if args.history_command == "import":
                if not args.logs.is_dir():
                    raise ValueError(f"--logs {args.logs}: not a directory")
                # imported when used: start-up of `harness --help`
                from harness.history.record import import_logs

                skipped: list[tuple[Path, str]] = []
                counts = import_logs(db, args.logs, skipped)
                for folder, why in skipped:
                    print(f"harness history import: skipped {folder}: {why}",
                          file=sys.stderr)
                if args.json:
                    print(json.dumps({**counts, "skipped_folders": [
                        {"folder": str(f), "reason": why} for f, why in skipped]}, indent=2))
                else:
                    for k, n in sorted(counts.items()):
                        print(f"{k}: {n}")
                    if not counts:
                        print(f"nothing to import under {args.logs}")
                return 0
            if args.history_command == "list":
                from harness.testing.measures import unit_text

                rows = sorted(db.catalogue(filters),
                              key=lambda r: (r["rig"], r["real_rig"], r["test"]))
                if args.json:
                    print(json.dumps(rows, indent=2))
                else:
                    rig = None
                    for r in rows:
                        if (r["rig"], r["real_rig"]) != rig:
                            rig = (r["rig"], r["real_rig"])
                            print(f"{r['rig'] or '(no rig recorded)'}"
                                  f"{' (real)' if r['real_rig'] else ''}:")
                        what = (f"--criterion {r['criterion']}" if r["series"] == "criterion"
                                else f"--mode {r['mode']}")
                        u = unit_text(r.get("unit") or "")
                        unit = f" ({u})" if u else ""
                        run = (f", run configuration {r['run_sha256'][:8]}"
                               if r["run_sha256"] else "")
                        print(f"  {r['test']} {what}{unit}{run}: {r['runs']} runs, last "
                              f"{r['last_utc']}")
                return 0 if rows else 1
            if args.history_command == "show":
                return _show(db, args, filters)
            return _drift(db, args, filters)
    except (ValueError, OSError, HistoryError) as exc:
        print(f"harness history: {exc}", file=sys.stderr)
        return 2


def _bands(db: Any, args: argparse.Namespace, rig: str | None
           ) -> tuple[list[dict[str, float]], str]:
    """The mode bands of the newest calibration recorded for ``rig`` (or --recommended)."""
    from harness.history.db import Filters
    from harness.history.record import design_bands

    if args.recommended is not None:
        if not args.recommended.is_file():
            raise ValueError(f"--recommended {args.recommended}: no such file")
        bands = design_bands(args.recommended)
        if not bands:
            raise ValueError(f"--recommended {args.recommended}: no controller.modes (not a "
                             "run file from harness calibrate)")
        return bands, str(args.recommended)
    cals = db.records(Filters(kind="calibrate", rig=rig or None))
    for c in reversed(cals):
        if c["extra"].get("bands"):
            return c["extra"]["bands"], c["extra"].get("recommended") or c["source"]
    return [], ""


def _spread(args: argparse.Namespace, series: Any) -> float | None:
    """The predicted scatter's std of a criterion, from the cache, if one was made for
    the configuration of the series' newest run."""
    # imported when used: start-up of `harness --help`
    from harness.history.scatter import cached_spread

    src = next((r["source"] for r in reversed(series.rows) if r.get("source")), None)
    return None if src is None else cached_spread(args.logs, Path(src), series.name)


def _analysed(db: Any, args: argparse.Namespace, filters: Any, what: str, test: str,
              name: str | int, reference: int = 0) -> list[Any]:
    """The test's series of ``name`` the filters select, one per rig and run
    configuration, each with its alarms."""
    from harness.history import series as hs

    out = []
    if what == "mode":
        for s in hs.split(hs.mode_series(db, test, int(name), filters)):
            bands, by = _bands(db, args, s.rig)
            out.append(hs.analyse(s, args.k, args.n_ref, args.n_trend, reference,
                                  bands=bands, designed_by=by))
        return out
    for s in hs.split(hs.criterion_series(db, test, str(name), filters)):
        _mark_scatter(args, s)
        out.append(hs.analyse(s, args.k, args.n_ref, args.n_trend, spread=_spread(args, s)))
    return out


def _mark_scatter(args: argparse.Namespace, series: Any) -> None:
    """A failed or marginal run whose configuration's scatter was predicted (harness
    history scatter) is marked within or beyond it."""
    # imported when used: start-up of `harness --help`
    from harness.history.scatter import cached_prediction, within

    for r in series.rows:
        if r.get("verdict") in ("FAIL", "MARGINAL") and r.get("value") is not None \
                and r.get("source"):
            p = cached_prediction(args.logs, Path(r["source"]), series.name)
            if p is not None:
                r["scatter"] = "within" if within(r["value"], p, args.k) else "beyond"


def _show(db: Any, args: argparse.Namespace, filters: Any) -> int:
    # imported when used: start-up of `harness --help`
    from harness.history import series as hs

    if args.mode is not None and args.mode < 1:
        raise ValueError(f"--mode: expected 1 or more, got {args.mode}")
    what, name = ("mode", args.mode) if args.mode is not None else ("criterion", args.criterion)
    if args.reference < 0:
        raise ValueError(f"--reference: expected a run index of 0 or more, got "
                         f"{args.reference}")
    found = _analysed(db, args, filters, what, args.test, name, args.reference)
    if not found:
        raise ValueError(f"no runs of {args.test} with {what} {name} (see 'harness history "
                         "list')")
    longest = max(len(s.rows) for s in found)
    if args.reference >= longest:
        raise ValueError(f"--reference: expected a run index in [0, {longest - 1}]")
    if args.png:
        hs.plot_png(found, args.png)
    if args.page:
        hs.page_html(found, args.page)
    if args.json:
        print(json.dumps({"series": [s.to_dict() for s in found]}, indent=2, default=str))
    else:
        print("\n\n".join(hs.table(s) for s in found))
    for path in (args.png, args.page):
        if path:
            print(f"harness history: wrote {path}", file=sys.stderr)
    return 1 if any(s.alarms or s.flaky for s in found) else 0


def _drift(db: Any, args: argparse.Namespace, filters: Any) -> int:
    from dataclasses import replace

    found = []
    seen: set[tuple[Any, ...]] = set()
    for entry in db.catalogue(filters):
        key = (entry["series"], entry["test"], entry.get("criterion"), entry.get("mode"),
               entry["rig"], entry["real_rig"], entry["run_sha256"])
        if key in seen:  # the same series under two units: analysed once
            continue
        seen.add(key)
        one = replace(filters, rig=entry["rig"], real=entry["real_rig"],
                      run_sha256=entry["run_sha256"])
        if entry["series"] == "mode":
            found += _analysed(db, args, one, "mode", entry["test"], entry["mode"])
        else:
            found += _analysed(db, args, one, "criterion", entry["test"], entry["criterion"])
    found = [s for s in found if s.alarms or s.flaky]
    found.sort(key=lambda s: (s.rig, s.real_rig, s.test, s.name))
    if args.json:
        print(json.dumps([{"test": s.test, "name": s.name, "rig": s.rig,
                           "real_rig": s.real_rig, "run_sha256": s.run_sha256,
                           "label": s.label, "alarms": [a.to_dict() for a in s.alarms],
                           "flaky": s.flaky} for s in found], indent=2))
    else:
        for s in found:
            for a in s.alarms:
                print(f"ALARM ({a.kind}, run {a.index}): {a.message}")
            for f in s.flaky:
                print(f"FLAKY: {f['message']}")
        if not found:
            print("harness history: no alarm")
    return 1 if found else 0


def _scatter(args: argparse.Namespace) -> int:
    # imported when used: start-up of `harness --help`
    from harness.history.scatter import ScatterError, classify, predict_for_run

    if not (args.run_dir / "verdict.json").is_file():
        raise ValueError(f"{args.run_dir}: no verdict.json (judge it first: harness judge)")
    try:
        pred = predict_for_run(args.run_dir, args.logs, seeds=args.seeds,
                               model_rig=args.model_rig,
                               progress=lambda m: print(m, file=sys.stderr, flush=True))
    except ScatterError as exc:
        print(f"harness history scatter: {exc}", file=sys.stderr)
        return 2
    rows = classify(args.run_dir, pred, args.k)
    if args.json:
        print(json.dumps({"prediction": pred, "criteria": rows}, indent=2))
    else:
        print(f"predicted from {pred['seeds']} noise seeds of the virtual rig "
              f"({pred['cache']})")
        from harness.review.units import unit_text

        # every value with its unit, as in verdicts (the criterion's)
        print(f"{'criterion':<28} {'value':>15} {'mean':>15} {'std':>14} {'z':>7} "
              f"{'verdict':<8} scatter")
        for r in rows:
            z = "-" if r["z"] is None else f"{r['z']:.1f}"
            u = unit_text(r.get("unit"))
            print(f"{r['name']:<28} {_g(r['value'], 15, u)} {_g(r['mean'], 15, u)} "
                  f"{_g(r['std'], 14, u)} "
                  f"{z:>7} {r['verdict']:<8} {r['scatter']}")
        for r in rows:
            if r["message"]:
                print(r["message"])
    return 1 if any(r["scatter"] == "beyond" for r in rows) else 0


def _g(v: Any, width: int = 11, unit: str = "") -> str:
    return f"{'-':>{width}}" if v is None else f"{f'{v:.4g} {unit}'.rstrip():>{width}}"
