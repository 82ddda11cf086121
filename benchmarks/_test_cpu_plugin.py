"""pytest plugin of ``bench_tests_cpu.py --by-file``: each test's CPU, written as JSON.

Per test (setup, call and teardown): the CPU of the pytest process and of the children it
waited for (``RUSAGE_SELF`` and ``RUSAGE_CHILDREN`` deltas), and its wall time. A suite's
forkserver workers are not waited for by anyone in the test (see bench_tests_cpu's
docstring): their CPU is the part the script reports as not attributed to a test. The JSON
goes to ``$SGSRT_TEST_CPU_OUT`` at the end of the session.
"""

from __future__ import annotations

import json
import os
import resource
import time
from collections.abc import Iterator
from typing import Any

import pytest

_ROWS: list[dict[str, Any]] = []


def _cpu() -> tuple[float, float]:
    s = resource.getrusage(resource.RUSAGE_SELF)
    c = resource.getrusage(resource.RUSAGE_CHILDREN)
    return s.ru_utime + s.ru_stime, c.ru_utime + c.ru_stime


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item: pytest.Item, nextitem: pytest.Item | None) -> Iterator[None]:
    own0, kids0 = _cpu()
    t0 = time.monotonic()
    yield
    own1, kids1 = _cpu()
    _ROWS.append({"test": item.nodeid, "cpu_s": own1 - own0, "children_cpu_s": kids1 - kids0,
                  "wall_s": time.monotonic() - t0})


def pytest_sessionfinish(session: pytest.Session) -> None:
    out = os.environ.get("SGSRT_TEST_CPU_OUT")
    if out:
        with open(out, "w") as f:
            json.dump(_ROWS, f)
