"""The verdict layer: criteria (a run file's ``expect:`` section), judging, verdicts.

Depends on the loop's channel list, the recording, the CAN log and the pure
``harness.identification`` (the ``modal_residual:`` fit); nothing below it imports it
(``harness.core.runs`` calls ``parse_criteria`` lazily to refuse bad criteria before a run).
The criteria forms are documented in docs/criteria.md.

Public API
----------
``parse_criteria(raw, source="expect", known_measures=None, channels=None, key="expect",
base_dir=None, check_files=True, open_paths=False) -> list[Criterion]``
    Check an ``expect:`` section (mapping ``name: criterion`` or a list); raises
    ``ConfigError`` naming ``source`` and the key path (``expect.final_error.max_abs_s: ...``).
    ``known_measures``: extra scalar paths beside summary.json's (unit from the name's
    suffix, dimensionless ``ratio`` without one). ``channels=()`` for results without a
    recording (scalar criteria only); None = the loop's recorded channels. ``open_paths``:
    a ``measure:`` may be any field of the judged document (a suite's ``check:``,
    ``harness.testing.suite.parse_checks``).

``evaluate_scalar(criterion, measures) -> CriterionResult``
    A ``measure:`` criterion against any mapping (summary.json, a study's JSON output):
    dotted paths (keys may contain dots), ``[N]`` / ``[*]`` into lists (every element
    judged, the worst reported), min / max / max_abs / equals, a list's length, ``is``,
    and the marginal band. The one scalar implementation of run files and suites.

``evaluate(criteria, facts) -> list[CriterionResult]``
    Every criterion against ``Facts(measures, channel, baseline_channel, left_safe,
    blocks)``: ``blocks(entities)`` yields ``(entity, t_s, values)`` chunk by chunk in one
    pass (the channel forms stream over it in bounded memory); without it each
    ``channel(entity) -> (t_s, values)`` is read whole. The others are called only by the
    forms that need them. Missing data gives that criterion ERROR, never an exception.

``make_verdict(results, identity=None) -> Verdict``
    ERROR if any, else INCONCLUSIVE if any (a real-time budget criterion failed: the bench
    did not hold its time), else the worst (PASS < MARGINAL < FAIL); no results is NO CRITERIA
    (nothing judged: exit 0 for ``harness run``, with a warning; a suite fails it unless
    ``require_criteria: false``).

``judge_run(run_dir, expect=None) -> Verdict``
    A run directory judged by its own criteria (config.yaml's ``run.expect`` with the rig's
    ``expect_overrides``) or ``expect`` (a YAML file path or the section itself), plus the
    run's own checks (it raised, was interrupted, a fault nobody expected, files missing).
    ``write_verdict(verdict, run_dir)`` writes verdict.json and verdict.rrd;
    ``format_block(verdict, path)`` is the text ``harness run`` / ``harness judge`` print.

``Verdict``: ``.verdict`` ("PASS" | "MARGINAL" | "INCONCLUSIVE" | "FAIL" | "ERROR" |
"NO CRITERIA"), ``.reason``,
``.criteria`` (CriterionResult: name, kind, value, unit, limit, margin, verdict,
worst_time_s, message), ``.identity``, ``.exit_code``, ``.to_dict()`` (verdict.json).

Exit codes (``EXIT_CODES``): 0 PASS (or NO CRITERIA), 1 FAIL, 2 bad input / refused before
anything was sent, 3 ERROR by a fault the run did not expect, 4 ERROR otherwise (exception,
missing data), 5 MARGINAL, 6 INCONCLUSIVE (the bench did not hold real time:
``harness.testing.bench``), 130 interrupted.
"""

from __future__ import annotations

from harness.testing.criteria import (
    Criterion,
    Window,
    apply_overrides,
    parse_criteria,
    parse_criterion,
    resolve_baselines,
)
from harness.testing.evaluate import (
    ERROR,
    FAIL,
    INCONCLUSIVE,
    MARGINAL,
    NO_CRITERIA,
    NOT_JUDGED,
    PASS,
    SEVERITY,
    CriterionResult,
    Facts,
    MissingData,
    evaluate,
    evaluate_scalar,
    exit_code,
    run_checks,
    worst_verdict,
)
from harness.testing.judge import (
    JudgeInputError,
    Verdict,
    format_block,
    judge_run,
    make_verdict,
    write_verdict,
)

EXIT_CODES = {"PASS": 0, "FAIL": 1, "BAD_INPUT": 2, "ERROR_FAULT": 3, "ERROR": 4,
              "MARGINAL": 5, "INCONCLUSIVE": 6, "INTERRUPTED": 130}

__all__ = [
    "ERROR", "EXIT_CODES", "FAIL", "INCONCLUSIVE", "MARGINAL", "NO_CRITERIA", "NOT_JUDGED",
    "PASS", "SEVERITY", "Criterion",
    "CriterionResult", "Facts", "JudgeInputError", "MissingData", "Verdict", "Window",
    "apply_overrides", "evaluate", "evaluate_scalar", "exit_code", "format_block",
    "judge_run", "make_verdict", "parse_criteria", "parse_criterion", "resolve_baselines",
    "run_checks", "worst_verdict", "write_verdict",
]
