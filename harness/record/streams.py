"""Rerun recording streams that leave nothing behind when a run ends.

Every Rerun ``RecordingStream`` owns two threads (its batcher and its sink loop) and its
buffers until it is *destroyed*, which rerun-sdk 0.41 does only when a sweep finds it
orphaned; and a blueprint (``save(default_blueprint=...)``, ``send_blueprint``) is logged
through its own in-memory stream that the sweep never frees, because the blueprint's storage
keeps it referenced. A process making many runs (a suite worker, a benchmark) grew by about
4 MB and 6 threads a run (measured, ``benchmarks/bench_many_runs.py``). Here every
blueprint stream is disconnected as soon as its blueprint has been handed over; a run's own
stream is freed by ``sweep_orphans`` once its owner has disconnected and dropped it
(``Recorder.close``).
"""

from __future__ import annotations

from pathlib import Path

import rerun as rr
import rerun.blueprint as rrb
from rerun_bindings import rerun_bindings as bindings


def _blueprint_storage(application_id: str, blueprint: rrb.BlueprintLike
                       ) -> tuple[object, object]:
    """The blueprint logged into a fresh in-memory stream: (storage, native stream).

    As rerun's own ``create_in_memory_blueprint``, but the stream is returned so that the
    caller can disconnect it (which ends its threads) once the storage has been used."""
    stream = rr.RecordingStream._from_native(bindings.new_blueprint(
        application_id=application_id, make_default=False, make_thread_default=False,
        default_enabled=True))
    stream.set_time("blueprint", sequence=0)
    blueprint.to_blueprint()._log_to_stream(stream)
    native = stream.to_native()
    return bindings.memory_recording(recording=native), native


def save_with_blueprint(rec: rr.RecordingStream, path: Path | str,
                        blueprint: rrb.BlueprintLike | None,
                        write_footer: bool = True) -> None:
    """``rec.save(path, default_blueprint=blueprint, write_footer=...)``, its blueprint
    stream freed once the file sink holds the blueprint."""
    if blueprint is None:
        rec.save(str(path), write_footer=write_footer)
        return
    storage, native = _blueprint_storage(_application_id(rec), blueprint)
    try:
        bindings.save(path=str(path), default_blueprint=storage, recording=rec.to_native(),
                      write_footer=write_footer)
    finally:
        bindings.disconnect(recording=native)


def send_blueprint(rec: rr.RecordingStream, blueprint: rrb.BlueprintLike,
                   make_active: bool = True, make_default: bool = True) -> None:
    """``rec.send_blueprint(...)``, its blueprint stream freed once sent."""
    storage, native = _blueprint_storage(_application_id(rec), blueprint)
    try:
        bindings.send_blueprint(storage, make_active, make_default,
                                recording=rec.to_native())
    finally:
        bindings.disconnect(recording=native)


def sweep_orphans() -> None:
    """Destroy the recording streams nothing references any more (their threads end)."""
    bindings.flush_and_cleanup_orphaned_recordings()


def _application_id(rec: rr.RecordingStream) -> str:
    app = rec.get_application_id()
    if app is None:
        raise ValueError("recording stream without an application id")
    return app
