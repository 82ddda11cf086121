"""Loaded by every Python process started with tools/trace_rig on PYTHONPATH; acts only in
the virtual rig's own process (``TRACE_RIG_OUT`` set and ``harness virtual-rig`` running):
writes an ftrace marker at the start (``RIG S``) and end (``RIG E tick ms``) of every SYNC
answer and stops tracing at the first answer longer than ``TRACE_RIG_THRESHOLD_MS``, so the
kernel's ring buffer ends with it. Diagnostic only (tools/trace_rig/trace.py)."""

import os
import sys

if os.environ.get("TRACE_RIG_OUT") and "virtual-rig" in " ".join(sys.orig_argv):
    import json
    import time

    from rig_models import virtual_rig as _vr

    _T = os.environ.get("TRACE_RIG_TRACEFS", "/sys/kernel/tracing") + "/"
    _marker = os.open(_T + "trace_marker", os.O_WRONLY)
    _limit_s = float(os.environ.get("TRACE_RIG_THRESHOLD_MS", "1.0")) * 1e-3
    _state = {"stopped": False}
    _orig = _vr.VirtualRig._on_sync

    def _on_sync(self, data):  # type: ignore[no-untyped-def]
        if _state["stopped"]:
            return _orig(self, data)
        os.write(_marker, b"RIG S")
        t0 = time.perf_counter()
        _orig(self, data)
        took = time.perf_counter() - t0
        os.write(_marker, b"RIG E %d %.3f" % (self.tick, took * 1e3))
        if took > _limit_s:
            with open(_T + "tracing_on", "w") as f:
                f.write("0")
            _state["stopped"] = True
            with open(os.environ["TRACE_RIG_OUT"], "w") as f:
                json.dump({"pid": os.getpid(), "tick": self.tick, "answer_ms": took * 1e3,
                           "longest_op": self.longest_op,
                           "longest_op_ms": self.longest_op_s * 1e3}, f)

    _vr.VirtualRig._on_sync = _on_sync
