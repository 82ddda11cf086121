"""The review layer's place in the house: ``harness.record`` imports
nothing of ``harness.review`` (the recorder takes the review's names, markers and summary text
as an ``Annotator``), and ``harness.review`` imports nothing of ``harness.core`` or
``harness.testing``, so the dependency runs one way: core -> review -> record."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1] / "harness"


def imported(path: Path) -> set[str]:
    """Every module a file imports, at the top or inside a function (lazy imports too)."""
    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            out.add(node.module)
    return out


@pytest.mark.parametrize(("package", "forbidden"), [
    ("record", ("harness.review", "harness.core", "harness.bus", "harness.testing")),
    ("review", ("harness.core", "harness.testing", "harness.commands")),
])
def test_package_imports_only_below_it(package, forbidden):
    files = sorted((ROOT / package).glob("*.py"))
    assert files
    for f in files:
        bad = sorted(m for m in imported(f) if m.startswith(forbidden))
        assert not bad, f"{f.relative_to(ROOT.parent)} imports {bad}"


def test_the_recorder_takes_the_review_as_an_annotator(tmp_path):
    """Without the review layer a recording still gets its events (as text logs) and its
    summary; with it, the legends and markers."""
    from harness.record.recording import Recorder
    from harness.review.annotations import ReviewAnnotator
    from harness.review.reader import read_events, read_series_names, read_text

    for annotator, named in ((None, False), (ReviewAnnotator(), True)):
        path = tmp_path / f"r{named}.rrd"
        rec = Recorder(path, ["/tip/accel_m_s2"], 0, "t", annotator=annotator)
        rec.row(0.0)[:] = 0.5
        rec.commit()
        rec.log_event(0.0, "/events/monitor", "monitor: tip_accel: big", "WARN")
        rec.log_summary({"run": "t", "stopped_by": "completed"})
        rec.close()
        assert [e.text for e in read_events(path)] == ["monitor: tip_accel: big"]
        assert "completed" in (read_text(path, "/run/summary") or "")
        names = read_series_names(path)
        assert (names.get("/tip/accel_m_s2") == ["tip acceleration"]) is named
        markers = read_series_names(path, points=True)
        assert ("/markers/tip/warning" in markers) is named
        # the review lists the first events under the summary (the events view scrolls to
        # its last rows)
        assert ("First events (1 of 1" in (read_text(path, "/run/summary") or "")) is named
