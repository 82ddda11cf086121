"""Host facts that decide real time, read from /proc and /sys under ``root`` (pure reads)."""

from __future__ import annotations

import os
import re
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any


def _read(root: Path, rel: str) -> str | None:
    try:
        return (root / rel.lstrip("/")).read_text().strip()
    except OSError:
        return None


def _cpu_list(text: str | None) -> list[int]:
    """``0-2,5`` -> [0, 1, 2, 5]; empty or missing -> []."""
    out: list[int] = []
    for part in (text or "").split(","):
        part = part.strip()
        if not part:
            continue
        a, _, b = part.partition("-")
        out.extend(range(int(a), int(b or a) + 1))
    return out


def _limit(limits: str | None, name: str) -> tuple[str, str] | None:
    """(soft, hard) of a line of /proc/<pid>/limits."""
    for line in (limits or "").splitlines():
        if line.startswith(name):
            parts = re.split(r"\s{2,}", line.strip())
            if len(parts) >= 3:
                return parts[1], parts[2]
    return None


@dataclass
class HostFacts:
    kernel_release: str = ""
    kernel_version: str = ""
    preempt_model: str = "unknown"  # none / voluntary / full / rt / dynamic(...) / unknown
    preempt_rt: bool = False
    cpus_online: list[int] = field(default_factory=list)
    governors: dict[int, str] = field(default_factory=dict)  # cpu -> governor (absent: {})
    isolated_cpus: list[int] = field(default_factory=list)
    nohz_full_cpus: list[int] = field(default_factory=list)
    smt_active: bool | None = None
    hypervisor: bool = False
    rt_runtime_us: int | None = None
    rt_period_us: int | None = None
    rtprio_limit: str | None = None  # soft limit of RLIMIT_RTPRIO ("0", "99", "unlimited")
    memlock_limit: str | None = None  # soft limit of RLIMIT_MEMLOCK in bytes or "unlimited"
    privileged: bool = False  # euid 0 (CAP_SYS_NICE and CAP_IPC_LOCK)

    @property
    def sched_fifo_allowed(self) -> bool:
        return self.privileged or (self.rtprio_limit not in (None, "0"))

    @property
    def memlock_unlimited(self) -> bool:
        return self.privileged or self.memlock_limit == "unlimited"

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["governors"] = {str(k): v for k, v in self.governors.items()}
        d["sched_fifo_allowed"] = self.sched_fifo_allowed
        d["memlock_unlimited"] = self.memlock_unlimited
        return d


def read_host_facts(root: Path = Path("/"), euid: int | None = None) -> HostFacts:
    f = HostFacts()
    f.kernel_release = _read(root, "proc/sys/kernel/osrelease") or ""
    f.kernel_version = _read(root, "proc/sys/kernel/version") or ""
    realtime = _read(root, "sys/kernel/realtime")
    f.preempt_rt = realtime == "1" or "PREEMPT_RT" in f.kernel_version
    # the model in force: debugfs (needs root and debugfs) shows "none voluntary (full) ..."
    dyn = _read(root, "sys/kernel/debug/sched/preempt")
    if f.preempt_rt:
        f.preempt_model = "rt"
    elif dyn and (m := re.search(r"\((\w+)\)", dyn)):
        f.preempt_model = m.group(1)
    elif "PREEMPT_DYNAMIC" in f.kernel_version:
        f.preempt_model = "dynamic (model not readable without debugfs)"
    elif re.search(r"\bPREEMPT\b", f.kernel_version):
        f.preempt_model = "full"
    elif f.kernel_version:
        f.preempt_model = "none or voluntary"
    f.cpus_online = _cpu_list(_read(root, "sys/devices/system/cpu/online"))
    for cpu in f.cpus_online:
        gov = _read(root, f"sys/devices/system/cpu/cpu{cpu}/cpufreq/scaling_governor")
        if gov:
            f.governors[cpu] = gov
    f.isolated_cpus = _cpu_list(_read(root, "sys/devices/system/cpu/isolated"))
    f.nohz_full_cpus = _cpu_list(_read(root, "sys/devices/system/cpu/nohz_full"))
    smt = _read(root, "sys/devices/system/cpu/smt/active")
    f.smt_active = None if smt is None else smt == "1"
    cpuinfo = _read(root, "proc/cpuinfo") or ""
    f.hypervisor = bool(re.search(r"^flags\s*:.*\bhypervisor\b", cpuinfo, re.M))
    rt = _read(root, "proc/sys/kernel/sched_rt_runtime_us")
    f.rt_runtime_us = int(rt) if rt and rt.lstrip("-").isdigit() else None
    rp = _read(root, "proc/sys/kernel/sched_rt_period_us")
    f.rt_period_us = int(rp) if rp and rp.isdigit() else None
    limits = _read(root, "proc/self/limits")
    rtprio = _limit(limits, "Max realtime priority")
    memlock = _limit(limits, "Max locked memory")
    f.rtprio_limit = rtprio[0] if rtprio else None
    f.memlock_limit = memlock[0] if memlock else None
    f.privileged = (os.geteuid() if euid is None else euid) == 0
    return f
