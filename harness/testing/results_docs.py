"""The docs' result tables, generated from the paper suites' ``results.json`` (``harness test
paper001 ...``): one markdown file per suite, every criterion as claim | ours | limit |
verdict, plus paper 003's Table 1 and Table 2 beside the paper's (from the run and identify
records). Pure: results.json documents in, markdown text out; ``harness report docs`` reads
and writes the files.
"""

from __future__ import annotations

import math
import re
from typing import Any

from harness.testing.measures import unit_text
from rig_models.paper003 import PAPER_TABLE1 as PAPER003_TABLE1
from rig_models.paper003 import PAPER_TABLE2 as PAPER003_TABLE2

PAPER_SUITES = ("paper001", "paper002", "paper003", "paper004")
TITLES = {
    "paper001": "Paper 001 (Hu 2006): PWPF, CSVS and optimal PPF",
    "paper002": "Paper 002 (Parman 2022): LHHL / HLLH two-amplitude shapers",
    "paper003": "Paper 003 (Xu 2018): the SGSRT, square-wave compensation, modes, sweep",
    "paper004": "Paper 004 (Wang 2022): variable-amplitude ZV / ZVD shapers",
}
_BETA = re.compile(r"beta-(\d+(?:\.\d+)?)")


def fmt(v: Any) -> str:
    """A measured value for a table: 4 significant digits, booleans and text as they are."""
    if isinstance(v, bool) or v is None:
        return str(v).lower() if isinstance(v, bool) else "-"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if v != 0 and (abs(v) >= 1e5 or abs(v) < 1e-3):
            return f"{v:.3g}"
        return f"{v:.4g}"
    return str(v)


def _unit(u: str) -> str:
    text = unit_text(u)
    return f" {text}" if text else ""


def fmt_limit(c: dict[str, Any]) -> str:
    lim = dict(c.get("limit") or {})
    u = _unit(str(c.get("unit") or ""))
    if c.get("kind") == "compare":
        which = "largest" if "largest" in lim else "smallest"
        return f"{which} of {len(lim.get('over') or {})}"
    # the verdict layer's limit keys carry the unit (max_abs_deg, len_min_count): shown
    # without it
    bases: dict[str, Any] = {}
    for key, val in lim.items():
        base = next((b for b in ("max_abs", "len_min", "len_max", "equals", "marginal",
                                 "within_ticks", "min", "max", "is") if key == b or
                     key.startswith(b + "_")), key)
        bases[base] = val
    parts = []
    for base, val in bases.items():
        if base == "marginal":
            continue
        shown = fmt(val) if not isinstance(val, bool) else str(val).lower()
        parts.append({"max_abs": f"abs <= {shown}{u}", "min": f">= {shown}{u}",
                      "max": f"<= {shown}{u}", "equals": f"= {shown}", "is": f"= {shown}",
                      "len_min": f"at least {shown}", "len_max": f"at most {shown}",
                      }.get(base, f"{base} {shown}"))
    if bases.get("min") is not None and bases.get("max") is not None and len(parts) == 2:
        return f"{fmt(bases['min'])} to {fmt(bases['max'])}{u}"
    return ", ".join(parts) or "-"


def _short(case_id: str) -> str:
    m = re.search(r"\[(.*)\]$", case_id)
    return m.group(1) if m else case_id


def fmt_value(c: dict[str, Any]) -> str:
    if c.get("kind") == "compare":
        lim = c.get("limit") or {}
        target = lim.get("largest") or lim.get("smallest")
        over = lim.get("over") or {}
        rest = ", ".join(f"{_short(k)} {fmt(v)}" for k, v in over.items() if k != target)
        return f"{_short(str(target))} {fmt(c.get('value'))} ({rest})"
    return f"{fmt(c.get('value'))}{_unit(str(c.get('unit') or ''))}"


def _cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def criteria_table(records: list[dict[str, Any]]) -> list[str]:
    """One row per criterion (its name, and its ``why:`` when it has one: the claim and the
    limit's source); a run test's left-safe criteria (one per variant) as one row."""
    lines = ["| claim | ours | limit | verdict |", "|---|---|---|---|"]
    safe = [c for r in records if r.get("kind") == "run" for c in r.get("criteria") or []
            if c.get("kind") == "left_safe"]
    for rec in records:
        label = rec["item"]
        for c in rec.get("criteria") or []:
            if c.get("kind") == "left_safe":
                continue
            name = str(c.get("name") or c.get("field") or "")
            if c.get("why"):  # the criterion's name, then its statement of what and why
                name = f"{f'`{name}`' if name.isidentifier() else name}: {c['why']}"
            if rec.get("kind") == "run":
                name = f"{label}{' ' if c.get('why') else ': '}{name}"
            lines.append(f"| {_cell(name)} | {_cell(fmt_value(c))} | {_cell(fmt_limit(c))} | "
                         f"{c.get('verdict', '-')} |")
    if safe:
        ok = sum(c.get("verdict") == "PASS" for c in safe)
        worst = "PASS" if ok == len(safe) else "FAIL"
        lines.append(f"| every run left the rig safe (actuators safe, heartbeat disarmed) | "
                     f"{ok} of {len(safe)} runs | all | {worst} |")
    return lines


def paper003_tables(records: list[dict[str, Any]]) -> list[str]:
    """Table 2 (cases A/B/C) and Table 1 (identified modes) beside the paper's."""
    out: list[str] = []
    amps: dict[str, dict[float, float]] = {}
    for rec in records:
        if rec.get("kind") != "run" or rec.get("test") not in PAPER003_TABLE2:
            continue
        m = _BETA.search(str(rec.get("variant") or rec.get("item")))
        amp = (rec.get("summary") or {}).get("steady_tip_accel_amplitude_m_s2")
        if m and amp is not None:
            amps.setdefault(rec["test"], {})[float(m.group(1))] = float(amp)
    if amps:
        out += ["### Table 2: steady tip acceleration amplitude (m/s^2)", "",
                "| case | beta | ours | paper | ours / paper |", "|---|---|---|---|---|"]
        for case, paper in PAPER003_TABLE2.items():
            for beta, p in paper.items():
                ours = amps.get(case, {}).get(beta)
                out.append(f"| {case[-1].upper()} | {beta:g} | {fmt(ours)} | {p:g} | "
                           + (f"{ours / p:.2f} |" if ours is not None else "- |"))
        out.append("")
    modes = next((r.get("modes") for r in records if r.get("kind") == "identify"
                  and r.get("modes")), None)
    if modes:
        out += ["### Table 1: identified modes (free-decay run)", "",
                "| mode | fit (rad/s) | damping | model (rad/s) | model damping | "
                "error (%) | paper measured | paper calculated |",
                "|---|---|---|---|---|---|---|---|"]
        for k, md in enumerate(sorted(modes, key=lambda x: x["omega_rad_s"])):
            pm = PAPER003_TABLE1["measured_fft"][k] if k < 2 else None
            pc = PAPER003_TABLE1["calculated"][k] if k < 2 else None
            out.append(
                f"| {k + 1} | {md['omega_rad_s']:.4f} +- {md.get('sigma_omega_rad_s', 0):.4f} "
                f"| {md['damping_ratio']:.4f} +- {md.get('sigma_damping', 0):.4f} | "
                f"{md.get('model_omega_rad_s', math.nan):.4f} | "
                f"{md.get('model_damping_ratio', math.nan):.4f} | "
                f"{md.get('omega_error_percent', math.nan):+.3f} | "
                f"{'-' if pm is None else f'{pm:g}'} | {'-' if pc is None else f'{pc:g}'} |")
        out.append("")
    return out


def measures_block(measures: dict[str, Any]) -> list[str]:
    """Every measure a study reported (when the results keep them), folded."""
    lines = ["<details><summary>every measure of this study</summary>", "",
             "| measure | value |", "|---|---|"]
    lines += [f"| `{k}` | {fmt(v)} |" for k, v in measures.items()]
    return lines + ["", "</details>", ""]


def suite_markdown(doc: dict[str, Any], suite: str, source: str) -> str:
    """The generated results page of one suite from one results.json document."""
    records = [r for r in doc.get("tests", []) if r.get("suite") == suite]
    counts: dict[str, int] = {}
    for r in records:
        counts[r["verdict"]] = counts.get(r["verdict"], 0) + 1
    worst = next((v for v in ("ERROR", "FAIL", "INCONCLUSIVE", "MARGINAL", "PASS")
                  if counts.get(v)), "-")
    title = TITLES.get(suite, suite)
    desc = next((s.get("description", "") for s in doc.get("suites", [])
                 if s.get("name") == suite), "")
    names = [str(s.get("name")) for s in doc.get("suites", [])] or [suite]
    together = (f" (run together with {', '.join(n for n in names if n != suite)}: "
                "the wall time is theirs together)" if len(names) > 1 else "")
    lines = [
        "<!-- generated by `harness report docs` from " + source + "; do not edit: change "
        f"harness/suites/{suite}.yaml or docs/claims.md and regenerate -->",
        f"# {title}: results", "",
        f"`harness test {suite}` ({desc}): **{worst}** "
        f"({', '.join(f'{n} {v}' for v, n in sorted(counts.items()))}), "
        f"{doc.get('created_utc', '?')}, {doc.get('engine', '?')}, "
        f"wall {fmt(doc.get('wall_time_s'))} s{together}. Each claim is a criterion of the "
        "suite; why each limit is what it is: [docs/claims.md](../claims.md).", ""]
    if suite == "paper003":
        lines += paper003_tables(records)
    by_test: dict[str, list[dict[str, Any]]] = {}
    for r in records:
        key = r["test"].removeprefix("compare[").removesuffix("]")
        by_test.setdefault(key, []).append(r)
    for test, recs in by_test.items():
        verdicts = {r["verdict"] for r in recs}
        v = next((x for x in ("ERROR", "FAIL", "INCONCLUSIVE", "MARGINAL", "PASS")
                  if x in verdicts), "-")
        desc = next((r.get("description") for r in recs if r.get("description")), "")
        lines += [f"## {test}: {v}", ""]
        if desc:
            lines += [desc, ""]
        lines += criteria_table(recs) + [""]
        for r in recs:
            measures = r.get("measures") or (r.get("document") or {}).get("measures")
            if isinstance(measures, dict) and measures:
                lines += measures_block(measures)
    return "\n".join(lines).rstrip() + "\n"
