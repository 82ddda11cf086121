"""``harness rt-check``'s verdict: can this host hold the rate, and what to change."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from harness.realtime.floor import FloorResult
from harness.realtime.host import HostFacts

HOLDS, MARGINAL, CANNOT = "HOLDS", "MARGINAL", "CANNOT HOLD"
EXIT_CODES = {HOLDS: 0, MARGINAL: 5, CANNOT: 1}

# the criteria (fractions of ticks and of the period); documented in docs/realtime.md
HOLD_OVERRUN_FRACTION = 1e-4  # at most 1 tick in 10 000 misses its deadline
HOLD_P99_FRACTION = 0.10  # p99 lateness within a tenth of the period
CANNOT_OVERRUN_FRACTION = 1e-2  # more than 1 tick in 100 missed
CANNOT_P99_FRACTION = 0.50  # p99 lateness beyond half the period


@dataclass
class RtCheck:
    verdict: str
    reason: str
    floor: FloorResult
    host: HostFacts
    duration_s: float
    work_s: float
    advice: list[str] = field(default_factory=list)

    @property
    def exit_code(self) -> int:
        return EXIT_CODES[self.verdict]

    def to_dict(self) -> dict[str, Any]:
        return {"verdict": self.verdict, "reason": self.reason,
                "rate_hz": self.floor.rate_hz, "duration_s": self.duration_s,
                "work_us": self.work_s * 1e6, "floor": self.floor.to_dict(),
                "host": self.host.to_dict(), "advice": self.advice,
                "criteria": {"hold_overrun_fraction": HOLD_OVERRUN_FRACTION,
                             "hold_p99_fraction_of_period": HOLD_P99_FRACTION,
                             "cannot_overrun_fraction": CANNOT_OVERRUN_FRACTION,
                             "cannot_p99_fraction_of_period": CANNOT_P99_FRACTION}}


def judge(floor: FloorResult, host: HostFacts, duration_s: float, work_s: float) -> RtCheck:
    period = 1.0 / floor.rate_hz
    frac = floor.overruns / floor.ticks if floor.ticks else 1.0
    p99 = floor.lateness.quantile_s(0.99)
    pct = f"{100 * frac:.3f} %"
    stats = (f"{floor.overruns} overruns in {floor.ticks} ticks ({pct}), lateness p99 "
             f"{p99 * 1e3:.3f} ms of a {period * 1e3:.3f} ms period, max "
             f"{floor.lateness.max_s * 1e3:.3f} ms")
    if floor.ticks == 0:
        verdict, reason = CANNOT, "the floor loop ran no tick"
    elif frac > CANNOT_OVERRUN_FRACTION or p99 > CANNOT_P99_FRACTION * period:
        verdict, reason = CANNOT, f"the host alone misses the rate: {stats}"
    elif frac <= HOLD_OVERRUN_FRACTION and p99 <= HOLD_P99_FRACTION * period:
        verdict, reason = HOLDS, f"the host holds the rate: {stats}"
    else:
        verdict, reason = MARGINAL, f"the host holds the rate with misses: {stats}"
    refused = floor.measures.get("refused", [])
    if refused:
        reason += f"; measures refused: {'; '.join(refused)}"
    return RtCheck(verdict, reason, floor, host, duration_s, work_s,
                   advice(host, floor, verdict))


def advice(host: HostFacts, floor: FloorResult, verdict: str) -> list[str]:
    """What to change, most effective first; only what applies to this host."""
    out: list[str] = []
    for r in floor.measures.get("refused", []):
        if r.startswith("SCHED_FIFO"):
            out.append("SCHED_FIFO was refused: allow it (a line '@lab - rtprio 98' in "
                       "/etc/security/limits.conf, or run with CAP_SYS_NICE); without it "
                       "any busy task delays the loop")
        elif r.startswith("mlockall"):
            out.append("memory locking was refused: allow it ('@lab - memlock unlimited' in "
                       "/etc/security/limits.conf, or CAP_IPC_LOCK); page faults then stall "
                       "the loop")
        elif r.startswith("cpu affinity"):
            out.append(f"CPU pinning was refused ({r}): check the cpuset/cgroup of the shell")
    if not host.preempt_rt:
        out.append(f"kernel {host.kernel_release} is not PREEMPT_RT (model: "
                   f"{host.preempt_model}): a PREEMPT_RT kernel (e.g. Debian/Ubuntu "
                   "linux-image-rt) bounds the worst-case lateness")
    if host.hypervisor:
        out.append("this is a virtual machine: the hypervisor schedules its vCPUs, and its "
                   "pauses show up as lateness no guest setting removes (the guest may even "
                   "count them as the running task's CPU time: tools/trace_rig/trace.py "
                   "shows one); use bare metal for the lab's real-time runs")
    slow_gov = sorted({g for g in host.governors.values() if g != "performance"})
    if slow_gov:
        out.append(f"CPU frequency governor {', '.join(slow_gov)}: set 'performance' "
                   "(cpupower frequency-set -g performance) so a tick does not start on a "
                   "slowed-down core")
    if not host.isolated_cpus and len(host.cpus_online) > 1:
        last = host.cpus_online[-1]
        out.append(f"no isolated CPU: boot with isolcpus={last} nohz_full={last} "
                   f"rcu_nocbs={last} and keep the loop there (realtime.cpu: {last})")
    if host.smt_active:
        out.append("SMT is on: the loop's core shares its execution units with a sibling; "
                   "turn it off (echo off > /sys/devices/system/cpu/smt/control)")
    if host.rt_runtime_us is not None and host.rt_runtime_us != -1 and verdict != HOLDS:
        out.append(f"RT throttling is on (kernel.sched_rt_runtime_us = {host.rt_runtime_us}):"
                   " keep it (it saves the machine from a runaway SCHED_FIFO task); the loop "
                   "sleeps most of each period, so it is not what limits it")
    if not host.sched_fifo_allowed and not any(a.startswith("SCHED_FIFO") for a in out):
        out.append(f"RLIMIT_RTPRIO is {host.rtprio_limit}: an unprivileged user cannot have "
                   "SCHED_FIFO; raise it in /etc/security/limits.conf")
    if verdict != HOLDS and len(host.cpus_online) <= 2:
        out.append(f"only {len(host.cpus_online)} CPUs: the loop, the rig process and "
                   "everything else share them; a machine with a spare core for the loop "
                   "helps most")
    return out


def format_report(check: RtCheck) -> str:
    f, h = check.floor, check.host
    lat, work = f.lateness.percentiles_ms(), f.work.percentiles_ms()
    lines = [
        f"harness rt-check: {check.verdict} at {f.rate_hz:g} Hz",
        f"  {check.reason}",
        "",
        f"floor loop ({check.duration_s:g} s, {check.work_s * 1e6:.0f} us of work a tick):",
        f"  ticks {f.ticks}, overruns {f.overruns} ({f.overrun_percent:.3f} %)",
        f"  lateness p50 / p99 / max: {lat['p50']:.3f} / {lat['p99']:.3f} / "
        f"{lat['max']:.3f} ms",
        f"  work p50 / p99 / max:     {work['p50']:.3f} / {work['p99']:.3f} / "
        f"{work['max']:.3f} ms",
        f"  measures granted: {', '.join(f.measures.get('applied', [])) or 'none'}",
    ]
    for r in f.measures.get("refused", []):
        lines.append(f"  REFUSED: {r}")
    gov = ", ".join(f"cpu{c} {g}" for c, g in sorted(h.governors.items())) or "not exposed"
    lines += [
        "",
        "host:",
        f"  kernel {h.kernel_release} ({h.kernel_version}); preemption {h.preempt_model}; "
        f"PREEMPT_RT {'yes' if h.preempt_rt else 'no'}",
        f"  CPUs online {h.cpus_online}; isolated {h.isolated_cpus or 'none'}; nohz_full "
        f"{h.nohz_full_cpus or 'none'}; SMT "
        f"{'n/a' if h.smt_active is None else ('on' if h.smt_active else 'off')}; "
        f"virtual machine {'yes' if h.hypervisor else 'no'}",
        f"  frequency governor: {gov}",
        f"  SCHED_FIFO allowed {'yes' if h.sched_fifo_allowed else 'no'} (RLIMIT_RTPRIO "
        f"{h.rtprio_limit}, root {'yes' if h.privileged else 'no'}); memory locking "
        f"unlimited {'yes' if h.memlock_unlimited else 'no'} (RLIMIT_MEMLOCK "
        f"{h.memlock_limit})",
        f"  RT throttling: sched_rt_runtime_us {h.rt_runtime_us} of sched_rt_period_us "
        f"{h.rt_period_us}",
    ]
    if check.advice:
        lines += ["", "to change:"] + [f"  - {a}" for a in check.advice]
    return "\n".join(lines)
