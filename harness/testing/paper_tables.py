"""The papers' tables from results on disk (``harness report``).

``table2_rows``: our case A/B/C steady tip-acceleration amplitudes beside paper 003's
Table 2, from the newest completed ``summary.json`` of every ``case-X-beta-B`` run under a
logs folder (``collect``). ``newest_results`` and ``write_results_docs``: the docs' result
pages, one a paper suite, from the newest ``results.json`` holding it
(``harness.testing.results_docs`` makes the text).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

from harness.testing.results_docs import PAPER_SUITES, suite_markdown
from rig_models.paper003 import PAPER_TABLE2


def collect(logs: Path) -> dict[str, dict[float, dict]]:
    """case -> beta -> the newest completed run's summary (plus its ``dir``)."""
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


def table2_rows(found: dict[str, dict[float, dict]]) -> list[dict[str, Any]]:
    """One row a case and beta of Table 2: the paper's amplitude and ours (None: no run)."""
    rows = []
    for case, paper in PAPER_TABLE2.items():
        for beta, p_val in paper.items():
            s = found.get(case, {}).get(beta)
            rows.append({"case": case, "beta": beta, "paper_m_s2": p_val,
                         "ours_m_s2": None if s is None else s["steady_tip_accel_amplitude_m_s2"],
                         "frequency_ratio": None if s is None else s["frequency_ratio"],
                         "rotor_speed_rad_s": None if s is None else s["rotor_speed_rad_s"],
                         "run_dir": None if s is None else s["dir"]})
    return rows


def load_results(path: Path) -> dict | None:
    """A suite's results.json (its folder or the file), else None."""
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
        doc = load_results(path)
        if doc is None:
            continue
        names = {r.get("suite") for r in doc["tests"]}
        for suite in PAPER_SUITES:
            if suite in names and (suite not in found or str(doc.get("created_utc", "")) >
                                   str(found[suite][1].get("created_utc", ""))):
                found[suite] = (path, doc)
    return found


def write_results_docs(found: dict[str, tuple[Path, dict]], docs: Path,
                       say: Callable[[str], None]) -> None:
    """``docs/<suite>.md`` for every paper suite in ``found``; ``say`` gets one line a page
    written, or left as it is for want of results."""
    docs.mkdir(parents=True, exist_ok=True)
    for suite in PAPER_SUITES:
        if suite not in found:
            say(f"{suite}: no results; {docs / suite}.md left as it is")
            continue
        path, doc = found[suite]
        src = path if path.is_dir() else path.parent
        text = suite_markdown(doc, suite, f"`{src.name}/results.json`")
        (docs / f"{suite}.md").write_text(text)
        say(f"{docs / suite}.md from {src}")
