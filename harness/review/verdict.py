"""The verdict where a reviewer looks: in run.rrd itself once the run is judged (re-judging
replaces it), as a text view of the default layout, its violations in the events view and
marked on the plots.

``/run/verdict`` (static markdown): a headline naming the root cause (an unexpected fault
or an interruption that stopped the run, not the criteria it left unjudged), then every
criterion, failing ones first, each on its own lines (a narrow view wraps them; a table's
last columns were out of view): verdict, name, value, limit, margin and the time of the worst
sample. ``/events/verdict`` and ``/markers/<plot>/verdict``: each violation at its time.

Input is verdict.json's form (``Verdict.to_dict()``) and the run's summary.json; nothing of
the verdict layer is imported (harness.testing calls this).
"""

from __future__ import annotations

import json
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import rerun as rr

from harness.review.layouts import LAYOUT_FILE
from harness.review.units import limit_text, quantity

APPLICATION_ID = "sgsrt-harness"  # harness.record.recording's
VERDICT_ENTITY = "/run/verdict"
SEVERITY = {"ERROR": 0, "INCONCLUSIVE": 0.5, "FAIL": 1, "MARGINAL": 2, "NOT JUDGED": 3,
            "PASS": 4}

def seconds(t: Any) -> str:
    """A time on the run's timeline, to the millisecond (a tick at 500 Hz is 2 ms)."""
    return f"{t:.3f} s" if isinstance(t, int | float) and not isinstance(t, bool) else "-"


def _fault_text(f: Mapping[str, Any]) -> str:
    return (f"{f.get('device', '?')}: {f.get('kind', '?')} at {seconds(f.get('time_s'))}"
            + (f" ({f['message']})" if f.get("message") else ""))


def root_cause(verdict: Mapping[str, Any], summary: Mapping[str, Any] | None) -> str | None:
    """What stopped the run when the run did not end as planned: the first fault it did not
    expect, an interruption or an error; None when it completed (the criteria speak)."""
    summary = summary or {}
    criteria = verdict.get("criteria") or []
    expected = any(c.get("kind") == "fault" and c.get("verdict") == "PASS" for c in criteria)
    stopped = summary.get("stopped_by")
    faults = summary.get("faults") or []
    if stopped == "fault" and faults and isinstance(faults[0], Mapping):
        seq = summary.get("sequence") if isinstance(summary.get("sequence"), Mapping) else {}
        injected = [f for f in seq.get("injected") or [] if isinstance(f, Mapping)]
        t = faults[0].get("time_s")
        if injected and isinstance(t, int | float) and any(
                isinstance(f.get("at_s"), int | float) and f["at_s"] <= t for f in injected):
            f = injected[0]
            return (f"{_fault_text(faults[0])}, after the sequence injected {f.get('kind')} "
                    f"at {seconds(f.get('at_s'))} (step {f.get('step')}), stopped the run")
        what = "expected fault" if expected else "unexpected fault"
        return f"{what} {_fault_text(faults[0])} stopped the run"
    unexpected = [c for c in criteria if c.get("kind") == "fault"
                  and c.get("verdict") in ("ERROR", "FAIL")]
    if unexpected:
        c = unexpected[0]
        return f"unexpected fault {c.get('value')} at {seconds(c.get('worst_time_s'))}"
    if stopped == "interrupted":
        return f"interrupted at {seconds(summary.get('simulated_time_s'))}"
    if stopped == "error":
        return f"harness error: {summary.get('error') or '?'}"
    if verdict.get("verdict") == "ERROR" and not summary:
        return "no summary.json: the harness did not finish the run (killed?)"
    return None


def ordered(criteria: Sequence[Mapping[str, Any]]) -> list[Mapping[str, Any]]:
    """Failing first (ERROR, FAIL, MARGINAL, NOT JUDGED, PASS), the root cause (a fault)
    first of its verdict, otherwise in the run file's order."""
    return sorted(criteria, key=lambda c: (SEVERITY.get(str(c.get("verdict")), -1),
                                           c.get("kind") != "fault"))


def criterion_lines(c: Mapping[str, Any], consequence: str | None = None) -> list[str]:
    """One criterion: verdict and name, value, limit, margin, worst sample's time (each
    only when it has one), and for a criterion that did not pass, its message."""
    unit = str(c.get("unit") or "")
    parts = [quantity(c.get("value"), unit)]
    if c.get("kind") == "settles" and c.get("value") is not None:
        parts[0] += " after its trigger"  # summary.json's settle_time_s counts from t = 0
    if c.get("limit"):
        parts.append(f"limit {limit_text(c['limit'])}")
    if c.get("margin") is not None:
        parts.append(f"margin {quantity(c['margin'], unit)}")
    if c.get("worst_time_s") is not None:
        parts.append(f"worst at {seconds(c['worst_time_s'])}")
    lines = [f"- **{c.get('verdict')}** {c.get('name')}: " + "; ".join(parts)]
    if c.get("verdict") != "PASS" and c.get("message"):
        note = f" ({consequence})" if consequence and \
            str(c.get("message", "")).startswith("missing data") else ""
        lines.append(f"  {c['message']}{note}")
    return lines


def verdict_markdown(verdict: Mapping[str, Any], summary: Mapping[str, Any] | None = None
                     ) -> str:
    """The verdict document (see the module docstring)."""
    v = str(verdict.get("verdict", "?"))
    cause = root_cause(verdict, summary)
    criteria = ordered(verdict.get("criteria") or [])
    headline = f"# {v}: {cause}" if cause and v != "PASS" else f"# {v}"
    lines = [headline, ""]
    if cause and v == "PASS":
        lines += [cause + " (as the run expects)", ""]
    if not cause or v == "PASS":  # else the reason names a consequence, not the cause
        lines += [str(verdict.get("reason", "")), ""]
    failing = sum(1 for c in criteria if c.get("verdict") not in ("PASS", "NOT JUDGED"))
    unjudged = sum(1 for c in criteria if c.get("verdict") == "NOT JUDGED")
    lines.append(f"{len(criteria)} criteria, {failing} not passed"
                 + (f", {unjudged} not judged (the run stopped early)" if unjudged else "")
                 + " (failing first):")
    lines.append("")
    consequence = "a consequence of the run stopping early" if cause else None
    for c in criteria:
        lines += criterion_lines(c, consequence)
    return "\n".join(lines) + "\n"


def violations(verdict: Mapping[str, Any]) -> list[tuple[float, Mapping[str, Any]]]:
    """(time, criterion) of each criterion's worst sample when it did not pass."""
    out = []
    for c in verdict.get("criteria") or []:
        t = c.get("worst_time_s")
        if c.get("verdict") not in ("PASS", "NOT JUDGED") and isinstance(t, int | float):
            out.append((float(t), c))
    return sorted(out, key=lambda x: x[0])


def log_verdict(rec: rr.RecordingStream, verdict: Mapping[str, Any],
                summary: Mapping[str, Any] | None,
                events: Sequence[tuple[float, str, str]] = (),
                run_rrd: Path | None = None) -> None:
    """The verdict document, its violations as events (``events``: (time, level, text);
    default: each failing criterion's worst sample) and their markers on the plots at the
    run's values (read from ``run_rrd``)."""
    from harness.review.events import mark_events

    rec.log(VERDICT_ENTITY, rr.TextDocument(verdict_markdown(verdict, summary),
                                            media_type="text/markdown"), static=True)
    if not events:
        events = [(t, "ERROR" if c.get("verdict") == "ERROR" else "WARN",
                   f"{c.get('name')} {c.get('verdict')}: {c.get('message')}")
                  for t, c in violations(verdict)]
    for t, level, text in events:
        rec.set_time("time", duration=t)
        rec.log("/events/verdict", rr.TextLog(text, level=level))
    # a fault criterion's violation is the fault the run already marked on every plot:
    # a second marker there only cost a legend line (five-line legends were clipped)
    faults = tuple(f"{c.get('name')} " for c in verdict.get("criteria") or []
                   if c.get("kind") == "fault")
    marks = [(t, "verdict", f"VERDICT {text.split(':')[0]}"[:48]) for t, _, text in events
             if not (faults and text.startswith(faults))]
    if run_rrd is not None and marks:
        mark_events(rec, run_rrd, marks)


SHIFT = re.compile(r"time shift ([+-]?\d+(?:\.\d+)?) s")
BASELINE_COLOUR = (150, 150, 150)


def baseline_entity(channel: str) -> str:
    """Where a baseline's copy of ``channel`` goes: ``/baseline/attitude/error_deg``; each
    plot of the channel lists it (harness.review.layouts.time_plot)."""
    return "/baseline" + channel


def log_baselines(rec: rr.RecordingStream, run_dir: Path, verdict: Mapping[str, Any]) -> int:
    """Each ``baseline:`` criterion's baseline channel on the run's time axis, shifted as
    judged (the judged run's sample at t was compared with the baseline's at t + shift,
    the shift the message names), drawn on the channel's plot; returns how many."""
    import yaml

    from harness.record.reader import read_scalar_channel

    try:
        cfg = yaml.safe_load((run_dir / "config.yaml").read_text()) or {}
    except (OSError, yaml.YAMLError):
        return 0
    data = cfg.get("run", cfg) if isinstance(cfg, dict) else {}
    expect = data.get("expect") or cfg.get("expect") or {}
    n = 0
    for c in verdict.get("criteria") or []:
        spec = expect.get(c.get("name")) if isinstance(expect, Mapping) else None
        if c.get("kind") != "baseline" or not isinstance(spec, Mapping):
            continue
        channel, base = spec.get("channel"), spec.get("baseline")
        if not isinstance(channel, str) or not isinstance(base, str):
            continue
        base_path = Path(base)
        if not base_path.is_absolute():
            base_path = run_dir / base_path
        rrd = base_path / "run.rrd" if base_path.is_dir() else base_path
        match = SHIFT.search(str(c.get("message", "")))
        shift = float(match.group(1)) if match else 0.0
        try:
            t, v = read_scalar_channel(rrd, channel)
        except (OSError, ValueError, RuntimeError):
            continue  # the baseline may be on another machine: the verdict says so
        entity = baseline_entity(channel)
        rec.log(entity, rr.SeriesLines(
            names=f"baseline ({'shifted' if match else 'unshifted'} {shift:+.3f} s)",
            colors=[BASELINE_COLOUR], aggregation_policy="MinMax"), static=True)
        rec.send_columns(entity, indexes=[rr.TimeColumn("time", duration=t - shift)],
                         columns=rr.Scalars.columns(scalars=v))
        n += 1
    return n


def _summary(run_dir: Path) -> dict[str, Any]:
    try:
        loaded = json.loads((run_dir / "summary.json").read_text())
        return loaded if isinstance(loaded, dict) else {}
    except (OSError, ValueError):
        return {}


def recorded_bytes(run_dir: Path) -> int | None:
    """The size of run.rrd before a verdict was first appended (layout.json), or None."""
    try:
        saved = json.loads((run_dir / LAYOUT_FILE).read_text())
    except (OSError, ValueError):
        return None
    n = saved.get("run_rrd_bytes") if isinstance(saved, dict) else None
    return n if isinstance(n, int) and not isinstance(n, bool) and n > 0 else None


def run_rrd_sha256(run_dir: Path) -> str | None:
    """SHA-256 of the run's own recording: run.rrd without the verdict appended to it."""
    from harness.record.append import sha256_prefix

    rrd = run_dir / "run.rrd"
    n = recorded_bytes(run_dir)
    if n is not None and rrd.is_file() and n > rrd.stat().st_size:
        n = None
    return sha256_prefix(rrd, n)


def _remember_size(run_dir: Path, size: int) -> None:
    path = run_dir / LAYOUT_FILE
    try:
        saved = json.loads(path.read_text())
    except (OSError, ValueError):
        saved = {}
    if not isinstance(saved, dict):
        saved = {}
    saved["run_rrd_bytes"] = size
    path.write_text(json.dumps(saved, indent=1))


def write_into_run(run_dir: Path, verdict: Mapping[str, Any],
                   events: Sequence[tuple[float, str, str]] = ()) -> bool:
    """The verdict appended to the run's run.rrd, with the run's layout made default again;
    re-judging first cuts the file back to the run's own bytes (``recorded_bytes``), so the
    earlier verdict is replaced and the recording itself never rewritten. False when
    run.rrd is missing or cut short (the verdict is then in verdict.rrd only)."""
    from harness.record.append import append_stream, stream_end, truncate_to
    from harness.review.layouts import blueprint_for_run_dir

    rrd = run_dir / "run.rrd"
    if not rrd.is_file():
        return False
    own = recorded_bytes(run_dir)
    if own is not None and own <= rrd.stat().st_size:
        if not truncate_to(rrd, own):
            return False
    elif stream_end(rrd) != "open":
        return False
    else:
        _remember_size(run_dir, rrd.stat().st_size)
    summary = _summary(run_dir)
    try:
        blueprint = blueprint_for_run_dir(run_dir)
    except (OSError, ValueError, KeyError, TypeError):
        blueprint = None

    def write(rec: rr.RecordingStream) -> None:
        log_verdict(rec, verdict, summary, events, rrd)
        log_baselines(rec, run_dir, verdict)

    return append_stream(rrd, APPLICATION_ID, run_dir.name, write, blueprint)
