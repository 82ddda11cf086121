"""The virtual rig as its own process for a real-time run (``harness run --rig-process``).

In a real-time run with the rig in-process, the rig is a thread of the harness's own Python
process and shares its interpreter lock: the loop and the physics take turns, which costs
the loop timing margin that the lab rig (separate devices) would not take. With
``--rig-process`` the run starts ``harness virtual-rig --serve-socketcand 0`` (a socketcand
server on 127.0.0.1, an OS-chosen port) with the run's resolved rig written beside the
recording, connects to it over python-can's ``socketcand`` interface, and stops it (SIGTERM,
then SIGKILL) when the run ends, on every exit path. Should the harness itself be killed, the
rig process ends within a second: it holds the read end of a pipe whose write end only the
harness holds (``--parent-fd``), and the pipe's end of file (the harness gone, however it
ended) stops it as SIGTERM would, the rig left safe. It also exits on its own a minute after
the run's planned end, as a backstop. The rig's stderr goes to ``rig.log`` in
the run directory.
"""

from __future__ import annotations

import contextlib
import json
import os
import queue
import re
import secrets
import signal
import subprocess
import sys
import threading
from pathlib import Path
from types import TracebackType
from typing import IO

import can
import yaml

from rig_models.faults import FaultSpec
from rig_models.rig_file import RigConfig

READY = re.compile(r" on (socketcand:127\.0\.0\.1:\d+|unix:\S+) ")
START_TIMEOUT_S = 60.0
TIMING_PREFIX = "harness virtual-rig: timing "
"""The line (then JSON) the rig process writes on stderr at exit with its SYNC timing
(``SyncTiming``) and the real-time measures it took; ``RigProcess`` reads it back from
rig.log."""


class RigProcessError(RuntimeError):
    pass


class RigProcessExited(can.CanOperationError):
    """The rig process ended during the run: the bus to it failed because its other end is
    gone. The message names the process and how it ended (``RigProcess.exited``)."""


EXIT_WAIT_S = 1.0
"""After the bus to the rig process failed, how long ``RigProcess.exited`` may wait for
the process to be seen ended (its socket closes while it exits, a moment before it can be
reaped)."""


def fault_argument(f: FaultSpec) -> str:
    """The ``--fault`` text of a fault (``KIND@AT_S[+DURATION_S][:DEVICE][=VALUE]``)."""
    text = f"{f.kind}@{f.at_s!r}"
    if f.duration_s > 0:
        text += f"+{f.duration_s!r}"
    if f.device:
        text += f":{f.device}"
    if f.value is not None:
        text += f"={f.value!r}"
    return text


class RigProcess:
    """Context manager: start the rig process, yield its bus spec, stop it."""

    def __init__(self, rig: RigConfig, rate_hz: float, run_dir: Path,
                 faults: list[FaultSpec] | None = None, lifetime_s: float = 0.0,
                 transport: str = "tcp", cpu: int | None = None, priority: int = 0,
                 realtime: bool = False) -> None:
        """``transport`` "tcp" (socketcand on 127.0.0.1) or "unix" (``harness.bus.unix``);
        ``cpu`` pins the rig process, ``priority`` > 0 asks SCHED_FIFO for it (both set
        from here once it runs; what was granted or refused is in ``measures``);
        ``realtime`` makes the process lock its memory and run its collector in the slack
        (``harness virtual-rig --realtime``). After the stop, ``timing`` holds how promptly
        it answered each SYNC (``rig_models.virtual_rig.SyncTiming``), when it said."""
        if transport not in ("tcp", "unix"):
            raise RigProcessError(f"rig process transport {transport!r}: expected tcp or unix")
        self.transport = transport
        self.cpu = cpu
        self.priority = priority
        self.measures: dict[str, list[str]] = {"requested": [], "applied": [], "refused": []}
        self.rig_file = run_dir / "rig.yaml"
        self.log_path = run_dir / "rig.log"
        self.rate_hz = rate_hz
        self.lifetime_s = lifetime_s
        self.fault_args = [a for f in faults or [] for a in ("--fault", fault_argument(f))]
        self.realtime = realtime
        self.timing: dict | None = None
        self.rig_file.write_text(yaml.safe_dump(rig.data, sort_keys=False))
        self.proc: subprocess.Popen[str] | None = None
        self._log: IO[str] | None = None
        self._pump: threading.Thread | None = None
        self._lifeline: int | None = None

    def __enter__(self) -> str:
        serve = (["--serve-socketcand", "0"] if self.transport == "tcp" else
                 ["--serve-unix", f"{os.getpid()}-{secrets.token_hex(4)}"])
        cmd = [sys.executable, "-m", "harness", "virtual-rig", "--rig", str(self.rig_file),
               *serve, "--rate-hz", f"{self.rate_hz:g}", *self.fault_args]
        if self.realtime:
            cmd.append("--realtime")
        if self.lifetime_s > 0:  # if the harness is killed, the rig still exits by itself
            cmd += ["--duration-s", f"{self.lifetime_s:g}"]
        self._log = self.log_path.open("w")
        # the child watches the read end; the write end (not inherited by any child) closes
        # when this process ends, however it ends
        watch, self._lifeline = os.pipe()
        cmd += ["--parent-fd", str(watch)]
        try:
            self.proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL,
                                         stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                                         text=True, start_new_session=True, pass_fds=(watch,))
        except BaseException:
            os.close(self._lifeline)
            self._lifeline = None
            raise
        finally:
            os.close(watch)
        lines: queue.Queue[str | None] = queue.Queue()
        self._pump = threading.Thread(target=self._copy_stderr, args=(lines,), daemon=True)
        self._pump.start()
        try:
            while True:
                line = lines.get(timeout=START_TIMEOUT_S)
                if line is None:
                    raise RigProcessError(
                        f"the virtual rig process exited ({self.proc.wait()}) before serving; "
                        f"see {self.log_path}")
                m = READY.search(line)
                if m:
                    self._apply_measures()
                    return m.group(1)
        except queue.Empty:
            self._stop()
            raise RigProcessError(f"the virtual rig process did not start within "
                                  f"{START_TIMEOUT_S:g} s; see {self.log_path}") from None
        except BaseException:
            self._stop()
            raise

    def _apply_measures(self) -> None:
        assert self.proc is not None
        pid = self.proc.pid
        tasks = [pid]
        with contextlib.suppress(OSError):  # every thread of the rig process
            tasks = [int(t) for t in os.listdir(f"/proc/{pid}/task")]
        if self.cpu is not None:
            self.measures["requested"].append(f"rig process cpu affinity {self.cpu}")
            try:
                for task in tasks:
                    os.sched_setaffinity(task, {self.cpu})
                self.measures["applied"].append(f"rig process cpu affinity {self.cpu}")
            except OSError as exc:
                self.measures["refused"].append(f"rig process cpu affinity {self.cpu}: {exc}")
        if self.priority > 0:
            self.measures["requested"].append(f"rig process SCHED_FIFO priority "
                                              f"{self.priority}")
            try:  # the rig's main thread (the one serving the bus)
                os.sched_setscheduler(pid, os.SCHED_FIFO, os.sched_param(self.priority))
                self.measures["applied"].append(f"rig process SCHED_FIFO priority "
                                                f"{self.priority}")
            except OSError as exc:
                self.measures["refused"].append(f"rig process SCHED_FIFO priority "
                                                f"{self.priority}: {exc}")
        for line in self.measures["refused"]:
            print(f"harness: WARNING: real-time measure not granted: {line}", file=sys.stderr)

    def _copy_stderr(self, lines: queue.Queue[str | None]) -> None:
        assert self.proc is not None and self.proc.stderr is not None and self._log is not None
        for line in self.proc.stderr:
            self._log.write(line)
            self._log.flush()
            lines.put(line)
        lines.put(None)

    def stop(self) -> None:
        """Stop the process (SIGTERM, then SIGKILL) and read what it said of its timing
        and of its own measures (a refused one is added to ``measures``). Idempotent."""
        self._stop()

    def exited(self, wait_s: float = 0.0) -> str | None:
        """How the process ended, when it has (waited for at most ``wait_s``): "the virtual
        rig process (pid N) exited (killed by SIGKILL, exit code -9)"; None while it runs."""
        if self.proc is None:
            return None
        try:
            code = self.proc.wait(timeout=wait_s) if wait_s > 0 else self.proc.poll()
        except subprocess.TimeoutExpired:
            return None
        if code is None:
            return None
        how = f"exit code {code}"
        if code < 0:
            try:
                how = f"killed by {signal.Signals(-code).name}, {how}"
            except ValueError:
                how = f"killed by signal {-code}, {how}"
        return f"the virtual rig process (pid {self.proc.pid}) exited ({how})"

    def _read_timing(self) -> None:
        with contextlib.suppress(OSError):
            for line in self.log_path.read_text().splitlines():
                if line.startswith(TIMING_PREFIX):
                    with contextlib.suppress(ValueError):
                        self.timing = json.loads(line[len(TIMING_PREFIX):])
        own = (self.timing or {}).get("measures") or {}
        for key in ("requested", "applied", "refused"):
            self.measures[key] += [f"rig process {m}" for m in own.get(key, [])]

    def _stop(self) -> None:
        if self.proc is None:
            return
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            # a stopped process (SIGSTOP) takes its SIGTERM only once it runs again
            with contextlib.suppress(ProcessLookupError):
                self.proc.send_signal(signal.SIGCONT)
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        if self._lifeline is not None:
            os.close(self._lifeline)
            self._lifeline = None
        if self._pump is not None:
            self._pump.join(timeout=5)
        if self._log is not None:
            self._log.close()
            self._log = None
            self._read_timing()

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self._stop()
