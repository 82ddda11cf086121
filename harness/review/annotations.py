"""The review layer's annotations of a recording as the recorder takes them
(``harness.record.recording.Annotator``): series named and styled (``names``), events logged
and marked on the plots (``events``), the summary as a markdown table. The caller (the
session, replay) hands ``ReviewAnnotator()`` to the ``Recorder``, so that
``harness.record`` never imports this package.

It also keeps the run's first events (``FIRST_EVENTS``, bounded) and lists them under the
summary: the viewer's events view scrolls to its last rows, where a long run's first
warnings are out of sight.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import rerun as rr

from harness.review.events import log_event, summary_markdown
from harness.review.names import log_series_names

FIRST_EVENTS = 12


class ReviewAnnotator:
    def __init__(self) -> None:
        self.first: list[tuple[float, str, str]] = []
        self.events = 0

    def name_series(self, rec: rr.RecordingStream, channels: list[str]) -> None:
        log_series_names(rec, channels)

    def log_event(self, rec: rr.RecordingStream, time_s: float, entity: str, text: str,
                  level: str, values: Mapping[str, float], name: str | None,
                  series: str | None) -> None:
        log_event(rec, time_s, entity, text, level, values, name=name, series=series)
        self.events += 1
        if len(self.first) < FIRST_EVENTS:
            self.first.append((time_s, level, text))

    def summary_text(self, summary: Mapping[str, Any]) -> str:
        text = summary_markdown(summary)
        if self.first:
            shown = len(self.first)
            text += (f"\n## First events ({shown} of {self.events}; all in the events "
                     "view)\n\n" + "\n".join(f"- {t:.3f} s {lv}: {tx}"
                                              for t, lv, tx in sorted(self.first)) + "\n")
        return text
