"""A sequence's steps as verdict records: each step is judged where it ran, in the tick
(``harness.sequences.runner``); here its outcome in summary.json becomes one record of the
verdict beside the criteria, so verdict.json, the report, JUnit and the recording's
verdict events show every step with its reason.

PASS is PASS; FAIL and TIMEOUT are FAIL (a wait that timed out says so in its message);
ERROR (``on_timeout: error``) is an ERROR of the run; a step not reached is NOT JUDGED with
why. A fault the monitor found after the sequence injected one is the sequence's to judge
(its steps say whether the rig was made safe in time), not an unexpected fault.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from harness.testing.evaluate import ERROR, FAIL, NOT_JUDGED, PASS, CriterionResult

_VERDICT = {"PASS": PASS, "FAIL": FAIL, "TIMEOUT": FAIL, "ERROR": ERROR, "SKIPPED": NOT_JUDGED}


def sequence_of(summary: Mapping[str, Any]) -> Mapping[str, Any] | None:
    seq = summary.get("sequence")
    return seq if isinstance(seq, Mapping) and isinstance(seq.get("steps"), list) else None


def step_name(step: Mapping[str, Any]) -> str:
    prefix = "finally" if step.get("finally") else "step"
    return f"{prefix} {int(step.get('index', 0)) + 1}: {step.get('name', '?')}"


def step_results(summary: Mapping[str, Any]) -> list[CriterionResult]:
    """One record per step of the run's sequence (none without one)."""
    seq = sequence_of(summary)
    if seq is None:
        return []
    out = []
    for step in seq["steps"]:
        if not isinstance(step, Mapping):
            continue
        outcome = str(step.get("outcome", "SKIPPED"))
        verdict = _VERDICT.get(outcome, ERROR)
        ended = step.get("ended_s")
        started = step.get("started_s")
        parts: list[str] = []  # the outcome is the record's value
        if started is not None:
            parts.append(f"t = {float(started):.3f}-{float(ended):.3f} s"
                         if ended is not None else f"from t = {float(started):.3f} s")
        if step.get("reason"):
            parts.append(str(step["reason"]))
        if step.get("condition"):
            parts.append(f"{step['condition']}: {step.get('value', '')}")
        parts += [f"verified {v}" for v in step.get("verified") or [] if isinstance(v, str)]
        measures = step.get("measures") or {}
        if isinstance(measures, Mapping):
            parts += [f"{k} {float(v):.4g}" for k, v in measures.items()
                      if isinstance(v, int | float)]
        message = "; ".join(parts)
        failed = verdict in (FAIL, ERROR)
        out.append(CriterionResult(
            step_name(step), "step", outcome, "", {}, None, verdict,
            float(ended) if failed and ended is not None else None, message,
            why="a step of the run's sequence, decided in the tick",
            violations_s=[float(ended)] if failed and ended is not None else []))
    return out


def first_injection_s(summary: Mapping[str, Any]) -> float | None:
    seq = sequence_of(summary)
    if seq is None:
        return None
    times = [float(f["at_s"]) for f in seq.get("injected") or []
             if isinstance(f, Mapping) and isinstance(f.get("at_s"), int | float)]
    return min(times) if times else None


def without_sequence_faults(summary: Mapping[str, Any]) -> Mapping[str, Any]:
    """``summary`` without the monitor's faults from the sequence's first injection on."""
    t0 = first_injection_s(summary)
    if t0 is None:
        return summary
    faults = [f for f in summary.get("faults") or []
              if not (isinstance(f, Mapping) and isinstance(f.get("time_s"), int | float)
                      and float(f["time_s"]) >= t0 - 1e-9)]
    return {**summary, "faults": faults}
