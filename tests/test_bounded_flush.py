"""Every wait on a Rerun sink has a bound: the recordings written after a run (the
sweep's sweep.rrd, the studies' recordings, identify.rrd, calibration.rrd, verdict.rrd, the
verdict appended to run.rrd) flush through ``harness.record.recording.close_stream``, the
recording's own bounded flush, and a sink that never answers ends in ``OutputError`` naming
the file within the bound instead of a hang."""

from __future__ import annotations

import re
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest
import rerun as rr

import harness.record.recording as recording
from harness.record.output import OutputError

ROOT = Path(__file__).resolve().parents[1]
BOUND_S = 0.3


@pytest.fixture
def mute_sink(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    """Every Rerun flush waits until the test ends (a sink that stopped answering: a full
    disk's dead writer thread, a viewer gone mute), with the flush bound cut to 0.3 s."""
    release = threading.Event()

    def stuck(self: rr.RecordingStream, *args: object, **kwargs: object) -> None:
        release.wait(30.0)

    monkeypatch.setattr(recording, "FLUSH_TIMEOUT_S", BOUND_S)
    monkeypatch.setattr(rr.RecordingStream, "flush", stuck)
    yield
    release.set()
    recording.ABANDONED.clear()  # harness.cli clears it per command; the tests share it


def _sweep(path: Path) -> None:
    from harness.studies.sweep_report import save_rrd

    lambdas, betas = np.array([0.5, 1.0]), np.array([0.6, 0.8])
    save_rrd(path, "sweep", lambdas, betas, np.full((2, 2, 2), 0.01))


def _parman(path: Path) -> None:
    from harness.studies.parman2022 import write_rrd

    write_rrd(path, [])


def _wang(path: Path) -> None:
    from harness.studies.wang2022 import write_recording

    write_recording(str(path), {}, None, np.zeros(4))  # type: ignore[arg-type]


WRITERS: dict[str, Callable[[Path], None]] = {"sweep.rrd": _sweep, "parman2022.rrd": _parman,
                                              "wang2022.rrd": _wang}


@pytest.mark.parametrize("name", list(WRITERS))
def test_a_mute_sink_ends_the_writer_in_bounded_time(name, tmp_path, mute_sink):
    done: list[BaseException | None] = []

    def call() -> None:
        try:
            WRITERS[name](tmp_path / name)
            done.append(None)
        except BaseException as exc:  # judged below
            done.append(exc)

    t0 = time.monotonic()
    worker = threading.Thread(target=call, daemon=True)
    worker.start()
    worker.join(10.0)
    assert done, f"{name}: still waiting on the sink after 10 s (no bound)"
    assert isinstance(done[0], OutputError), f"{name}: {done[0]!r}"
    assert name in str(done[0])
    assert time.monotonic() - t0 < 5.0
    assert recording.ABANDONED.is_set()  # harness.cli then exits without Rerun's shutdown


def test_a_stream_that_flushed_is_disconnected(tmp_path):
    rec = rr.RecordingStream("sgsrt-test", recording_id="bounded")
    rec.save(str(tmp_path / "ok.rrd"))
    rec.log("/x", rr.Scalars(1.0))
    recording.close_stream(rec, tmp_path / "ok.rrd")
    assert (tmp_path / "ok.rrd").stat().st_size > 0


FLUSH_CALL = re.compile(r"\b(rec|stream)\.(flush|disconnect)\(")
BOUNDED_ELSEWHERE = {"harness/review/bus.py": "self.rec.flush()"}
"""The decoded bus writes into the recorder's ``bounded_stream`` (harness.core.session)."""


def test_no_unbounded_rerun_flush_is_left():
    """Rerun streams are flushed and disconnected only by the recording module (its bounded
    flush); elsewhere through ``close_stream`` (or a recorder's bounded stream)."""
    found = []
    for path in sorted((ROOT / "harness").rglob("*.py")):
        if path == ROOT / "harness" / "record" / "recording.py":
            continue
        for i, line in enumerate(path.read_text().splitlines(), 1):
            rel = str(path.relative_to(ROOT))
            if FLUSH_CALL.search(line) and BOUNDED_ELSEWHERE.get(rel) != line.strip():
                found.append(f"{rel}:{i}: {line.strip()}")
    assert not found, "\n".join(found)
