"""Criteria on JSON documents (``check:`` in suite files) and across the cases of one test
(``compare:``), with results in verdict.json's criterion shape.

Each criterion becomes ``{"name", "kind", "value", "unit", "limit", "margin", "verdict",
"worst_time_s", "message"}``: ``margin`` is the distance to the nearest limit in the
criterion's unit, positive inside (for ``equals``: 0 when equal, else None). With ``[*]`` in
the field the criterion is judged on every element and reports the worst one.
"""

from __future__ import annotations

import math
import re
from typing import Any

from harness.testing.suite import Check

ORDER = {"PASS": 0, "MARGINAL": 1, "FAIL": 2, "ERROR": 3}
_INDEX = re.compile(r"\[(\*|-?\d+)\]")


class FieldMissing(LookupError):
    pass


def resolve(doc: Any, path: str) -> list[tuple[str, Any]]:
    """Every (concrete path, value) that ``path`` names in ``doc``. Keys may contain dots:
    at each level the longest key that matches the rest of the path wins."""
    out: list[tuple[str, Any]] = []

    def walk(node: Any, rest: str, here: str) -> None:
        if not rest:
            out.append((here, node))
            return
        m = _INDEX.match(rest)
        if m:
            if not isinstance(node, list):
                raise FieldMissing(f"{here or '(top)'}: not a list")
            idx = m.group(1)
            tail = rest[m.end():].removeprefix(".")
            if idx == "*":
                for i, v in enumerate(node):
                    walk(v, tail, f"{here}[{i}]")
            else:
                try:
                    walk(node[int(idx)], tail, f"{here}[{idx}]")
                except IndexError:
                    raise FieldMissing(f"{here}[{idx}]: no such element") from None
            return
        if not isinstance(node, dict):
            raise FieldMissing(f"{here or '(top)'}: not a mapping")
        for key in sorted((k for k in node if isinstance(k, str)), key=len, reverse=True):
            if rest == key or rest.startswith(key + ".") or rest.startswith(key + "["):
                walk(node[key], rest[len(key):].removeprefix("."),
                     f"{here}.{key}" if here else key)
                return
        raise FieldMissing(f"{here + '.' if here else ''}{rest.split('.')[0]}: no such field "
                           f"(fields here: {', '.join(sorted(map(str, node)))[:300]})")

    walk(doc, path, "")
    return out


def _num(v: Any) -> float | None:
    if isinstance(v, bool) or not isinstance(v, int | float):
        return None
    return float(v)


def _judge_value(rules: dict[str, Any], value: Any) -> tuple[str, float | None, str]:
    """(verdict, margin, what broke) of one value against the rules."""
    margins: list[float] = []
    broke = ""
    for rule, limit in rules.items():
        if rule == "equals":
            ok = value == limit or (_num(value) is not None and _num(limit) is not None
                                    and math.isclose(float(value), float(limit)))
            if not ok:
                broke = broke or f"!= {limit!r}"
            continue
        if rule in ("len_min", "len_max"):
            if not hasattr(value, "__len__"):
                return "ERROR", None, f"has no length ({value!r})"
            x = float(len(value))
        else:
            x = _num(value)
            if x is None or math.isnan(x):
                return "ERROR", None, f"is not a number ({value!r})"
        if rule in ("min", "len_min"):
            m = x - float(limit)
            op = "<"
        elif rule in ("max", "len_max"):
            m = float(limit) - x
            op = ">"
        else:  # max_abs
            m = float(limit) - abs(x)
            op = "|x| >"
        margins.append(m)
        if m < 0:
            broke = broke or f"{op} {limit:g}"
    margin = min(margins) if margins else (0.0 if not broke else None)
    return ("FAIL" if broke else "PASS"), margin, broke


def _show(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.6g}"
    if isinstance(v, list | dict):
        return f"{type(v).__name__} of {len(v)}"
    return repr(v)


def judge_check(check: Check, doc: Any) -> dict[str, Any]:
    base = {"name": check.label, "kind": "field", "field": check.field, "unit": check.unit,
            "limit": dict(check.rules), "worst_time_s": None}
    try:
        found = resolve(doc, check.field)
    except FieldMissing as exc:
        return {**base, "value": None, "margin": None, "verdict": "ERROR",
                "message": f"{check.field}: {exc}"}
    if not found:
        return {**base, "value": None, "margin": None, "verdict": "ERROR",
                "message": f"{check.field}: no element"}
    worst = None
    for where, value in found:
        verdict, margin, broke = _judge_value(check.rules, value)
        key = (ORDER[verdict], -(margin if margin is not None else -math.inf))
        if worst is None or key > worst[0]:
            worst = (key, where, value, verdict, margin, broke)
    assert worst is not None
    _, where, value, verdict, margin, broke = worst
    unit = f" {check.unit}" if check.unit else ""
    if verdict == "PASS":
        msg = f"{where} = {_show(value)}{unit} within {_limits(check.rules)}"
        if len(found) > 1:
            msg = f"all {len(found)} within {_limits(check.rules)}; worst {where} = " \
                  f"{_show(value)}{unit}"
    else:
        msg = f"{where} = {_show(value)}{unit} {broke}".rstrip()
    return {**base, "value": value if not isinstance(value, list | dict) else _show(value),
            "margin": margin, "verdict": verdict, "message": msg}


def _limits(rules: dict[str, Any]) -> str:
    names = {"min": ">=", "max": "<=", "max_abs": "|x| <=", "equals": "==",
             "len_min": "len >=", "len_max": "len <="}
    return ", ".join(f"{names[k]} {v:g}" if isinstance(v, int | float) and
                     not isinstance(v, bool) else f"{names[k]} {v!r}" for k, v in rules.items())


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
    """Worst verdict of the criteria, and the reason (the first criterion that set it)."""
    if not criteria:
        return "PASS", empty_reason
    worst = max(criteria, key=lambda c: ORDER[c["verdict"]])
    if worst["verdict"] == "PASS":
        return "PASS", f"{len(criteria)} criteria passed"
    return worst["verdict"], f"{worst['name']}: {worst['message']}"


def worst(verdicts: list[str]) -> str:
    return max(verdicts, key=ORDER.__getitem__) if verdicts else "PASS"
