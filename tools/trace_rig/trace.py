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

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent.parent
EVENTS = ["irq:*", "ipi:*", "sched:sched_switch", "sched:sched_waking", "sched:sched_wakeup",
          "timer:hrtimer_start", "timer:hrtimer_expire_entry", "timer:hrtimer_expire_exit"]
LINE = re.compile(r"^\s*(?P<task>.+?)-(?P<pid>\d+)\s+\[(?P<cpu>\d+)\]\s+\S+\s+"
                  r"(?P<ts>\d+\.\d+):\s+(?P<what>.*)$")
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
    pid = str(found["pid"])
    events = [m.groupdict() for m in map(LINE.match, lines) if m]
    end = max(i for i, e in enumerate(events) if e["pid"] == pid
              and e["what"].startswith(f"tracing_mark_write: RIG E {found['tick']} "))
    start = max(i for i in range(end) if events[i]["pid"] == pid
                and events[i]["what"].endswith("RIG S"))
    cpu = events[start]["cpu"]
    on_cpu = [e for e in events[:end + 1] if e["cpu"] == cpu]
    t_s, t_e = float(events[start]["ts"]), float(events[end]["ts"])
    print(f"slow answer: tick {found['tick']}, {found['answer_ms']:.3f} ms, longest "
          f"operation {found['longest_op']} {found['longest_op_ms']:.3f} ms, rig pid {pid} "
          f"on CPU {int(cpu)}")
    print(f"events on CPU {int(cpu)} from the answer's start to its end:")
    for e in on_cpu:
        if t_s <= float(e["ts"]) <= t_e:
            print(f"  {e['ts']}  {e['task']}-{e['pid']}: {e['what'][:110]}")
    # each timer that fired on the CPU during the answer, against the expiry it was armed
    # for (hrtimer_start ... expires=, same clock as the handler's now=)
    expires: dict[str, int] = {}
    late = []
    for e in events[:end + 1]:
        m = TIMER.search(e["what"])
        if m is None:
            continue
        if e["what"].startswith("hrtimer_start") and m["expires"]:
            expires[m["ptr"]] = int(m["expires"])
        elif (e["what"].startswith("hrtimer_expire_entry") and m["now"] and e["cpu"] == cpu
              and t_s <= float(e["ts"]) <= t_e and m["ptr"] in expires):
            fn = re.search(r"function=(\w+)", e["what"])
            late.append((fn[1] if fn else "?", (int(m["now"]) - expires[m["ptr"]]) * 1e-6))
    if not late:
        print("timers: none fired on this CPU during the answer (or armed before the trace)")
    for fn, ms in late:
        print(f"timer {fn} fired {ms:.3f} ms after its expiry"
              + ("  <- the CPU was not running for about that long" if ms > 0.1 else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
