"""A sequence's steps in the recording: the step timeline beside the channels.

``/sequence/step`` holds the number of the step under way (1 first, 0 between and after
the steps), drawn as steps; ``/sequence/ends/<outcome>`` marks each step's end at its
number, PASS in green and anything else in red, named by the step and what decided it. The
text of each start and end is in ``/events/sequence`` (logged in the tick).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import rerun as rr

from harness.review.layouts import SEQUENCE_STEP

PASS_COLOR = (40, 160, 60)
FAIL_COLOR = (210, 40, 40)


def step_timeline(steps: Sequence[Mapping[str, Any]]) -> tuple[np.ndarray, np.ndarray]:
    """(times, step numbers) drawn as steps: each step's number from its start, 0 from its
    end unless the next starts then; at each change the old value and the new one at the
    same time, so the line's edges are vertical."""
    changes: list[tuple[float, int, float]] = []
    for i, s in enumerate(steps):
        t0, t1 = s.get("started_s"), s.get("ended_s")
        if t0 is None:
            continue
        changes.append((float(t0), 1, float(i + 1)))
        if t1 is not None:
            changes.append((float(t1), 0, 0.0))  # before a start at the same time
    changes.sort(key=lambda c: (c[0], c[1]))
    ts: list[float] = []
    vs: list[float] = []
    cur = 0.0
    for k, (t, _, v) in enumerate(changes):
        if k + 1 < len(changes) and changes[k + 1][0] == t:
            continue  # the last change at this time wins
        if v != cur:
            ts += [t, t]
            vs += [cur, v]
            cur = v
    return np.asarray(ts), np.asarray(vs)


def write_steps(rec: rr.RecordingStream, sequence: Mapping[str, Any]) -> None:
    """The step timeline and each step's end marker into ``rec`` (time: ``time``)."""
    steps = [s for s in sequence.get("steps") or [] if isinstance(s, Mapping)]
    t, v = step_timeline(steps)
    if len(t):
        rec.log(SEQUENCE_STEP, rr.SeriesLines(names="step under way", colors=[(90, 90, 200)]),
                static=True)
        rec.send_columns(SEQUENCE_STEP, indexes=[rr.TimeColumn("time", duration=t)],
                         columns=rr.Scalars.columns(scalars=v))
    for i, s in enumerate(steps):
        if s.get("ended_s") is None:
            continue
        outcome = str(s.get("outcome", ""))
        rec.set_time("time", duration=float(s["ended_s"]))
        rec.log(f"/sequence/ends/{i + 1}",
                rr.SeriesPoints(names=f"{i + 1} {s.get('name', '')}: {outcome}",
                                colors=[PASS_COLOR if outcome == "PASS" else FAIL_COLOR],
                                marker_sizes=[6.0]),
                rr.Scalars(float(i + 1)))
