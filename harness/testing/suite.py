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
          check:                             # the run file's criterion form, keyed by name
            frequencies:
              measure: "modes[*].omega_error_percent"   # every element; the worst reported
              max_abs_percent: 0.5
              marginal_percent: 0.19
              why: 2.6 sigma of mode 3's scatter
      - run: slew-rw
        name: fault-hub-silent
        faults: [{kind: silent_sensor, at_s: 3, device: hub_sensor}]   # virtual rig only
      - study: hu2006                        # ``harness study hu2006 --json``
        args: []
        check:
          settles: {measure: measures.pd_pwpf_settle_s, max_s: 20, why: "the paper's ~20 s"}

Each test expands to one or more *cases* (one per variant x matrix point; a case is one job
for the engine) and each case to one or more pytest items: the run itself
(``slew-rw``, ``case-a[beta-1.0]``), its identification (``identify[free-decay]``); a
``compare`` adds one item per test (``compare[case-a]``). Test names must be unique in a
suite.

``check:`` criteria apply to a JSON document (summary.json for a run, the probe report,
``identify --json``, ``study NAME --json``) and take the run file's scalar form
(docs/criteria.md): ``NAME: {measure: PATH, <limit>_<unit>: ..., marginal_<unit>: ...,
why: ...}``, the path any field of the document (``a.b[0].c``, ``[*]`` for every element;
keys may contain dots: the longest key that matches wins), the unit from the field's name.
The deprecated list form ``[{field, min|max|..., unit, name}]`` is translated, with a
message on stderr giving the new spelling (``translate_old_checks``).

Everything is checked when the suite is loaded, before anything runs: an error names the
suite file, the key path and what was expected (``acceptance.yaml: tests[2].matrix: expected
a mapping KEY.PATH: [values]``), and every run file is loaded with its overrides.
"""

from __future__ import annotations

import copy
import dataclasses
import itertools
import math
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from harness.core.paths import safe_name
from harness.core.runs import _deep_merge, load_run, run_path
from harness.testing.criteria import FORMS, Criterion, _items, parse_criterion
from harness.testing.measures import path_error, unit_of_path
from rig_models.schema import ConfigError, short_repr
from rig_models.yaml_file import load_yaml

SUITES_DIR = Path(__file__).resolve().parent.parent / "suites"
TEST_KEYS = {
    "run": ("name", "description", "run", "variants", "matrix", "set", "duration_s",
            "expect", "own_expect", "faults", "virtual_only", "identify", "compare", "check"),
    "probe": ("name", "description", "probe", "check"),
    "study": ("name", "description", "study", "args", "check", "timeout_s"),
}


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
    identify_checks: tuple[Criterion, ...] = ()
    checks: tuple[Criterion, ...] = ()
    probe: dict[str, Any] = field(default_factory=dict)
    study: str = ""
    study_args: tuple[str, ...] = ()
    timeout_s: float = 1800.0
    require_criteria: bool = True  # the suite's: a test judging nothing FAILs

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
    finite = False
    if not isinstance(value, bool) and isinstance(value, int | float):
        try:
            finite = math.isfinite(value)
        except OverflowError:  # an int too large for a float
            finite = False
    if not finite:
        raise _err(where, f"expected a finite number{f' ({unit})' if unit else ''}, "
                   f"got {value!r}")
    return float(value)


OLD_RULES = ("min", "max", "max_abs", "equals", "len_min", "len_max")
OLD_UNITS = {"%": "percent", "percent": "percent", "s": "s", "ms": "ms", "deg": "deg",
             "rad": "rad", "deg/s": "deg_s", "rad/s": "rad_s", "hz": "hz", "Hz": "hz",
             "m": "m", "m/s^2": "m_s2", "m/s2": "m_s2", "N m": "n_m", "Nm": "n_m",
             "kg": "kg", "V": "v", "A": "a", "count": "count", "ratio": "ratio"}
"""The old ``check:`` form's free-text ``unit:`` values and the unit suffix each means."""


def translate_old_checks(raw: list[Any], source: str, key: str) -> dict[str, Any]:
    """The deprecated list form ``[{field, min|max|max_abs|equals|len_min|len_max, unit?,
    name?}]`` as the run file's form ``{name: {measure, <limit>_<unit>, ...}}``, with a
    deprecation message on stderr naming the file, the key path and the new spelling.
    Refused (ConfigError) where the translation would change a meaning: a ``unit:`` that is
    not the unit the field's name gives."""
    out: dict[str, Any] = {}
    for i, c in enumerate(raw):
        w = f"{key}[{i}]"
        if not isinstance(c, dict) or "field" not in c:
            raise _err(f"{source}: {w}", "mixes the deprecated {field: ...} form with the run "
                       "file's form: write every criterion as NAME: {measure: PATH, ...}")
        unknown = sorted(set(c) - {"field", "name", "unit", *OLD_RULES}, key=str)
        if unknown:
            raise _err(f"{source}: {w}.{unknown[0]}", "unknown key (the deprecated form takes "
                       f"field, name, unit, {', '.join(OLD_RULES)})")
        field_path = c["field"]
        bad = path_error(field_path)
        if bad is not None:
            raise _err(f"{source}: {w}.field", bad)
        rules = [r for r in OLD_RULES if r in c]
        if not rules:
            raise _err(f"{source}: {w}", f"expected at least one of {', '.join(OLD_RULES)}")
        given = c.get("unit")
        unit = unit_of_path(field_path)
        if unit is None:  # no unit in the name: dimensionless, a count if it said so
            unit = "count" if OLD_UNITS.get(str(given)) == "count" else "ratio"
        valued = [r for r in rules if r in ("min", "max", "max_abs") or (
            r == "equals" and not isinstance(c[r], bool | str))]
        if valued and given not in (None, ""):
            meant = OLD_UNITS.get(str(given))
            if meant != unit:
                origin = "no suffix: ratio" if unit == "ratio" else "its suffix"
                said = "is not a unit the harness knows" if meant is None else f"is {meant}"
                raise _err(f"{source}: {w}.unit", f"{field_path} is in {unit} (the unit comes "
                           f"from the field's name, {origin}); unit {given!r} {said}: the "
                           f"field's name decides, as in run files ({rules[0]}_{unit})")
        new: dict[str, Any] = {"measure": field_path}
        for r in rules:
            v = c[r]
            if r == "equals":
                new["is" if isinstance(v, bool | str) else f"equals_{unit}"] = v
            elif r in ("len_min", "len_max"):
                new[f"{r}_count"] = v
            else:
                new[f"{r}_{unit}"] = v
        name = str(c.get("name") or field_path)
        if name in out:
            name = f"{name} [{i}]"
        out[name] = new
    spelled = yaml.safe_dump({key.rsplit(".", 1)[-1]: out}, sort_keys=False, width=100,
                             allow_unicode=True)
    print(f"harness: deprecated: {source}: {key}: the list form [{{field: ..., max: ...}}] "
          "is deprecated; it was read as the run file's criterion form, which is written "
          "(docs/criteria.md):\n"
          + "".join(f"    {line}\n" for line in spelled.splitlines()), end="", file=sys.stderr)
    return out


def parse_checks(raw: Any, source: str, key: str) -> tuple[Criterion, ...]:
    """A ``check:`` section: the run file's scalar criteria (``NAME: {measure: PATH, ...}``,
    docs/criteria.md) on a JSON document, any field path of it (``open_paths``). The
    deprecated list form (``field:``) is translated, with a message on stderr."""
    if raw is None:
        return ()
    if isinstance(raw, list) and any(isinstance(c, dict) and "field" in c for c in raw):
        raw = translate_old_checks(raw, source, key)
    out = []
    for name, path, c in _items(raw, source, key):
        if isinstance(c, dict) and "measure" not in c:
            other = next((f for f in FORMS if f in c), None)
            if other is not None:
                raise _err(f"{source}: {path}.{other}", "a check: criterion is the scalar form "
                           "(measure: PATH); channels, settling, faults, baselines and "
                           "left_safe belong in a run test's expect:")
        out.append(parse_criterion(name, c, source, path, channels=(), check_files=False,
                                   open_paths=True))
    return tuple(out)


MAX_SUITE_CASES = 10_000
"""The most cases (runs) a suite expands to, every test's variants times its matrix
points: the built-in suites have a few dozen; a matrix of 10^9 points ran until killed."""

PROBE_LIMITS = {"rate_hz": ("Hz", 10_000.0), "duration_s": ("s", 30 * 24 * 3600.0),
                "settle_s": ("s", 30 * 24 * 3600.0),
                "receive_timeout_ms": ("ms", 30 * 24 * 3600.0 * 1e3)}
"""A probe test's options, their units and their largest values, as ``harness probe``'s
own options (``harness.cli``): a 1 Mbit/s bus carries about 8000 frames a second, a probe
at 10^9 Hz ran until killed."""


def _set_path(data: dict[str, Any], dotted: str, value: Any, where: str = "matrix") -> None:
    node = data
    parts = dotted.split(".")
    for i, p in enumerate(parts[:-1]):
        node = node.setdefault(p, {})
        if not isinstance(node, dict):
            raise _err(f"{where}.{dotted}", f"{'.'.join(parts[:i + 1])} is "
                       f"{short_repr(node)}, not a mapping with keys under it")
    node[parts[-1]] = value


def _check_matrix_keys(matrix: dict[str, Any], where: str) -> None:
    """Each key a dotted path of names; none the path of another's parent (``duration_s``
    and ``duration_s.x`` cannot both be set)."""
    for k in matrix:
        if not all(k.split(".")):
            raise _err(f"{where}.matrix.{k}", "expected a key path such as controller.beta "
                       "(names joined by dots)")
    for k in sorted(matrix):
        for other in matrix:
            if other.startswith(k + "."):
                raise _err(f"{where}.matrix", f"keys {k} and {other}: {k} cannot be both a "
                           f"value and a mapping holding {other[len(k) + 1:]}")


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


def _run_cases(t: dict[str, Any], where: str, suite: str, base_dir: Path, source: str,
               key: str, budget: int = MAX_SUITE_CASES) -> list[Case]:
    """The cases of a run test; ``budget``: the most it may expand to (checked before)."""
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
    raw = load_yaml(path, "run file") or {}
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
                           f"{sorted(available, key=str) or 'none'}, not {v!r}")
        variants = list(sel)
    else:
        raise _err(f"{where}.variants", f"expected 'all' or a list of variant names, got {sel!r}")
    matrix = t.get("matrix") or {}
    if not isinstance(matrix, dict) or not all(
            isinstance(k, str) and isinstance(v, list) and v for k, v in matrix.items()):
        raise _err(f"{where}.matrix", "expected a mapping KEY.PATH: [values, ...] (e.g. "
                   f"controller.beta: [0.6, 1.0]), got {matrix!r}")
    _check_matrix_keys(matrix, where)
    n_cases = len(variants) * math.prod(len(v) for v in matrix.values())
    if n_cases > budget:
        raise _err(f"{where}.matrix", f"{n_cases} cases ({len(variants)} variant(s) x "
                   f"{' x '.join(str(len(v)) for v in matrix.values())} matrix values), more "
                   f"than the {budget} left of the {MAX_SUITE_CASES} cases a suite may have")
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
    id_checks: tuple[Criterion, ...] = ()
    if identify is not None:
        if identify is True:
            identify = {}
        if not isinstance(identify, dict):
            raise _err(f"{where}.identify", "expected a mapping {n_modes?, f_max_hz?, check}")
        unknown = sorted(set(identify) - {"n_modes", "f_max_hz", "check"}, key=str)
        if unknown:
            raise _err(f"{where}.identify.{unknown[0]}",
                       "unknown key (expected one of: check, f_max_hz, n_modes)")
        id_checks = parse_checks(identify.get("check"), source, f"{key}.identify.check")
        identify = {k: v for k, v in identify.items() if k != "check"}
    checks = parse_checks(t.get("check"), source, f"{key}.check")
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
                _set_path(over, k, v, f"{where}.matrix")
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
        unknown = sorted(set(r) - {"measure", "largest", "smallest", "name", "unit", "why"},
                         key=str)
        if unknown:
            raise _err(f"{w}.{unknown[0]}",
                       "unknown key (expected one of: largest, measure, name, smallest, unit, "
                       "why)")
        if not isinstance(r.get("why", ""), str):
            raise _err(f"{w}.why", f"expected a string, got {r['why']!r}")
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


RUN_FILE_KEYS = ("controller", "actuators")
"""Keys only a run file has: a file with them and no ``tests:`` is a run file."""


def run_file_suite(path: Path, raw: dict[str, Any]) -> dict[str, Any]:
    """A run file as a one-test suite (``harness test RUN.yaml``): the run and each of its
    variants, judged by its own ``expect:``."""
    name = raw.get("name") if isinstance(raw.get("name"), str) and raw.get("name") \
        else path.stem
    return {"name": name, "description": f"the run file {path.name} as a one-test suite",
            "tests": [{"run": str(path.resolve())}]}


def load_suite(name_or_path: str) -> Suite:
    path = suite_path(name_or_path)
    if not path.exists() and run_path(name_or_path).exists():
        path = run_path(name_or_path)  # a built-in run's name: that run file
    if not path.exists():
        names = ", ".join(n for n, _ in list_suites())
        raise ConfigError(f"suite {name_or_path}: not found (built-in suites: {names}; or a "
                          "run file's name or path: 'harness cases')")
    src = path.name
    raw = load_yaml(path, "suite file")
    if isinstance(raw, dict) and "tests" not in raw and any(k in raw for k in RUN_FILE_KEYS):
        raw = run_file_suite(path, raw)
    if not isinstance(raw, dict):
        raise ConfigError(f"suite file {src}: expected a mapping with name and tests")
    unknown = sorted(set(raw) - {"name", "description", "tests", "require_criteria"}, key=str)
    if unknown:
        raise ConfigError(f"suite file {src}: {unknown[0]}: unknown key (expected one of: "
                          "description, name, require_criteria, tests)")
    required = raw.get("require_criteria", True)
    if not isinstance(required, bool):
        raise ConfigError(f"suite file {src}: require_criteria: expected true or false, got "
                          f"{required!r}")
    name = _str(raw.get("name", path.stem), f"suite file {src}: name")
    tests = raw.get("tests")
    if not isinstance(tests, list) or not tests:
        raise ConfigError(f"suite file {src}: tests: expected a non-empty list of tests "
                          "(each a mapping with run, probe or study)")
    cases: list[Case] = []
    compares: list[Compare] = []
    seen: set[str] = set()
    for i, t in enumerate(tests):
        source = f"suite file {src}"
        where = f"{source}: tests[{i}]"
        if not isinstance(t, dict):
            raise _err(where, f"expected a mapping with run, probe or study, got {t!r}")
        kinds = [k for k in TEST_KEYS if k in t]
        if len(kinds) != 1:
            raise _err(where, "expected exactly one of run, probe, study")
        kind = kinds[0]
        unknown = sorted(set(t) - set(TEST_KEYS[kind]), key=str)
        if unknown:
            raise _err(f"{where}.{unknown[0]}", f"unknown key for a {kind} test (expected one "
                       f"of: {', '.join(sorted(TEST_KEYS[kind]))})")
        if kind == "run":
            new = _run_cases(t, where, name, path.parent, source, f"tests[{i}]",
                             MAX_SUITE_CASES - len(cases))
            cmp = _compare(t, where, name, new)
            if cmp is not None:
                compares.append(cmp)
        elif kind == "probe":
            opts = t["probe"] if t["probe"] not in (None, True) else {}
            if not isinstance(opts, dict) or set(opts) - set(PROBE_LIMITS):
                raise _err(f"{where}.probe", "expected a mapping {rate_hz?, duration_s?, "
                           f"settle_s?, receive_timeout_ms?}}, got {short_repr(opts)}")
            for k, v in opts.items():
                unit, largest = PROBE_LIMITS[k]
                x = _number(v, f"{where}.probe.{k}", unit)
                if x <= 0 and k != "settle_s":
                    raise _err(f"{where}.probe.{k}", f"expected a number > 0, got {v!r}")
                if x < 0 or x > largest:
                    raise _err(f"{where}.probe.{k}", f"expected at most {largest:g} {unit}, "
                               f"got {v!r}")
            test = _str(t.get("name", "probe"), f"{where}.name")
            new = [Case(id=test, kind="probe", suite=name, test=test, where=where,
                        description=str(t.get("description", "")), probe=dict(opts),
                        checks=parse_checks(t.get("check"), source, f"tests[{i}].check"))]
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
                        checks=parse_checks(t.get("check"), source, f"tests[{i}].check"))]
        if len(cases) + len(new) > MAX_SUITE_CASES:
            raise _err(where, f"the suite expands to more than the {MAX_SUITE_CASES} cases "
                       "a suite may have")
        for c in new:
            for item in c.item_names:
                if item in seen:
                    raise _err(where, f"test name {item!r} is used twice in the suite "
                               "(give one of them a name:)")
                seen.add(item)
        cases.extend(new)
    if not required:
        cases = [dataclasses.replace(c, require_criteria=False) for c in cases]
    return Suite(name=name, description=str(raw.get("description", "")), source=path,
                 cases=cases, compares=compares)
