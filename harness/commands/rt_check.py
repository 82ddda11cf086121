"""`harness rt-check [--rate-hz 500] [--duration-s 60] [--cpu N] [--work-us 150] [--json]`:
the host's real-time floor, the pre-flight beside `harness probe`.

Runs a bare loop at the rate (the harness's clock, its real-time measures: SCHED_FIFO
priority 50, mlockall, pinned to ``--cpu`` or the last CPU, gc off) doing ``--work-us`` of
busy work a tick, the way cyclictest measures a host, and reports lateness p50/p99/max and
overruns beside the host facts that decide real time: kernel preemption model and
PREEMPT_RT, CPU frequency governor, isolated CPUs, SMT, virtual machine, RT throttling,
whether SCHED_FIFO and memory locking are allowed and their limits. The verdict: HOLDS
(overruns <= 0.01 % of ticks and lateness p99 <= 10 % of the period), CANNOT HOLD (> 1 % or
p99 > 50 % of the period), MARGINAL between; then what to change. A measure the OS refuses
is reported (and the floor is measured without it).

Exit status: 0 HOLDS, 5 MARGINAL, 1 CANNOT HOLD, 2 bad input. See docs/realtime.md.
"""

from __future__ import annotations

import argparse
import json
import sys

from harness.commands import examples
from harness.realtime import DEFAULT_WORK_S


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("rt-check", help="the host's real-time floor and what decides it",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--rate-hz", type=float, default=500.0, help="loop rate (default 500)")
    p.add_argument("--duration-s", type=float, default=60.0,
                   help="how long to measure (default 60)")
    p.add_argument("--cpu", type=int, default=-1,
                   help="CPU to pin the loop to (default -1: the last one, as a run does)")
    p.add_argument("--work-us", type=float, default=DEFAULT_WORK_S * 1e6,
                   help="busy work a tick in microseconds (default 150)")
    p.add_argument("--json", action="store_true", help="print the report as JSON on stdout")
    p.epilog = examples(
        "harness rt-check --duration-s 10",
        "harness rt-check --rate-hz 1000 --cpu 1 --json")
    p.set_defaults(func=cmd_rt_check)


def cmd_rt_check(args: argparse.Namespace) -> int:
    period_us = 1e6 / args.rate_hz if args.rate_hz > 0 else 0.0
    if not 0 < args.rate_hz <= 10_000:
        print(f"harness rt-check: --rate-hz {args.rate_hz:g}: expected 0 < rate <= 10000 Hz",
              file=sys.stderr)
        return 2
    if args.duration_s <= 0:
        print(f"harness rt-check: --duration-s {args.duration_s:g}: expected > 0 s",
              file=sys.stderr)
        return 2
    if not 0 <= args.work_us < period_us:
        print(f"harness rt-check: --work-us {args.work_us:g}: expected 0 <= work < the period "
              f"({period_us:g} us)", file=sys.stderr)
        return 2
    # the floor's loop and clock, imported only when measuring (their numpy and python-can
    # would slow `harness rt-check --help`)
    from harness.realtime.check import format_report, judge
    from harness.realtime.floor import Measures, run_floor
    from harness.realtime.host import read_host_facts

    host = read_host_facts()
    if args.cpu >= 0 and host.cpus_online and args.cpu not in host.cpus_online:
        print(f"harness rt-check: --cpu {args.cpu}: not an online CPU {host.cpus_online}",
              file=sys.stderr)
        return 2
    print(f"harness rt-check: measuring {args.duration_s:g} s at {args.rate_hz:g} Hz ...",
          file=sys.stderr)
    floor = run_floor(args.rate_hz, args.duration_s, args.work_us * 1e-6,
                      Measures(cpu=args.cpu))
    check = judge(floor, host, args.duration_s, args.work_us * 1e-6)
    if args.json:
        print(json.dumps(check.to_dict(), indent=2))
    else:
        print(format_report(check))
    return check.exit_code
