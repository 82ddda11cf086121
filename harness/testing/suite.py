"""Suite files: many runs (their variants and a parameter matrix), probes, identifications
and studies as tests, each with criteria.

A suite is a YAML file (built-ins in ``harness/suites/``, ``harness test --list``)::

    name: acceptance
    description: the lab's daily check of the rig
    tests:
      - probe: {duration_s: 1}               # every device answers (never arms); on a real
                                         # bus the first probe test sets the pre-flight's
                                         # rate_hz, duration_s, settle_s, receive_timeout_ms
      - run: slew-rw                         # a run file: built-in name or path
        expect: ...                          # extra criteria, added to the run file's expect
        own_expect: true                     # false: only this test's expect (a fault test
                                             # built on a run whose criteria no longer apply)
      - run: case-a
        variants: [beta-0.6, beta-1.0]       # default: every variant of the run file
        matrix: {controller.torque_fraction: [0.6, 0.8]}   # cartesian product of overrides
        set: {duration_s: 40}                # overrides deep-merged into the run file
        compare:                             # across the variants / matrix points of this test
          - {measure: steady_tip_accel_amplitude_m_s2, largest: beta-1.0}
      - run: free-decay
        identify:                            # identify the run's modes, then check the JSON
          check: [{field: "modes[*].omega_error_percent", max_abs: 0.5, unit: "%"}]
      - run: slew-rw
        name: fault-hub-silent
        faults: [{kind: silent_sensor, at_s: 3, device: hub_sensor}]   # virtual rig only
      - study: hu2006                        # ``harness study hu2006 --json``
        args: []
        check: [{field: "...", max: 1.0}]

Each test expands to one or more *cases* (one per variant x matrix point; a case is one job
for the engine) and each case to one or more pytest items: the run itself
(``slew-rw``, ``case-a[beta-1.0]``), its identification (``identify[free-decay]``); a
``compare`` adds one item per test (``compare[case-a]``). Test names must be unique in a
suite.

``check:`` criteria apply to a JSON document (summary.json for a run, the probe report,
``identify --json``, ``study NAME --json``): ``field`` is a path (``a.b[0].c``, ``[*]`` for
every element; keys may contain dots: the longest key that matches wins), with one or more
of ``min``, ``max``, ``max_abs``, ``equals``, ``len_min``, ``len_max``, and optional
``name`` and ``unit``.

Everything is checked when the suite is loaded, before anything runs: an error names the
suite file, the key path and what was expected (``acceptance.yaml: tests[2].matrix: expected
a mapping KEY.PATH: [values]``), and every run file is loaded with its overrides.
"""

from __future__ import annotations

import copy
import itertools
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from harness.paths import safe_name
from harness.runs import _deep_merge, load_run, run_path
from rig_models.schema import ConfigError

SUITES_DIR = Path(__file__).resolve().parent.parent / "suites"
CHECK_RULES = ("min", "max", "max_abs", "equals", "len_min", "len_max")
TEST_KEYS = {
    "run": ("name", "description", "run", "variants", "matrix", "set", "duration_s",
            "expect", "own_expect", "faults", "virtual_only", "identify", "compare", "check"),
    "probe": ("name", "description", "probe", "check"),
    "study": ("name", "description", "study", "args", "check", "timeout_s"),
}


@dataclass(frozen=True)
class Check:
    """A criterion on one field of a JSON document."""

    field: str
    rules: dict[str, Any]
    name: str = ""
    unit: str = ""

    @property
    def label(self) -> str:
        return self.name or self.field


@dataclass(frozen=True)
class Case:
    """One job: a run (one variant x matrix point), a probe or a study."""

    id: str
    kind: str  # "run" | "probe" | "study"
    suite: str
    test: str
    where: str  # "acceptance.yaml: tests[1]" for messages
    description: str = ""
    run: str = ""  # run file: built-in name or absolute path
    overrides: dict[str, Any] = field(default_factory=dict)
    variant: str | None = None
    point: dict[str, Any] = field(default_factory=dict)
    virtual_only: bool = False
    identify: dict[str, Any] | None = None
    identify_checks: tuple[Check, ...] = ()
    checks: tuple[Check, ...] = ()
    probe: dict[str, Any] = field(default_factory=dict)
    study: str = ""
    study_args: tuple[str, ...] = ()
    timeout_s: float = 1800.0

    @property
    def run_name(self) -> str:
        return str(self.overrides.get("name", self.test))

    @property
    def item_names(self) -> list[str]:
        return [self.id] + ([f"identify[{self.id}]"] if self.identify is not None else [])


@dataclass(frozen=True)
class Compare:
    """Criteria across the cases of one test (its variants / matrix points)."""

    id: str
    suite: str
    test: str
    where: str
    cases: tuple[str, ...]
    rules: tuple[dict[str, Any], ...]


@dataclass
class Suite:
    name: str
    description: str
    source: Path
    cases: list[Case]
    compares: list[Compare]


def list_suites() -> list[tuple[str, str]]:
    out = []
    for path in sorted(SUITES_DIR.glob("*.yaml")):
        raw = yaml.safe_load(path.read_text()) or {}
        out.append((path.stem, str(raw.get("description", "")) if isinstance(raw, dict)
                    else ""))
    return out


def suite_path(name_or_path: str) -> Path:
    p = Path(name_or_path)
    if p.suffix in (".yaml", ".yml") or p.exists():
        return p
    return SUITES_DIR / f"{name_or_path}.yaml"


def _err(where: str, message: str) -> ConfigError:
    return ConfigError(f"{where}: {message}")


def _str(value: Any, where: str, what: str = "a string") -> str:
    if not isinstance(value, str) or not value:
        raise _err(where, f"expected {what}, got {value!r}")
    return value


def _number(value: Any, where: str, unit: str = "") -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise _err(where, f"expected a number{f' ({unit})' if unit else ''}, got {value!r}")
    return float(value)


def parse_checks(raw: Any, where: str) -> tuple[Check, ...]:
    if raw is None:
        return ()
    if not isinstance(raw, list):
        raise _err(where, "expected a list of {field, min|max|max_abs|equals|len_min|len_max}")
    out = []
    for i, c in enumerate(raw):
        w = f"{where}[{i}]"
        if not isinstance(c, dict):
            raise _err(w, f"expected a mapping {{field, {'|'.join(CHECK_RULES)}}}, got {c!r}")
        unknown = sorted(set(c) - {"field", "name", "unit", *CHECK_RULES})
        if unknown:
            raise _err(f"{w}.{unknown[0]}", "unknown key (expected one of: field, name, unit, "
                       f"{', '.join(CHECK_RULES)})")
        rules = {k: c[k] for k in CHECK_RULES if k in c}
        if not rules:
            raise _err(w, f"expected at least one of {', '.join(CHECK_RULES)}")
        for k, v in rules.items():
            if k != "equals":
                _number(v, f"{w}.{k}", str(c.get("unit", "")))
        out.append(Check(field=_str(c.get("field"), f"{w}.field", "a field path (a.b[0].c)"),
                         rules=rules, name=str(c.get("name", "")), unit=str(c.get("unit", ""))))
    return tuple(out)


def _set_path(data: dict[str, Any], dotted: str, value: Any) -> None:
    node = data
    parts = dotted.split(".")
    for p in parts[:-1]:
        node = node.setdefault(p, {})
    node[parts[-1]] = value


def _merge_expect(base: Any, extra: Any) -> Any:
    if extra is None:
        return copy.deepcopy(base)
    if base is None:
        return copy.deepcopy(extra)
    if isinstance(base, list) and isinstance(extra, list):
        return [*copy.deepcopy(base), *copy.deepcopy(extra)]
    if isinstance(base, dict) and isinstance(extra, dict):
        return _deep_merge(base, extra)
    return copy.deepcopy(extra)


def _fmt(v: Any) -> str:
    return f"{v:g}" if isinstance(v, float) else str(v)


def _run_cases(t: dict[str, Any], where: str, suite: str, base_dir: Path) -> list[Case]:
    run_ref = _str(t["run"], f"{where}.run", "a run name or path")
    path = run_path(run_ref)
    if not path.exists() and not path.is_absolute():
        local = base_dir / run_ref
        path = local if local.exists() else path
    if not path.exists():
        # load_run names the built-in runs
        try:
            load_run(run_ref)
        except ConfigError as exc:
            raise _err(f"{where}.run", str(exc)) from exc
    path = path.resolve()
    raw = yaml.safe_load(path.read_text()) or {}
    if not isinstance(raw, dict):
        raise _err(f"{where}.run", f"{path.name}: expected a mapping of keys")
    name = t.get("name") or raw.get("name") or path.stem
    _str(name, f"{where}.name")
    available = raw.get("variants") or {}
    sel = t.get("variants", "all")
    if sel is None or sel == "all":
        variants: list[str | None] = list(available) or [None]
    elif isinstance(sel, list) and all(isinstance(v, str) for v in sel) and sel:
        for i, v in enumerate(sel):
            if v not in available:
                raise _err(f"{where}.variants[{i}]", f"{path.name} has variants "
                           f"{sorted(available) or 'none'}, not {v!r}")
        variants = list(sel)
    else:
        raise _err(f"{where}.variants", f"expected 'all' or a list of variant names, got {sel!r}")
    matrix = t.get("matrix") or {}
    if not isinstance(matrix, dict) or not all(
            isinstance(k, str) and isinstance(v, list) and v for k, v in matrix.items()):
        raise _err(f"{where}.matrix", "expected a mapping KEY.PATH: [values, ...] (e.g. "
                   f"controller.beta: [0.6, 1.0]), got {matrix!r}")
    sets = t.get("set") or {}
    if not isinstance(sets, dict):
        raise _err(f"{where}.set", f"expected a mapping of run-file overrides, got {sets!r}")
    faults = t.get("faults")
    if faults is not None and not isinstance(faults, list):
        raise _err(f"{where}.faults", "expected a list of {kind, at_s, device?, ...}")
    own_expect = t.get("own_expect", True)
    if not isinstance(own_expect, bool):
        raise _err(f"{where}.own_expect", f"expected true or false, got {own_expect!r}")
    virtual_only = t.get("virtual_only", False)
    if not isinstance(virtual_only, bool):
        raise _err(f"{where}.virtual_only", f"expected true or false, got {virtual_only!r}")
    identify = t.get("identify")
    id_checks: tuple[Check, ...] = ()
    if identify is not None:
        if identify is True:
            identify = {}
        if not isinstance(identify, dict):
            raise _err(f"{where}.identify", "expected a mapping {n_modes?, f_max_hz?, check}")
        unknown = sorted(set(identify) - {"n_modes", "f_max_hz", "check"})
        if unknown:
            raise _err(f"{where}.identify.{unknown[0]}",
                       "unknown key (expected one of: check, f_max_hz, n_modes)")
        id_checks = parse_checks(identify.get("check"), f"{where}.identify.check")
        identify = {k: v for k, v in identify.items() if k != "check"}
    checks = parse_checks(t.get("check"), f"{where}.check")
    keys = list(matrix)
    cases = []
    for variant in variants:
        for values in itertools.product(*(matrix[k] for k in keys)):
            point = dict(zip(keys, values, strict=True))
            over: dict[str, Any] = {}
            labels: list[str] = []
            if variant is not None:
                over = copy.deepcopy(available[variant])
                if not isinstance(over, dict):
                    raise _err(f"{where}.run", f"{path.name}: variants.{variant}: expected a "
                               "mapping of overrides")
                labels.append(variant)
            for k, v in point.items():
                _set_path(over, k, v)
                labels.append(f"{k.rsplit('.', 1)[-1]}={_fmt(v)}")
            over = _deep_merge(over, sets)
            if "duration_s" in t:
                over["duration_s"] = _number(t["duration_s"], f"{where}.duration_s", "s")
            if faults:
                over["faults"] = [*(raw.get("faults") or []), *copy.deepcopy(faults)]
            if "expect" in t or not own_expect:
                # the run file's criteria with the variant's changes, then the suite's
                base = _merge_expect(raw.get("expect"), over.get("expect"))
                if not own_expect:  # a null criterion is removed (load_run deep-merges)
                    base = dict.fromkeys(base, None) if isinstance(base, dict) else None
                over["expect"] = _merge_expect(base, t.get("expect"))
            case_id = f"{name}[{','.join(labels)}]" if labels else name
            over["name"] = safe_name("-".join([name, *(lb.replace("=", "-") for lb in labels)]))
            try:
                load_run(str(path), over)
            except ConfigError as exc:
                raise _err(f"{where} ({case_id})", str(exc)) from exc
            cases.append(Case(
                id=case_id, kind="run", suite=suite, test=name, where=where,
                description=str(t.get("description") or raw.get("description") or ""),
                run=str(path), overrides=over, variant=variant, point=point,
                virtual_only=virtual_only or bool(faults) or bool(raw.get("faults")),
                identify=identify, identify_checks=id_checks, checks=checks))
    return cases


def _compare(t: dict[str, Any], where: str, suite: str, cases: list[Case]) -> Compare | None:
    raw = t.get("compare")
    if raw is None:
        return None
    if not isinstance(raw, list) or not raw:
        raise _err(f"{where}.compare", "expected a list of {measure, largest|smallest: CASE}")
    labels = {c.id: c for c in cases}
    short = {c.id[len(c.test) + 1:-1]: c.id for c in cases if c.id != c.test}
    rules = []
    for i, r in enumerate(raw):
        w = f"{where}.compare[{i}]"
        if not isinstance(r, dict):
            raise _err(w, f"expected a mapping {{measure, largest|smallest}}, got {r!r}")
        unknown = sorted(set(r) - {"measure", "largest", "smallest", "name", "unit"})
        if unknown:
            raise _err(f"{w}.{unknown[0]}",
                       "unknown key (expected one of: largest, measure, name, smallest, unit)")
        _str(r.get("measure"), f"{w}.measure", "a summary.json field path")
        which = [k for k in ("largest", "smallest") if k in r]
        if len(which) != 1:
            raise _err(w, "expected exactly one of largest, smallest")
        target = r[which[0]]
        full = short.get(str(target), str(target))
        if full not in labels:
            raise _err(f"{w}.{which[0]}", f"expected one of {sorted(short) or sorted(labels)}, "
                       f"got {target!r}")
        rules.append({**r, which[0]: full})
    if len(cases) < 2:
        raise _err(f"{where}.compare", "needs at least two variants or matrix points")
    return Compare(id=f"compare[{cases[0].test}]", suite=suite, test=cases[0].test,
                   where=where, cases=tuple(c.id for c in cases), rules=tuple(rules))


def load_suite(name_or_path: str) -> Suite:
    path = suite_path(name_or_path)
    if not path.exists():
        names = ", ".join(n for n, _ in list_suites())
        raise ConfigError(f"suite {name_or_path}: not found (built-in suites: {names})")
    src = path.name
    try:
        raw = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise ConfigError(f"suite file {path}: not valid YAML: {exc}") from exc
    if not isinstance(raw, dict):
        raise ConfigError(f"suite file {src}: expected a mapping with name and tests")
    unknown = sorted(set(raw) - {"name", "description", "tests"})
    if unknown:
        raise ConfigError(f"suite file {src}: {unknown[0]}: unknown key (expected one of: "
                          "description, name, tests)")
    name = _str(raw.get("name", path.stem), f"suite file {src}: name")
    tests = raw.get("tests")
    if not isinstance(tests, list) or not tests:
        raise ConfigError(f"suite file {src}: tests: expected a non-empty list of tests "
                          "(each a mapping with run, probe or study)")
    cases: list[Case] = []
    compares: list[Compare] = []
    seen: set[str] = set()
    for i, t in enumerate(tests):
        where = f"suite file {src}: tests[{i}]"
        if not isinstance(t, dict):
            raise _err(where, f"expected a mapping with run, probe or study, got {t!r}")
        kinds = [k for k in TEST_KEYS if k in t]
        if len(kinds) != 1:
            raise _err(where, "expected exactly one of run, probe, study")
        kind = kinds[0]
        unknown = sorted(set(t) - set(TEST_KEYS[kind]))
        if unknown:
            raise _err(f"{where}.{unknown[0]}", f"unknown key for a {kind} test (expected one "
                       f"of: {', '.join(sorted(TEST_KEYS[kind]))})")
        if kind == "run":
            new = _run_cases(t, where, name, path.parent)
            cmp = _compare(t, where, name, new)
            if cmp is not None:
                compares.append(cmp)
        elif kind == "probe":
            opts = t["probe"] if t["probe"] not in (None, True) else {}
            keys = {"rate_hz": "Hz", "duration_s": "s", "settle_s": "s",
                    "receive_timeout_ms": "ms"}
            if not isinstance(opts, dict) or set(opts) - set(keys):
                raise _err(f"{where}.probe", "expected a mapping {rate_hz?, duration_s?, "
                           f"settle_s?, receive_timeout_ms?}}, got {opts!r}")
            for k, v in opts.items():
                if _number(v, f"{where}.probe.{k}", keys[k]) <= 0 and k != "settle_s":
                    raise _err(f"{where}.probe.{k}", f"expected a number > 0, got {v!r}")
            test = _str(t.get("name", "probe"), f"{where}.name")
            new = [Case(id=test, kind="probe", suite=name, test=test, where=where,
                        description=str(t.get("description", "")), probe=dict(opts),
                        checks=parse_checks(t.get("check"), f"{where}.check"))]
        else:
            study = _str(t["study"], f"{where}.study", "a study name ('harness study -h')")
            args = t.get("args") or []
            if not isinstance(args, list) or not all(isinstance(a, str | int | float)
                                                     for a in args):
                raise _err(f"{where}.args", f"expected a list of arguments, got {args!r}")
            test = _str(t.get("name", f"study-{study}"), f"{where}.name")
            new = [Case(id=test, kind="study", suite=name, test=test, where=where,
                        description=str(t.get("description", "")), study=study,
                        study_args=tuple(str(a) for a in args),
                        timeout_s=_number(t.get("timeout_s", 1800.0), f"{where}.timeout_s", "s"),
                        checks=parse_checks(t.get("check"), f"{where}.check"))]
        for c in new:
            for item in c.item_names:
                if item in seen:
                    raise _err(where, f"test name {item!r} is used twice in the suite "
                               "(give one of them a name:)")
                seen.add(item)
        cases.extend(new)
    return Suite(name=name, description=str(raw.get("description", "")), source=path,
                 cases=cases, compares=compares)
