"""The review layer's annotations of a recording as the recorder takes them
(``harness.record.recording.Annotator``): series named and styled (``names``), events logged
and marked on the plots (``events``), the summary as a markdown table. The caller (the
session, replay) hands ``ReviewAnnotator()`` to the ``Recorder``, so that
``harness.record`` never imports this package."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import rerun as rr

from harness.review.events import log_event, summary_markdown
from harness.review.names import log_series_names


class ReviewAnnotator:
    def name_series(self, rec: rr.RecordingStream, channels: list[str]) -> None:
        log_series_names(rec, channels)

    def log_event(self, rec: rr.RecordingStream, time_s: float, entity: str, text: str,
                  level: str, values: Mapping[str, float], name: str | None,
                  series: str | None) -> None:
        log_event(rec, time_s, entity, text, level, values, name=name, series=series)

    def summary_text(self, summary: Mapping[str, Any]) -> str:
        return summary_markdown(summary)
