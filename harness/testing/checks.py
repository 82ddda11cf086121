"""Judging a suite's criteria: ``check:`` (the run file's scalar form, on a JSON document)
and ``compare:`` (across the cases of one test), with results in verdict.json's criterion
shape.

Each criterion becomes ``{"name", "kind", "value", "unit", "limit", "margin", "verdict",
"worst_time_s", "message"}`` (and ``"why"`` when it has one): ``check:`` criteria are judged
by the verdict layer's own ``evaluate_scalar`` (docs/criteria.md), so a suite and a run file
judge a scalar the same way; ``margin`` is the distance to the nearest limit in the
criterion's unit, positive inside.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import Any

from harness.testing.criteria import Criterion
from harness.testing.evaluate import evaluate_scalar
from harness.testing.measures import FieldMissing, resolve

ORDER = {"PASS": 0, "NO CRITERIA": 0.5, "MARGINAL": 1, "INCONCLUSIVE": 1.5, "FAIL": 2,
         "ERROR": 3}
"""Severity across tests; a test that judged nothing (NO CRITERIA) is worse than one that
passed; INCONCLUSIVE (the bench lost its time) is worse than a pass and hides no FAIL."""


def _num(v: Any) -> float | None:
    if isinstance(v, bool) or not isinstance(v, int | float):
        return None
    try:
        return float(v)
    except OverflowError:  # a hand-edited int too large for a float: not a number here
        return None


def judge_checks(criteria: Iterable[Criterion], doc: Any) -> list[dict[str, Any]]:
    """Every ``check:`` criterion against one JSON document, as verdict.json records."""
    if not isinstance(doc, dict):
        doc = {}
    return [evaluate_scalar(c, doc).to_dict() for c in criteria]


def judge_compare(rule: dict[str, Any], docs: dict[str, Any]) -> dict[str, Any]:
    """``{measure, largest|smallest: CASE}`` over the summaries of a test's cases."""
    which = "largest" if "largest" in rule else "smallest"
    target = rule[which]
    values: dict[str, float | None] = {}
    for case, doc in docs.items():
        try:
            found = resolve(doc, rule["measure"])
            values[case] = _num(found[0][1]) if len(found) == 1 else None
        except FieldMissing:
            values[case] = None
    base = {"name": rule.get("name") or f"{target} has the {which} {rule['measure']}",
            "kind": "compare", "unit": rule.get("unit", ""), "worst_time_s": None,
            "limit": {which: target, "over": values}, "value": values.get(target)}
    if rule.get("why"):
        base["why"] = rule["why"]
    missing = [c for c, v in values.items() if v is None or math.isnan(v)]
    if missing:
        return {**base, "margin": None, "verdict": "ERROR",
                "message": f"{rule['measure']} missing or not a number in {', '.join(missing)}"}
    others = {c: v for c, v in values.items() if c != target}
    best_other = max(others, key=others.get) if which == "largest" else min(
        others, key=others.get)
    v_t, v_o = values[target], others[best_other]
    margin = (v_t - v_o) if which == "largest" else (v_o - v_t)
    verdict = "PASS" if margin > 0 else "FAIL"
    ranking = ", ".join(f"{c} {v:.4g}" for c, v in sorted(values.items(), key=lambda kv: kv[1],
                                                          reverse=True))
    msg = (f"{target} {v_t:.4g} vs next {best_other} {v_o:.4g} ({ranking})" if verdict == "PASS"
           else f"{best_other} {v_o:.4g} is {which}, not {target} {v_t:.4g} ({ranking})")
    return {**base, "margin": margin, "verdict": verdict, "message": msg}


def combine(criteria: list[dict[str, Any]], empty_reason: str = "completed, no criteria"
            ) -> tuple[str, str]:
    """Worst verdict of the criteria, and the reason (the first criterion that set it);
    NO CRITERIA without any (nothing judged is not a pass)."""
    if not criteria:
        return "NO CRITERIA", empty_reason
    # one test's criteria: a run the bench did not hold is INCONCLUSIVE whatever else FAILed
    # (evaluate.run_verdict); only an ERROR outranks it
    inconclusive = [c for c in criteria if c["verdict"] == "INCONCLUSIVE"]
    if inconclusive and not any(c["verdict"] == "ERROR" for c in criteria):
        return "INCONCLUSIVE", f"{inconclusive[0]['name']}: {inconclusive[0]['message']}"
    worst = max(criteria, key=lambda c: ORDER[c["verdict"]])
    if worst["verdict"] == "PASS":
        return "PASS", f"{len(criteria)} criteria passed"
    return worst["verdict"], f"{worst['name']}: {worst['message']}"


def worst(verdicts: list[str]) -> str:
    return max(verdicts, key=ORDER.__getitem__) if verdicts else "PASS"
