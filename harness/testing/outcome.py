"""A suite test's outcome as plain data: verdict names, exit codes, the item record and the
suite's exit code. Shared by the job (``work``), the pytest plugin (``plugin``) and the
report (``report``), so that neither of those two imports the other (the plugin imports the
report; nothing imports the plugin but ``harness test``).
"""

from __future__ import annotations

from typing import Any

from harness.testing.evaluate import NO_CRITERIA

# NO CRITERIA: a test that judged nothing. Not a PASS: a suite fails it unless the suite
# says ``require_criteria: false`` (``require_criteria``).

EXIT = {"PASS": 0, "FAIL": 1, "MARGINAL": 5, "ERROR": 4, "INCONCLUSIVE": 6, NO_CRITERIA: 0}

EXIT_ORDER = (130, 2, 3, 4, 1, 6, 5, 0)
"""Most severe first (as ``harness run``'s variants, with 2: refused before anything was
sent, e.g. the pre-flight probe failed). INCONCLUSIVE (6: a test the bench could not hold in
time) is worse than a pass and never hides another test's FAIL."""


def item_result(verdict: str, reason: str, criteria: list[dict[str, Any]] | None = None,
                exit_code: int | None = None, **extra: Any) -> dict[str, Any]:
    return {"verdict": verdict, "reason": reason, "criteria": criteria or [],
            "exit_code": EXIT[verdict] if exit_code is None else exit_code, **extra}


def require_criteria(items: dict[str, dict[str, Any]], required: bool) -> dict[str, Any]:
    """A suite's items with NO CRITERIA turned into FAIL when the suite requires criteria
    (its default): a test that checks nothing must not count as passed."""
    if not required:
        return items
    return {name: (item_result(
        "FAIL", f"no criteria: {res['reason']}; this test judges nothing (give it expect: or "
        "check:, or set require_criteria: false in the suite)", res.get("criteria"),
        **{k: v for k, v in res.items() if k not in ("verdict", "reason", "criteria",
                                                      "exit_code")})
                   if res.get("verdict") == NO_CRITERIA else res)
            for name, res in items.items()}


def exit_code(records: list[dict[str, Any]]) -> int:
    """The exit code of the most severe test: interrupted 130, refused 2, ERROR by a fault
    nobody expected 3, ERROR 4, FAIL 1, INCONCLUSIVE 6, MARGINAL 5, PASS (or NO CRITERIA
    allowed) 0."""
    codes = [r.get("exit_code") if r.get("exit_code") is not None else EXIT[r["verdict"]]
             for r in records if r["verdict"] != "SKIPPED" and r.get("reported", True)]
    return min(codes, key=lambda c: EXIT_ORDER.index(c) if c in EXIT_ORDER else 3,
               default=0)
