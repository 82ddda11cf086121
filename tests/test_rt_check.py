"""`harness rt-check`: host facts from a fake /proc and /sys, the verdict, the report, its
JSON, and what it says when a real-time measure is refused."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from harness.cli import main
from harness.realtime.check import CANNOT, HOLDS, MARGINAL, format_report, judge
from harness.realtime.floor import FloorResult
from harness.realtime.host import read_host_facts

LIMITS = """Limit                     Soft Limit           Hard Limit           Units
Max locked memory         65536                65536                bytes
Max realtime priority     0                    0
"""


def fake_root(tmp_path: Path, version: str = "#1 SMP PREEMPT_DYNAMIC", rt: bool = False,
              governor: str = "powersave", isolated: str = "", smt: str = "1",
              hypervisor: bool = False) -> Path:
    files = {
        "proc/sys/kernel/osrelease": "6.1.0-test",
        "proc/sys/kernel/version": version,
        "proc/sys/kernel/sched_rt_runtime_us": "950000",
        "proc/sys/kernel/sched_rt_period_us": "1000000",
        "proc/self/limits": LIMITS,
        "proc/cpuinfo": "flags\t\t: fpu sse2" + (" hypervisor" if hypervisor else "") + "\n",
        "sys/devices/system/cpu/online": "0-3",
        "sys/devices/system/cpu/isolated": isolated,
        "sys/devices/system/cpu/smt/active": smt,
    }
    if rt:
        files["sys/kernel/realtime"] = "1"
    for cpu in range(4):
        files[f"sys/devices/system/cpu/cpu{cpu}/cpufreq/scaling_governor"] = governor
    for rel, text in files.items():
        p = tmp_path / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(text + "\n")
    return tmp_path


def _floor(ticks: int, overruns: int, lateness_s: float, refused=()) -> FloorResult:
    f = FloorResult(500.0, ticks=ticks, overruns=overruns,
                    measures={"requested": [], "applied": [], "refused": list(refused)})
    for _ in range(ticks):
        f.lateness.add(lateness_s)
    return f


def test_host_facts_from_a_fake_root(tmp_path):
    h = read_host_facts(fake_root(tmp_path, hypervisor=True), euid=1000)
    assert h.kernel_release == "6.1.0-test" and not h.preempt_rt
    assert h.preempt_model.startswith("dynamic")
    assert h.cpus_online == [0, 1, 2, 3] and h.isolated_cpus == []
    assert h.governors == {0: "powersave", 1: "powersave", 2: "powersave", 3: "powersave"}
    assert h.smt_active is True and h.hypervisor
    assert h.rt_runtime_us == 950000 and h.rtprio_limit == "0" and h.memlock_limit == "65536"
    assert not h.sched_fifo_allowed and not h.memlock_unlimited
    rt = read_host_facts(fake_root(tmp_path / "rt", version="#1 SMP PREEMPT_RT", rt=True,
                                   governor="performance", isolated="3", smt="0"), euid=0)
    assert rt.preempt_rt and rt.preempt_model == "rt" and rt.isolated_cpus == [3]
    assert rt.sched_fifo_allowed and rt.smt_active is False


def test_verdicts_and_advice(tmp_path):
    bad_host = read_host_facts(fake_root(tmp_path), euid=1000)
    good_host = read_host_facts(fake_root(tmp_path / "g", version="#1 SMP PREEMPT_RT", rt=True,
                                          governor="performance", isolated="3", smt="0"),
                                euid=0)
    assert judge(_floor(30000, 0, 5e-6), good_host, 60, 150e-6).verdict == HOLDS
    assert judge(_floor(30000, 0, 5e-6), good_host, 60, 150e-6).advice == []
    assert judge(_floor(30000, 30, 5e-6), good_host, 60, 150e-6).verdict == MARGINAL
    assert judge(_floor(30000, 0, 0.5e-3), good_host, 60, 150e-6).verdict == MARGINAL
    c = judge(_floor(30000, 600, 5e-6), bad_host, 60, 150e-6)
    assert c.verdict == CANNOT and c.exit_code == 1
    text = " ".join(c.advice)
    for what in ("PREEMPT_RT", "performance", "isolcpus=3", "SMT", "RLIMIT_RTPRIO"):
        assert what in text
    report = format_report(c)
    assert report.startswith("harness rt-check: CANNOT HOLD at 500 Hz")
    assert "600 overruns in 30000 ticks (2.000 %)" in report and "to change:" in report


def test_refused_measure_in_verdict():
    host = read_host_facts()
    c = judge(_floor(1000, 0, 5e-6, refused=["SCHED_FIFO priority 50: [Errno 1] no"]),
              host, 2, 150e-6)
    assert "measures refused: SCHED_FIFO" in c.reason
    assert any(a.startswith("SCHED_FIFO was refused") for a in c.advice)
    assert "REFUSED: SCHED_FIFO priority 50" in format_report(c)


def test_command_report_and_json(capsys):
    code = main(["rt-check", "--duration-s", "0.5"])
    out = capsys.readouterr().out
    assert code in (0, 1, 5)
    assert out.startswith("harness rt-check: ") and "floor loop (0.5 s, 150 us" in out
    assert "ticks 250," in out and "host:" in out and "RT throttling" in out
    code = main(["rt-check", "--duration-s", "0.5", "--json", "--rate-hz", "200"])
    d = json.loads(capsys.readouterr().out)
    assert d["verdict"] in ("HOLDS", "MARGINAL", "CANNOT HOLD")
    assert code == {"HOLDS": 0, "MARGINAL": 5, "CANNOT HOLD": 1}[d["verdict"]]
    assert d["floor"]["ticks"] == 100 and d["rate_hz"] == 200
    assert set(d["floor"]["lateness_ms"]) == {"p50", "p99", "max"}
    assert "preempt_rt" in d["host"] and "sched_fifo_allowed" in d["host"]
    assert os.sched_getscheduler(0) == os.SCHED_OTHER  # restored


def test_command_says_when_a_measure_is_refused(capsys, monkeypatch):
    def refuse(*_a, **_k):
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    main(["rt-check", "--duration-s", "0.3", "--json"])
    captured = capsys.readouterr()
    d = json.loads(captured.out)
    assert d["floor"]["measures"]["refused"][0].startswith("SCHED_FIFO priority 50:")
    assert "measures refused: SCHED_FIFO" in d["reason"]
    assert any("SCHED_FIFO was refused" in a for a in d["advice"])
    assert "WARNING: real-time measure not granted: SCHED_FIFO" in captured.err


@pytest.mark.parametrize("argv", [["--rate-hz", "0"], ["--duration-s", "-1"],
                                  ["--work-us", "3000"], ["--cpu", "99"]])
def test_bad_input_exit_2(argv, capsys):
    assert main(["rt-check", *argv]) == 2
    err = capsys.readouterr().err
    assert "harness rt-check:" in err and argv[0] in err and "Traceback" not in err
