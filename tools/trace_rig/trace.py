"""Catch one slow answer of the virtual rig in a kernel trace, and say whether its CPU was
running (diagnostic; root and tracefs needed; docs/realtime.md, "Stalls under a running
thread").

Real-time runs of slew-rw (the benchmark's harness block: every actuator commanded, the rig
in its own process over the Unix socket) are made one after another with ftrace recording
interrupts, IPIs, the scheduler and timer expiries on every CPU. The rig process writes a
marker around each SYNC answer and stops the trace at the first answer longer than
``--threshold-ms``. The tool then prints every event on the rig's CPU during that answer and
the lateness of the CPU's periodic scheduler tick (``tick_nohz_handler``) in it: a timer
interrupt is delivered at once to a CPU running user code, so a tick that comes late while
the rig's thread "ran" means the (virtual) CPU was not running: the hypervisor's stall.

    sudo .venv/bin/python tools/trace_rig/trace.py [--threshold-ms 1.0] [--blocks 40]
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent.parent
EVENTS = ["irq:*", "ipi:*", "sched:sched_switch", "sched:sched_waking", "sched:sched_wakeup",
          "timer:hrtimer_start", "timer:hrtimer_expire_entry", "timer:hrtimer_expire_exit"]
LINE = re.compile(r"^\s*(?P<task>.+?)-(?P<pid>\d+)\s+\[(?P<cpu>\d+)\]\s+\S+\s+"
                  r"(?P<ts>\d+\.\d+):\s+(?P<what>.*)$")
TICK_JITTER_NS = 50_000  # a tick this early against the grid is on time, not a period late
TIMER = re.compile(r"hrtimer=(?P<ptr>\w+).*?(?:expires=(?P<expires>\d+)|now=(?P<now>\d+))")


def _w(tracefs: Path, name: str, text: str) -> None:
    (tracefs / name).write_text(text)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--threshold-ms", type=float, default=1.0)
    ap.add_argument("--blocks", type=int, default=40, help="runs of --block-s at most")
    ap.add_argument("--block-s", type=float, default=30.0)
    ap.add_argument("--tracefs", default="/sys/kernel/tracing")
    args = ap.parse_args()
    tracefs = Path(args.tracefs)
    if not (tracefs / "trace_marker").exists():
        subprocess.run(["mount", "-t", "tracefs", "nodev", str(tracefs)], check=False)
    if not os.access(tracefs / "trace_marker", os.W_OK):
        print(f"trace: {tracefs} is not writable (root and tracefs needed)", file=sys.stderr)
        return 2
    _w(tracefs, "tracing_on", "0")
    _w(tracefs, "trace", "")
    _w(tracefs, "buffer_size_kb", "40000")
    _w(tracefs, "set_event", "")
    fd = os.open(tracefs / "set_event", os.O_WRONLY | os.O_APPEND)
    try:
        for e in EVENTS:  # one write each (Python's append mode seeks, which tracefs refuses)
            os.write(fd, (e + "\n").encode())
    finally:
        os.close(fd)
    _w(tracefs, "trace_clock", "global")
    found = None
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "slow.json"
        env = {**os.environ, "PYTHONPATH": f"{HERE}{os.pathsep}{ROOT}",
               "TRACE_RIG_OUT": str(out), "TRACE_RIG_TRACEFS": str(tracefs),
               "TRACE_RIG_THRESHOLD_MS": str(args.threshold_ms)}
        _w(tracefs, "tracing_on", "1")
        try:
            for i in range(args.blocks):
                print(f"trace: run {i + 1}/{args.blocks} ...", file=sys.stderr)
                subprocess.run([sys.executable, "-m", "harness", "run", "slew-rw", "--clock",
                                "realtime", "--duration-s", str(args.block_s), "--quiet",
                                "--out", str(Path(tmp) / "runs")], env=env, cwd=ROOT,
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
                subprocess.run(["rm", "-rf", str(Path(tmp) / "runs")], check=False)
                if out.exists():
                    found = json.loads(out.read_text())
                    break
        finally:
            _w(tracefs, "tracing_on", "0")
        if found is None:
            print(f"trace: no answer over {args.threshold_ms} ms in {args.blocks} runs")
            _w(tracefs, "set_event", "")
            return 1
        lines = (tracefs / "trace").read_text().splitlines()
    _w(tracefs, "set_event", "")
    _w(tracefs, "trace", "")
    result = analyse(lines, found["pid"], found["tick"])
    print(f"slow answer: tick {found['tick']}, {found['answer_ms']:.3f} ms, longest "
          f"operation {found['longest_op']} {found['longest_op_ms']:.3f} ms, rig pid "
          f"{found['pid']} on CPU {result['cpu']}")
    print(f"events on CPU {result['cpu']} from the answer's start to its end:")
    for e in result["events"]:
        print(f"  {e['ts']}  {e['task']}-{e['pid']}: {e['what'][:110]}")
    if not result["timers"]:
        print("timers: none fired on this CPU during the answer")
    for fn, ms in result["timers"]:
        print(f"timer {fn} fired {ms:.3f} ms after its expiry"
              + ("  <- the CPU was not running for about that long" if ms > 0.1 else ""))
    return 0


def analyse(lines: list[str], pid: int, tick: int) -> dict[str, Any]:
    """The rig's answer to ``tick`` (process ``pid``) in an ftrace text: its CPU, every
    event on that CPU between the answer's markers, and each timer that fired there during
    it as (function, ms after its expiry). A timer's expiry is the one its last
    ``hrtimer_start`` set; the periodic scheduler tick, which re-arms itself without one, is
    due on its grid: the previous tick's time on that CPU plus whole periods (the period is
    the shortest spacing of consecutive ticks in the trace)."""
    events = [m.groupdict() for m in map(LINE.match, lines) if m]
    p = str(pid)
    end = max(i for i, e in enumerate(events) if e["pid"] == p
              and e["what"].startswith(f"tracing_mark_write: RIG E {tick} "))
    start = max(i for i in range(end) if events[i]["pid"] == p
                and events[i]["what"].endswith("RIG S"))
    cpu = events[start]["cpu"]
    t_s, t_e = float(events[start]["ts"]), float(events[end]["ts"])
    expires: dict[str, int] = {}
    ticks: list[int] = []  # the periodic tick's now= on this CPU, in order
    timers: list[tuple[str, float]] = []
    for e in events[:end + 1]:
        m = TIMER.search(e["what"])
        if m is None:
            continue
        if e["what"].startswith("hrtimer_start") and m["expires"]:
            expires[m["ptr"]] = int(m["expires"])
            continue
        if not (e["what"].startswith("hrtimer_expire_entry") and m["now"]
                and e["cpu"] == cpu):
            continue
        now = int(m["now"])
        fn = re.search(r"function=(\w+)", e["what"])
        name = fn[1] if fn else "?"
        inside = t_s <= float(e["ts"]) <= t_e
        if name == "tick_nohz_handler":
            if inside and len(ticks) >= 2:
                period = min(b - a for a, b in zip(ticks, ticks[1:], strict=False))
                # whole periods since the last tick, allowing that tick's own jitter
                k = (now - ticks[-1] + TICK_JITTER_NS) // period
                timers.append((name, (now - ticks[-1] - k * period) * 1e-6))
            ticks.append(now)
            expires.pop(m["ptr"], None)  # forwarded from here on, not started
        elif inside and m["ptr"] in expires:
            timers.append((name, (now - expires[m["ptr"]]) * 1e-6))
    return {"cpu": int(cpu), "start_s": t_s, "end_s": t_e, "timers": timers,
            "events": [e for e in events[start:end + 1] if e["cpu"] == cpu]}


if __name__ == "__main__":
    sys.exit(main())
