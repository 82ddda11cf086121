"""A suite test's outcome as plain data: verdict names, exit codes, the item record and the
suite's exit code. Shared by the job (``work``), the pytest plugin (``plugin``) and the
report (``report``), so that neither of those two imports the other (the plugin imports the
report; nothing imports the plugin but ``harness test``).
"""

from __future__ import annotations

from typing import Any

NO_CRITERIA = "NO CRITERIA"
"""A test that judged nothing: it ran (or completed) with no criterion of its own. Not a
PASS: a suite fails it unless the suite says ``require_criteria: false``."""

EXIT = {"PASS": 0, "FAIL": 1, "MARGINAL": 5, "ERROR": 4, NO_CRITERIA: 0}

EXIT_ORDER = (130, 2, 3, 4, 1, 5, 0)
"""Most severe first (as ``harness run``'s variants, with 2: refused before anything was
sent, e.g. the pre-flight probe failed)."""


def item_result(verdict: str, reason: str, criteria: list[dict[str, Any]] | None = None,
                exit_code: int | None = None, **extra: Any) -> dict[str, Any]:
    return {"verdict": verdict, "reason": reason, "criteria": criteria or [],
            "exit_code": EXIT[verdict] if exit_code is None else exit_code, **extra}


def exit_code(records: list[dict[str, Any]]) -> int:
    """The exit code of the most severe test: interrupted 130, refused 2, ERROR by a fault
    nobody expected 3, ERROR 4, FAIL 1, MARGINAL 5, PASS (or NO CRITERIA allowed) 0."""
    codes = [r.get("exit_code") if r.get("exit_code") is not None else EXIT[r["verdict"]]
             for r in records if r["verdict"] != "SKIPPED" and r.get("reported", True)]
    return min(codes, key=lambda c: EXIT_ORDER.index(c) if c in EXIT_ORDER else 3,
               default=0)
