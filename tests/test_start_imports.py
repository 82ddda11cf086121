"""A harness process's start stays cheap: every suite worker, study and command pays it.
scipy.stats (through scipy.signal's peak finding or qmc) was a quarter of it;
it is imported where it is used."""

from __future__ import annotations

import subprocess
import sys


def test_a_harness_start_does_not_import_scipy_stats() -> None:
    code = ("import sys, harness.cli, harness.core.session, harness.testing.work; "
            "print(sorted(m for m in sys.modules if m.startswith('scipy.stats')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.strip()
    assert out == "[]", f"imported at start: {out}"
