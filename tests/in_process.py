"""`harness ARGS` in the test's own process, for tests whose claim is the command's behaviour
(exit code, what it prints and writes), not the process's: an interpreter start and the
harness's imports cost 1-2 s of CPU a call. Tests about the process itself (the entry point,
signals, exit paths, child processes, real time) start one."""

from __future__ import annotations

import io
import subprocess
from contextlib import redirect_stderr, redirect_stdout


def harness_in_process(*args: str) -> subprocess.CompletedProcess[str]:
    """``harness.cli.main(ARGS)`` with stdout and stderr captured: its exit code and text as
    ``subprocess.run(..., capture_output=True, text=True)`` would give them."""
    from harness.cli import main

    out, err = io.StringIO(), io.StringIO()
    with redirect_stdout(out), redirect_stderr(err):
        try:
            code = main(list(args))
        except SystemExit as exc:  # argparse's usage errors exit, as the process would
            code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
            if exc.code is not None and not isinstance(exc.code, int):
                print(exc.code, file=err)
    return subprocess.CompletedProcess(["harness", *args], code, out.getvalue(), err.getvalue())
