"""The pytest plugin behind ``harness test``: suite files collected as test items.

``harness test`` calls ``pytest.main([...suite files...], plugins=[SuitePlugin(...)])``, so
pytest's own selection (``-k``), stop at the first failure (``-x``), re-run of what failed
last time (``--lf``), JUnit XML (``--junitxml``) and its summary work unchanged. The plugin
is only active when passed this way; the project's own tests never collect it.

- Collection: each suite file given becomes a ``SuiteFile`` whose items are the suite's run
  (variant x matrix point), identify, probe, study and compare tests.
- ``pytest_collection_finish`` (after ``-k`` / ``--lf`` deselection): every case a selected
  item needs is submitted to the engine (``harness.engine``) at once, so the runs proceed in
  parallel while pytest walks the items in order; each item waits for its own case. A line
  per finished test (verdict, time, reason, N/M done) goes to stderr as cases finish.
- Real rig (a bus that is not the in-process virtual one): the pre-flight probe runs first
  and, if it fails, nothing is armed: every item errors with the probe's reason. Tests that
  need the virtual rig (fault injection) are skipped with the reason. The engine is inline,
  one test at a time (the bus is one rig).
- The verdict of an item maps to pytest: PASS and MARGINAL pass (MARGINAL is in the report,
  the JUnit properties and the exit code), and so does NO CRITERIA in a suite with
  ``require_criteria: false`` (otherwise the job made it FAIL: ``outcome.require_criteria``);
  FAIL fails with the failed criterion as the
  message, ERROR errors (JUnit ``<error>``). INCONCLUSIVE (the bench did not hold real time)
  is skipped with its reason (JUnit ``<skipped message="INCONCLUSIVE: ...">``): CI readers
  show a skipped test as neither passed nor failed, with the message, which is what an
  inconclusive test is; ``<error>`` would read as a broken test. The exit code (6) still
  makes the job fail.
- ``pytest_sessionfinish``: stops the engine (``-x``, Ctrl-C: running runs end at their next
  tick with the rig safe), then writes results.json, report.md and report.html in the
  suite's output folder.
"""

from __future__ import annotations

import sys
import threading
import time
from collections.abc import Callable, Iterator
from concurrent.futures import CancelledError
from pathlib import Path
from typing import Any

import pytest

from harness.core.paths import safe_child
from harness.engine import Engine
from harness.testing.checks import combine, judge_compare
from harness.testing.outcome import EXIT_ORDER, exit_code, item_result  # noqa: F401 - re-exported
from harness.testing.report import write_reports
from harness.testing.suite import Case, Compare, Suite
from harness.testing.work import probe_verdict, run_case, run_probe


class SuiteFailure(Exception):
    """A test's verdict is FAIL."""


class SuiteError(Exception):
    """A test's verdict is ERROR (or it could not run)."""


class SuitePlugin:
    def __init__(self, suites: list[Suite], out_dir: Path,
                 engine_factory: Callable[[], Engine], bus: str | None = None,
                 real_bus: bool = False, progress: bool = True,
                 clock: str | None = None) -> None:
        self.suites = {s.source.resolve(): s for s in suites}
        self.out_dir = out_dir
        self.engine_factory = engine_factory
        self.engine: Engine | None = None
        self.bus = bus
        self.real_bus = real_bus
        self.clock = clock  # "lockstep" on a bus: a virtual rig process in lockstep
        self.show_progress = progress
        self.refused: str | None = None
        self.preflight: dict[str, Any] | None = None
        self.cases: dict[str, Case] = {}
        self.futures: dict[str, Any] = {}
        self.outputs: dict[str, dict[str, Any]] = {}  # case key -> run_case output
        self.records: list[dict[str, Any]] = []  # one per reported item, in report order
        self.junit_rigs: set[tuple[Any, Any]] = set()  # rigs named in the JUnit testsuite
        self.selected: list[pytest.Item] = []
        self.total = 0
        self.done = 0
        self.engine_name = ""
        self._lock = threading.Lock()
        self.t0 = time.perf_counter()

    # --- collection -------------------------------------------------------------------
    def pytest_configure(self, config: pytest.Config) -> None:
        config.addinivalue_line("markers", "virtual_only: injects faults in the virtual rig")

    def pytest_collect_file(self, file_path: Path, parent: pytest.Collector
                            ) -> pytest.Collector | None:
        suite = self.suites.get(Path(file_path).resolve())
        if suite is None:
            return None
        return SuiteFile.from_parent(parent, path=Path(file_path), suite=suite, plugin=self)

    def pytest_collection_finish(self, session: pytest.Session) -> None:
        items = [i for i in session.items if isinstance(i, SuiteItem)]
        self.selected = items
        self.total = len(items)
        if session.config.option.collectonly or not items:
            return
        needed: dict[str, Case] = {}
        for item in items:
            for case in item.cases():
                needed.setdefault(self.key(case), case)
        if self.real_bus:
            self._preflight()
            if self.refused:
                return
        self.engine = self.engine_factory()
        self.engine_name = self.engine.name
        self._say(f"{len(items)} tests ({len(needed)} jobs) on {self.engine.name}"
                  + (f", bus {self.bus}" if self.bus else ""))
        for key, case in needed.items():
            if self.real_bus and case.virtual_only:
                continue
            if self.real_bus and case.kind == "probe" and self.preflight is not None:
                # on a real bus the pre-flight is the suite's probe: judged, not repeated
                self.cases[key] = case
                self.futures[key] = self.engine.submit(_preflight_case, case,
                                                       self.preflight)
                self.futures[key].add_done_callback(lambda f, k=key: self._finished(k, f))
                continue
            self.cases[key] = case
            fut = self.engine.submit(run_case, case, str(self.out_dir),
                                     self.engine.ships_files, self.bus, self.clock)
            self.futures[key] = fut
            fut.add_done_callback(lambda f, k=key: self._finished(k, f))

    def _preflight(self) -> None:
        """The probe before anything is armed, with the first probe test's settings."""
        opts = next((c.probe for s in self.suites.values() for c in s.cases
                     if c.kind == "probe"), {})
        self._say(f"pre-flight probe on {self.bus} (never arms) ...")
        try:
            self.preflight = run_probe(opts, self.bus, clock=self.clock)
            v = probe_verdict(self.preflight)
        except Exception as exc:  # noqa: BLE001 - a bus that does not open refuses too
            v = item_result("ERROR", f"{type(exc).__name__}: {exc}")
        if v["verdict"] != "PASS":
            self.refused = (f"pre-flight probe on {self.bus} failed, nothing armed: "
                            f"{v['reason']}")
            self._say(self.refused)
        else:
            self._say(f"pre-flight probe OK: {v['reason']}")

    @staticmethod
    def key(case: Case) -> str:
        return f"{case.suite}::{case.id}"

    @pytest.hookimpl(wrapper=True)
    def pytest_runtest_makereport(self, item: pytest.Item, call: pytest.CallInfo[None]
                                  ) -> Any:
        """A test's verdict as its failure text (setup errors too), not a traceback."""
        report = yield
        if isinstance(item, SuiteItem) and call.excinfo is not None and isinstance(
                call.excinfo.value, SuiteFailure | SuiteError):
            report.longrepr = item._describe()
        if isinstance(item, SuiteItem) and call.when == "setup":
            # the job ran in the engine while pytest walked other items: a test whose job
            # had finished by the time its item came up took no time here (JUnit time
            # 0.000 for identify and fault tests); its time is the job's (setup is where
            # an item waits for it, and the phase every item has)
            out = self.outputs.get(item.case_key) if item.case is not None else None
            wall = out.get("wall_s") if out else None
            if isinstance(wall, int | float):
                report.duration = max(report.duration, float(wall))
        return report

    @pytest.hookimpl(tryfirst=True)
    def pytest_report_teststatus(self, report: pytest.TestReport, config: pytest.Config
                                 ) -> tuple[str, str, str] | None:
        """No progress dots while the plugin prints a line per test: on one terminal the
        two ran into each other."""
        if not self.show_progress or config.option.verbose > 0 or report.when == "collect":
            return None
        if report.when == "call" or report.failed or report.skipped:
            outcome = report.outcome
            if report.when != "call" and report.failed:
                outcome = "error"
            return outcome, "", outcome.upper()
        return None

    # --- results ----------------------------------------------------------------------
    def _finished(self, key: str, fut: Any) -> None:
        """Done callback (any thread): one progress line per item of the case."""
        try:
            out = fut.result()
        except BaseException:  # noqa: BLE001 - reported when the item asks for it
            return
        case = self.cases[key]
        wanted = {i.name for i in self.selected if i.case_key == key and i.item_kind != "cmp"}
        for name, res in out["items"].items():
            if name in wanted:
                self._count(f"{res['verdict']:<8} {case.suite}::{name} ({out['wall_s']:.1f} s):"
                            f" {res['reason']}")

    def _count(self, line: str) -> None:
        with self._lock:
            self.done += 1
            self._say(f"[{self.done}/{self.total}] {line}")

    def _say(self, line: str) -> None:
        if self.show_progress:
            print(f"harness test: {line}", file=sys.stderr, flush=True)

    def output(self, key: str) -> dict[str, Any]:
        """The case's output, waiting for it; files shipped back are written here once."""
        if key in self.outputs:
            return self.outputs[key]
        case = self.cases.get(key)
        fut = self.futures.get(key)
        if fut is None or case is None:
            raise SuiteError(self.refused or f"{key}: not run")
        try:
            out = fut.result()
        except CancelledError:
            out = {"items": {}, "cancelled": True}
        except Exception as exc:  # noqa: BLE001 - a worker that died, a lost connection
            out = {"items": {}, "worker_error": f"{type(exc).__name__}: {exc}"}
        reason = out.get("worker_error") or ("cancelled" if out.get("cancelled") else None)
        if reason:
            out = {"case": case.id, "kind": case.kind, "worker": None, "run_dir": None,
                   "summary": None, "wall_s": None, "files": {},
                   "items": {n: item_result("ERROR", f"job lost: {reason}")
                             for n in case.item_names}}
        for rel, data in out.pop("files", {}).items():
            run_dir, _, name = rel.partition("/")
            target = safe_child(self.out_dir, run_dir, name)
            target.parent.mkdir(parents=True, exist_ok=True)
            target.write_bytes(data)
        self.outputs[key] = out
        return out

    def record(self, item: SuiteItem, res: dict[str, Any], out: dict[str, Any] | None) -> None:
        case = item.case
        rec = {
            "suite": item.suite.name, "test": case.test if case else item.name,
            "item": item.name, "nodeid": item.nodeid, "kind": item.item_kind,
            "description": case.description if case else "",
            "variant": case.variant if case else None,
            "point": case.point if case else {},
            "verdict": res["verdict"], "reason": res["reason"],
            "reported": res.get("reported", True),
            "criteria": res.get("criteria", []), "exit_code": res.get("exit_code"),
            "wall_s": out.get("wall_s") if out else None,
            "worker": out.get("worker") if out else None,
            "run_dir": out.get("run_dir") if out else None,
        }
        rig = rig_of(res, out)
        if rig is not None:
            rec["rig"] = rig
        if "modes" in res:
            rec["modes"] = res["modes"]
        if "document" in res and item.item_kind in ("probe", "study"):
            rec["document"] = res["document"]
        if out and out.get("summary") and item.item_kind == "run":
            s = out["summary"]
            rec["summary"] = {k: s.get(k) for k in (
                "stopped_by", "final_angle_error_deg", "settle_time_s",
                "residual_tip_accel_m_s2", "steady_tip_accel_amplitude_m_s2",
                "real_time_factor", "faults", "injected_faults") if k in s}
        with self._lock:
            self.records.append(rec)

    # --- end --------------------------------------------------------------------------
    def pytest_sessionfinish(self, session: pytest.Session, exitstatus: int) -> None:
        if self.engine is not None:
            if any(not f.done() for f in self.futures.values()):
                self.engine.stop()
            self.engine.close()
        if session.config.option.collectonly or not self.selected:
            return
        reported = {r["nodeid"] for r in self.records}
        not_run = [i.nodeid for i in self.selected if i.nodeid not in reported]
        for item in self.selected:  # stopped early (-x, Ctrl-C): what finished anyway
            if item.nodeid in reported or item.case is None:
                continue
            fut = self.futures.get(item.case_key)
            if fut is None or not fut.done() or fut.cancelled():
                continue
            out = self.output(item.case_key)
            res = out["items"].get(item.name)
            if res is not None:
                self.record(item, {**res, "reported": False}, out)
        write_reports(self.out_dir, self.records, not_run=not_run, suites=list(
            self.suites.values()), engine=self.engine_name, bus=self.bus,
            preflight=self.preflight, refused=self.refused,
            wall_s=time.perf_counter() - self.t0,
            interrupted=exitstatus == pytest.ExitCode.INTERRUPTED)


def rig_of(res: dict[str, Any], out: dict[str, Any] | None) -> dict[str, Any] | None:
    """The rig identity of a test's result (``rig_models.rig_file.rig_identity``): its
    run's summary.json, or its probe's document."""
    for doc in ((out or {}).get("summary"), res.get("document")):
        if isinstance(doc, dict) and doc.get("rig_sha256"):
            return {k: doc.get(k) for k in ("rig", "rig_sha256", "bus", "binding")}
    return None


def _preflight_case(case: Case, report: dict[str, Any]) -> dict[str, Any]:
    """A probe test on a real bus: the pre-flight's report, judged with the test's checks."""
    from harness.testing.checks import judge_checks
    from harness.testing.work import _with_checks, current_worker

    res = _with_checks(probe_verdict(report), judge_checks(case.checks, report))
    return {"case": case.id, "kind": "probe", "worker": current_worker(), "run_dir": None,
            "summary": None, "wall_s": 0.0, "files": {},
            "items": {case.id: {**res, "document": report,
                                "reason": f"pre-flight: {res['reason']}"}}}


class SuiteFile(pytest.File):
    def __init__(self, *, suite: Suite, plugin: SuitePlugin, **kw: Any) -> None:
        super().__init__(**kw)
        self.suite = suite
        self.plugin = plugin

    def collect(self) -> Iterator[pytest.Item]:
        compares = {c.test: c for c in self.suite.compares}
        for case in self.suite.cases:
            yield self._item(case.id, case=case, item_kind=case.kind)
            if case.identify is not None:
                yield self._item(f"identify[{case.id}]", case=case, item_kind="identify")
            cmp = compares.get(case.test)
            if cmp is not None and case.id == cmp.cases[-1]:
                yield self._item(cmp.id, case=None, compare=cmp, item_kind="cmp")

    def _item(self, name: str, **kw: Any) -> SuiteItem:
        # pytest 9 reads the ids saved for --lf back with NodeId.parse, which splits
        # "case-a[beta-1.0]" into a name and parameters; an id built by NodeId.child keeps
        # the brackets in the name, so the two never match and --lf re-ran everything. An
        # id made by the same parse matches (and prints the same).
        return SuiteItem.from_parent(self, name=name, nodeid=_parse_nodeid(
            f"{self.nodeid}::{name}"), **kw)


def _parse_nodeid(nodeid: str) -> Any:
    try:
        from _pytest.nodeid import NodeId
    except ImportError:  # pytest < 9 keeps string ids: nothing to match
        return nodeid
    return NodeId.parse(nodeid)


class SuiteItem(pytest.Item):
    def __init__(self, *, case: Case | None, item_kind: str, compare: Compare | None = None,
                 **kw: Any) -> None:
        super().__init__(**kw)
        self.case = case
        self.compare = compare
        self.item_kind = item_kind
        self.result: dict[str, Any] | None = None
        self.rig: dict[str, Any] | None = None  # its result's rig (rig_of), once set up
        self.case_key = SuitePlugin.key(case) if case else ""
        if case is not None and case.virtual_only:
            self.add_marker("virtual_only")

    @property
    def suite(self) -> Suite:
        return self.parent.suite  # type: ignore[attr-defined]

    @property
    def plugin(self) -> SuitePlugin:
        return self.parent.plugin  # type: ignore[attr-defined]

    def cases(self) -> list[Case]:
        if self.case is not None:
            return [self.case]
        assert self.compare is not None
        by_id = {c.id: c for c in self.suite.cases}
        return [by_id[c] for c in self.compare.cases]

    def setup(self) -> None:
        plugin = self.plugin
        if plugin.refused:
            res = item_result("ERROR", plugin.refused, exit_code=2)
            self.result = res
            plugin.record(self, res, None)
            plugin._count(f"ERROR    {self.suite.name}::{self.name}: refused")
            raise SuiteError(plugin.refused)
        if plugin.real_bus and any(c.virtual_only for c in self.cases()):
            res = item_result("PASS", "skipped: injects faults, needs the virtual rig",
                              skipped=True)
            plugin.record(self, {**res, "verdict": "SKIPPED"}, None)
            plugin._count(f"SKIPPED  {self.suite.name}::{self.name}: needs the virtual rig")
            pytest.skip("injects faults in the virtual rig; not on a real bus "
                        f"({plugin.bus})")
        if self.compare is not None:
            res, out = self._judge_compare(), None
        else:
            assert self.case is not None
            out = plugin.output(self.case_key)
            res = out["items"].get(self.name) or item_result(
                "ERROR", "no result for this test (its job ended early)")
        self.result = res
        plugin.record(self, res, out)
        self.rig = rig_of(res, out)
        self._suite_rig_property()
        if self.compare is not None:
            plugin._count(f"{res['verdict']:<8} {self.suite.name}::{self.name}: {res['reason']}")
        if res["verdict"] == "ERROR":
            raise SuiteError(res["reason"])

    def _judge_compare(self) -> dict[str, Any]:
        assert self.compare is not None
        docs: dict[str, Any] = {}
        for case in self.cases():
            out = self.plugin.output(SuitePlugin.key(case))
            if out.get("summary") is None:
                main = out["items"].get(case.id, {})
                return item_result("ERROR", f"{case.id} has no summary: "
                                   f"{main.get('reason', 'not run')}")
            docs[case.id] = out["summary"]
        crit = [judge_compare(r, docs) for r in self.compare.rules]
        verdict, reason = combine(crit)
        return item_result(verdict, reason, crit)

    def _rig_properties(self) -> list[tuple[str, str]]:
        """The rig of this test's result as JUnit properties (none without a rig)."""
        rig = self.rig
        if rig is None:
            return []
        from rig_models.rig_file import binding_text

        return [("rig", str(rig.get("rig"))), ("rig_sha256", str(rig.get("rig_sha256"))),
                ("bus", str(rig.get("bus"))), ("binding", binding_text(rig.get("binding")))]

    def _suite_rig_property(self) -> None:
        """The rig in the JUnit testsuite's properties, once per rig (a suite run on one
        rig names it once); not its bus: a suite's virtual runs each have their own."""
        from _pytest.junitxml import xml_key

        xml = self.config.stash.get(xml_key, None)
        if xml is None or self.rig is None:
            return
        key = (self.rig.get("rig"), self.rig.get("rig_sha256"))
        if key not in self.plugin.junit_rigs:
            self.plugin.junit_rigs.add(key)
            for name, value in self._rig_properties():
                if name != "bus":
                    xml.add_global_property(name, value)

    def runtest(self) -> None:
        res = self.result
        assert res is not None
        self.user_properties.append(("verdict", res["verdict"]))
        self.user_properties.extend(self._rig_properties())  # after the verdict, the first
        # a sequence's steps, each with its outcome and why (JUnit readers list properties
        # of passed tests too; a failure's text lists them again)
        self.user_properties.extend(
            (c["name"], f"{c.get('verdict')}: {c.get('message', '')}")
            for c in res.get("criteria", []) if c.get("kind") == "step")
        if res["verdict"] == "FAIL":
            raise SuiteFailure(res["reason"])
        if res["verdict"] == "INCONCLUSIVE":
            pytest.skip(f"INCONCLUSIVE: {res['reason']}")

    def repr_failure(self, excinfo: pytest.ExceptionInfo[BaseException],
                     style: Any = None) -> str:
        if isinstance(excinfo.value, SuiteFailure | SuiteError):
            return self._describe()
        return str(super().repr_failure(excinfo))

    def _describe(self) -> str:
        res = self.result or {"verdict": "ERROR", "reason": self.plugin.refused or "?",
                              "criteria": []}
        lines = [f"{res['verdict']}: {res['reason']}"]
        for c in res.get("criteria", []):
            if c.get("verdict") not in ("PASS", None):
                lines.append(f"  {c['verdict']} {c['name']}: {c.get('message', '')}")
        for c in res.get("criteria", []):
            if c.get("verdict") == "PASS":
                lines.append(f"  PASS {c['name']}: {c.get('message', '')}")
        if res.get("traceback"):
            lines.append(res["traceback"])
        return "\n".join(lines)

    def reportinfo(self) -> tuple[Path, int | None, str]:
        return self.path, None, f"{self.suite.name}::{self.name}"
