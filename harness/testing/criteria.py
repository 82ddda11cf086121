"""Parsing and checking criteria: a run file's ``expect:`` section, and a suite's ``check:``
(the same scalar form, ``parse_criteria(..., open_paths=True)``; no run, no file reading
except checking that a baseline exists).

Every error names the source, the key path and what was expected, e.g.
``run file slew.yaml: expect.final_error.max_abs_s: final_angle_error_deg is in deg: expected
max_abs_deg``. The forms and keys are documented in docs/criteria.md.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from harness.testing.measures import (
    DIMENSIONLESS,
    TIME_EVENTS,
    is_budget,
    path_error,
    unit_of_channel,
    unit_of_measure,
    unit_of_path,
)
from rig_models.schema import ConfigError

FORMS = ("fault", "left_safe", "settles", "baseline", "modal_residual", "frf", "measure",
         "channel")
"""The key that names a criterion's form, checked in this order (``baseline`` criteria also
have a ``channel``)."""

REDUCTIONS = ("each", "rms", "std", "mean", "final")
"""A channel criterion's value: each sample, the rms, the rms about the mean (``std``: a
vibration with the sensor's bias left out), the mean, the final sample."""
COMMON_KEYS = ("why", "budget", "applies_to_stopped")
WINDOW_KEYS = ("after", "from_s", "to_s", "last_s")


@dataclass(frozen=True)
class Window:
    """Samples from ``after``'s time + ``from_s`` to ``after``'s time + ``to_s`` (run start and
    end by default), or the last ``last_s`` of the run."""

    after: str | None = None
    from_s: float | None = None
    to_s: float | None = None
    last_s: float | None = None

    def describe(self) -> str:
        if self.last_s is not None:
            return f"last {self.last_s:g} s"
        base = self.after or "start"
        a = "" if self.from_s is None else f"{base}+{self.from_s:g} s"
        b = "" if self.to_s is None else f"{base}+{self.to_s:g} s"
        if not a and not b:
            return f"after {self.after}" if self.after else "whole run"
        return f"{a or base}..{b or 'end'}"


@dataclass(frozen=True)
class Criterion:
    """One parsed criterion. ``limit`` holds the limits without their unit suffix (``min``,
    ``max``, ``max_abs``, ``marginal``, ``within_s``, ...); ``unit`` is the measure's."""

    name: str
    kind: str  # "scalar" | "channel" | "settles" | "baseline" | "modal_residual" | "fault"
    # | "left_safe" | "frf"
    key_path: str  # e.g. "expect.final_error" (for messages)
    target: str  # summary path, channel entity, or fault device
    unit: str
    limit: dict[str, Any]
    window: Window = field(default_factory=Window)
    reduce: str = "each"
    budget: bool = False
    params: dict[str, Any] = field(default_factory=dict)
    why: str = ""
    applies_to_stopped: bool = False
    """Judged on a run a fault, an interruption or an error stopped early too (``fault`` and
    ``left_safe`` criteria always are); otherwise such a run leaves it NOT JUDGED."""

    @property
    def marginal(self) -> float | None:
        return self.limit.get("marginal")


def _err(source: str, path: str, msg: str) -> ConfigError:
    return ConfigError(f"{source}: {path}: {msg}")


def _finite(v: int | float) -> bool:
    try:
        return math.isfinite(v)
    except OverflowError:  # an int too large for a float (YAML reads 1e999 as text)
        return False


def _number(source: str, path: str, v: Any, unit: str, positive: bool = False,
            nonneg: bool = False) -> float:
    if isinstance(v, bool) or not isinstance(v, int | float) or not _finite(v):
        raise _err(source, path, f"expected a finite number ({unit}), got {v!r}")
    if positive and v <= 0:
        raise _err(source, path, f"expected a number > 0 ({unit}), got {v!r}")
    if nonneg and v < 0:
        raise _err(source, path, f"expected a number >= 0 ({unit}), got {v!r}")
    return float(v)


LIMIT_NAMES = ("max_abs", "len_min", "len_max", "equals", "marginal", "min", "max")
"""Limit keys without their unit (a key is NAME_<unit>), longest first where one begins
another. ``len_*`` bound a list's length (unit ``count``); ``equals`` stands alone."""
VALUE_LIMITS = ("min", "max", "max_abs", "marginal")
MEASURE_LIMITS = ("min", "max", "max_abs", "equals", "marginal")
LENGTH_LIMITS = ("len_min", "len_max", "marginal")


def _limit_name(key: str) -> str | None:
    return next((n for n in LIMIT_NAMES if key == n or key.startswith(n + "_")), None)


def _band(source: str, path: str, raw: Mapping[str, Any], unit: str, target: str,
          used: set[str], require: bool = True,
          allowed: tuple[str, ...] = VALUE_LIMITS) -> dict[str, Any]:
    """The limit keys (``<name>_<unit>``, names in ``allowed``) in ``unit``; refuses a wrong
    or missing unit, a limit this form does not take, and contradictory limits."""
    limit: dict[str, Any] = {}
    length = "len_min" in allowed
    for key in raw:
        name = _limit_name(str(key))
        if name is None:
            continue
        if name not in allowed:
            if length:
                why = f"a criterion on the length of {target} takes only len_min_count, " \
                      "len_max_count and marginal_count"
            elif name in ("len_min", "len_max", "equals"):
                why = f"{name}_<unit> is for measure: criteria only"
            else:
                why = "not with len_min_count / len_max_count (the length is a count)"
            raise _err(source, f"{path}.{key}", why)
        got = str(key)[len(name) + 1:]
        what = f"the length of {target}" if length else target
        if not got:
            raise _err(source, f"{path}.{key}", f"missing unit: {what} is in {unit}: "
                       f"expected {name}_{unit}")
        if got != unit:
            raise _err(source, f"{path}.{key}", f"{what} is in {unit}: expected "
                       f"{name}_{unit}, got unit {got!r}")
        limit[name] = _number(source, f"{path}.{key}", raw[key], unit,
                              nonneg=name in ("max_abs", "marginal", "len_min", "len_max"))
        used.add(key)
    hard = [k for k in limit if k != "marginal"]
    if require and not hard:
        names = [f"{n}_{unit}" for n in allowed if n != "marginal"]
        raise _err(source, path, f"no limit: expected {', '.join(names[:-1])} or {names[-1]}")
    if "equals" in limit and len(hard) > 1:
        raise _err(source, f"{path}.equals_{unit}", "equals stands alone (not with min, max "
                   "or max_abs)")
    if "equals" in limit and "marginal" in limit:
        raise _err(source, f"{path}.marginal_{unit}", "an equality has no marginal band")
    lo_key, hi_key = ("len_min", "len_max") if length else ("min", "max")
    lo, hi = limit.get(lo_key), limit.get(hi_key)
    if lo is not None and hi is not None and lo > hi:
        raise _err(source, f"{path}.{lo_key}_{unit}", f"{lo_key.replace('len_', 'length ')} "
                   f"{lo:g} > {hi_key.replace('len_', 'length ')} {hi:g} ({unit})")
    if "max_abs" in limit and lo is not None and lo > limit["max_abs"]:
        raise _err(source, f"{path}.min_{unit}",
                   f"min {lo:g} > max_abs {limit['max_abs']:g} ({unit})")
    if "marginal" in limit and limit["marginal"] > 0:
        halves = [limit["max_abs"]] if "max_abs" in limit else []
        if lo is not None and hi is not None:
            halves.append((hi - lo) / 2)
        if halves and limit["marginal"] >= min(halves):
            raise _err(source, f"{path}.marginal_{unit}",
                       f"marginal band {limit['marginal']:g} {unit} covers the whole pass "
                       f"band (half-width {min(halves):g} {unit}); expected less")
    return limit


def _measure(name: str, raw: Mapping[str, Any], source: str, key_path: str, used: set[str],
             why: str, budget_raw: bool | None, known_measures: Iterable[str] | None,
             open_paths: bool) -> Criterion:
    """The scalar form: ``measure: PATH`` with limits in the path's unit, ``is:``, or the
    length of a list (``len_min_count`` / ``len_max_count``)."""
    target = raw["measure"]
    if open_paths:
        bad = path_error(target)
        if bad is not None:
            raise _err(source, f"{key_path}.measure", bad)
        unit: str | None = unit_of_path(target)
        if unit is None:  # no unit in the name: dimensionless, counted or not as written
            keys = [str(k) for k in raw if _limit_name(str(k)) and not str(k).startswith("len_")]
            for k in keys:
                if k.rsplit("_", 1)[-1] not in DIMENSIONLESS:
                    name_ = _limit_name(k)
                    raise _err(source, f"{key_path}.{k}", f"{target} has no unit in its name "
                               f"(dimensionless): expected {name_}_ratio or {name_}_count")
            unit = "count" if keys and all(k.endswith("_count") for k in keys) else "ratio"
    else:
        extra = set(known_measures or ())
        unit = unit_of_measure(target) if isinstance(target, str) else None
        if unit is None and isinstance(target, str) and target in extra:
            unit = unit_of_measure_name(target) or "ratio"
        if unit is None:
            from harness.testing.measures import SUMMARY_MEASURES
            raise _err(source, f"{key_path}.measure", f"unknown measure {target!r} (known: "
                       f"{', '.join(sorted(set(SUMMARY_MEASURES) | extra))}, "
                       "controller_design.*)")
    budget = is_budget(target) if budget_raw is None else budget_raw
    if "is" in raw or unit == "bool":
        v = raw.get("is")
        if not (isinstance(v, bool) or (open_paths and isinstance(v, str))):
            expected = "is: true|false" + (" or is: TEXT" if open_paths else "")
            raise _err(source, f"{key_path}.is", f"{target} is compared with {expected}, "
                       f"got {v!r}")
        if unit != "bool" and not open_paths:
            raise _err(source, f"{key_path}.is", f"{target} is in {unit}: a number takes "
                       f"min_{unit}, max_{unit}, max_abs_{unit} or equals_{unit}, not is:")
        used.add("is")
        _check_keys(source, key_path, raw, used, "measure, is, why")
        return Criterion(name, "scalar", key_path, target, "bool" if isinstance(v, bool)
                         else "", {"is": v}, budget=budget, why=why)
    if any(str(k).startswith("len_") for k in raw):
        limit = _band(source, key_path, raw, "count", target, used, allowed=LENGTH_LIMITS)
        _check_keys(source, key_path, raw, used, "len_min_count, len_max_count, "
                    "marginal_count, why")
        return Criterion(name, "scalar", key_path, target, "count", limit, budget=budget,
                         why=why)
    limit = _band(source, key_path, raw, unit, target, used, allowed=MEASURE_LIMITS)
    _check_keys(source, key_path, raw, used, f"min_{unit}, max_{unit}, max_abs_{unit}, "
                f"equals_{unit}, marginal_{unit}, budget, why")
    return Criterion(name, "scalar", key_path, target, unit, limit, budget=budget, why=why)


def _window(source: str, path: str, raw: Mapping[str, Any], used: set[str]) -> Window:
    after = raw.get("after")
    if after is not None and after not in TIME_EVENTS:
        raise _err(source, f"{path}.after", f"expected one of {list(TIME_EVENTS)}, "
                   f"got {after!r}")
    vals: dict[str, float | None] = {}
    for k in ("from_s", "to_s", "last_s"):
        vals[k] = None if raw.get(k) is None else _number(
            source, f"{path}.{k}", raw[k], "s", positive=k == "last_s")
    if vals["last_s"] is not None and (after or vals["from_s"] is not None
                                        or vals["to_s"] is not None):
        raise _err(source, f"{path}.last_s", "last_s is a window of its own: not with "
                   "after, from_s or to_s")
    if vals["from_s"] is not None and vals["to_s"] is not None and vals["from_s"] > vals["to_s"]:
        raise _err(source, f"{path}.from_s", f"from_s {vals['from_s']:g} > to_s "
                   f"{vals['to_s']:g} (s)")
    used.update(k for k in WINDOW_KEYS if k in raw)
    return Window(after, vals["from_s"], vals["to_s"], vals["last_s"])


def _channel(source: str, path: str, entity: Any, channels: Iterable[str] | None) -> str:
    if not isinstance(entity, str) or not entity.startswith("/"):
        raise _err(source, path, f"expected a recorded channel such as /tip/accel_m_s2, "
                   f"got {entity!r}")
    if channels is not None and entity not in set(channels):
        raise _err(source, path, f"unknown channel {entity!r} (recorded channels: "
                   f"{', '.join(sorted(channels))})")
    return entity


def _check_keys(source: str, path: str, raw: Mapping[str, Any], used: set[str],
                allowed: str) -> None:
    for key in raw:
        if key not in used and key not in COMMON_KEYS:
            raise _err(source, f"{path}.{key}", f"unknown key for this criterion (expected "
                       f"{allowed})")


def parse_criterion(name: str, raw: Any, source: str, key_path: str,
                    known_measures: Iterable[str] | None = None,
                    channels: Iterable[str] | None = None, base_dir: Path | None = None,
                    check_files: bool = True, open_paths: bool = False) -> Criterion:
    """One criterion (see ``_parse_form``), with its ``applies_to_stopped`` (true: judged on
    a run stopped early too)."""
    c = _parse_form(name, raw, source, key_path, known_measures, channels, base_dir,
                    check_files, open_paths)
    stopped = raw.get("applies_to_stopped", False)
    if not isinstance(stopped, bool):
        raise _err(source, f"{key_path}.applies_to_stopped",
                   f"expected true or false, got {stopped!r}")
    always = c.kind in ("fault", "left_safe")
    return replace(c, applies_to_stopped=stopped or always) if stopped or always else c


def _parse_form(name: str, raw: Any, source: str, key_path: str,
                known_measures: Iterable[str] | None = None,
                channels: Iterable[str] | None = None, base_dir: Path | None = None,
                check_files: bool = True, open_paths: bool = False) -> Criterion:
    """One criterion (see docs/criteria.md). ``known_measures``: extra scalar measure paths
    accepted beside summary.json's (their unit from their name); ``channels``: the recorded
    channels (None: any entity path); ``open_paths``: a ``measure:`` may be any field path
    of the judged document (a suite's ``check:``: its fields are not known before it
    exists), its unit from its name (``unit_of_path``)."""
    if not isinstance(raw, Mapping):
        raise _err(source, key_path, f"expected a mapping with one of {list(FORMS)}, "
                   f"got {raw!r}")
    form = next((f for f in FORMS if f in raw), None)
    if form is None:
        raise _err(source, key_path, f"expected one of the keys {list(FORMS)} "
                   f"(got {sorted(raw)})")
    used = {form}
    why = raw.get("why", "")
    if not isinstance(why, str):
        raise _err(source, f"{key_path}.why", f"expected a string, got {why!r}")
    budget_raw = raw.get("budget")
    if budget_raw is not None and not isinstance(budget_raw, bool):
        raise _err(source, f"{key_path}.budget", f"expected true or false, got {budget_raw!r}")

    if form == "measure":
        return _measure(name, raw, source, key_path, used, why, budget_raw, known_measures,
                        open_paths)

    if form == "frf":
        from harness.testing.frf_criterion import parse_frf

        return parse_frf(name, raw, source, key_path, why)

    if form == "channel":
        target = _channel(source, f"{key_path}.channel", raw["channel"], channels)
        unit = unit_of_channel(target)
        reduce = raw.get("reduce", "each")
        if reduce not in REDUCTIONS:
            raise _err(source, f"{key_path}.reduce", f"expected one of {list(REDUCTIONS)}, "
                       f"got {reduce!r}")
        used.add("reduce")
        limit = _band(source, key_path, raw, unit, target, used)
        window = _window(source, key_path, raw, used)
        _check_keys(source, key_path, raw, used, f"reduce, min_{unit}, max_{unit}, "
                    f"max_abs_{unit}, marginal_{unit}, after, from_s, to_s, last_s, why")
        return Criterion(name, "channel", key_path, target, unit, limit, window, reduce,
                         budget=bool(budget_raw), why=why)

    if form == "settles":
        target = _channel(source, f"{key_path}.settles", raw["settles"], channels)
        unit = unit_of_channel(target)
        band_key, center_key = f"band_{unit}", f"center_{unit}"
        for key in raw:
            if (key.startswith("band") and key != band_key) or (
                    key.startswith("center") and key != center_key):
                raise _err(source, f"{key_path}.{key}", f"{target} is in {unit}: expected "
                           f"{band_key if key.startswith('band') else center_key}")
        if band_key not in raw:
            raise _err(source, f"{key_path}.{band_key}", f"missing; expected the band's "
                       f"half-width, a number > 0 ({unit})")
        band = _number(source, f"{key_path}.{band_key}", raw[band_key], unit, positive=True)
        center = _number(source, f"{key_path}.{center_key}", raw.get(center_key, 0.0), unit)
        for k in ("within_s", "stays_s"):
            if k not in raw:
                raise _err(source, f"{key_path}.{k}", "missing; expected a number > 0 (s)")
        within = _number(source, f"{key_path}.within_s", raw["within_s"], "s", positive=True)
        stays = _number(source, f"{key_path}.stays_s", raw["stays_s"], "s", positive=True)
        limit: dict[str, Any] = {"max": within}
        if raw.get("marginal_s") is not None:
            limit["marginal"] = _number(source, f"{key_path}.marginal_s", raw["marginal_s"],
                                        "s", nonneg=True)
            if limit["marginal"] > within:
                raise _err(source, f"{key_path}.marginal_s", f"marginal {limit['marginal']:g}"
                           f" s is wider than within_s {within:g} s")
        for key in raw:
            if key.startswith(("min_", "max_", "marginal_")) and key != "marginal_s":
                raise _err(source, f"{key_path}.{key}", "a settling criterion's limit is "
                           "within_s (and marginal_s, in s)")
        used.update({band_key, center_key, "within_s", "stays_s", "marginal_s"})
        window = _window(source, key_path, raw, used)
        if window.last_s is not None or window.to_s is not None:
            raise _err(source, f"{key_path}.{'last_s' if window.last_s else 'to_s'}",
                       "a settling criterion starts at after (+ from_s) and runs to the end")
        _check_keys(source, key_path, raw, used, f"{band_key}, {center_key}, within_s, "
                    "stays_s, marginal_s, after, from_s, why")
        return Criterion(name, "settles", key_path, target, "s", limit, window,
                         params={"band": band, "center": center, "stays_s": stays,
                                 "channel_unit": unit}, why=why)

    if form == "modal_residual":
        target = _channel(source, f"{key_path}.modal_residual", raw["modal_residual"],
                          channels)
        unit = unit_of_channel(target)
        modes = _modes(source, f"{key_path}.modes", raw.get("modes"))
        used.add("modes")
        limit = _band(source, key_path, raw, unit, target, used)
        window = _window(source, key_path, raw, used)
        _check_keys(source, key_path, raw, used, f"modes, min_{unit}, max_{unit}, "
                    f"marginal_{unit}, after, from_s, to_s, last_s, why")
        return Criterion(name, "modal_residual", key_path, target, unit, limit, window,
                         params={"modes": modes}, why=why)

    if form == "baseline":
        base = raw["baseline"]
        if not isinstance(base, str) or not base:
            raise _err(source, f"{key_path}.baseline", f"expected a run directory (or its "
                       f"run.rrd), relative to the run file or absolute, got {base!r}")
        p = Path(base)
        if not p.is_absolute():
            p = (base_dir or Path.cwd()) / p
        p = Path(str(p.resolve()))
        if check_files and not (p / "run.rrd").is_file() and not (
                p.is_file() and p.suffix == ".rrd"):
            raise _err(source, f"{key_path}.baseline", f"baseline {p} does not exist (expected"
                       " a run directory with run.rrd, or an .rrd file)")
        if "channel" not in raw:
            raise _err(source, f"{key_path}.channel", "missing; expected the channel to "
                       "compare, e.g. /attitude/angle_deg")
        target = _channel(source, f"{key_path}.channel", raw["channel"], channels)
        unit = unit_of_channel(target)
        used.add("channel")
        tol_key = f"tol_{unit}"
        for key in raw:
            if key.startswith("tol") and key not in (tol_key, "tol_rel_percent"):
                raise _err(source, f"{key_path}.{key}", f"{target} is in {unit}: expected "
                           f"{tol_key} (and tol_rel_percent)")
        if tol_key not in raw:
            raise _err(source, f"{key_path}.{tol_key}", f"missing; expected the absolute "
                       f"tolerance, a number >= 0 ({unit})")
        tol = _number(source, f"{key_path}.{tol_key}", raw[tol_key], unit, nonneg=True)
        rel = _number(source, f"{key_path}.tol_rel_percent", raw.get("tol_rel_percent", 0.0),
                      "percent", nonneg=True)
        shift = _number(source, f"{key_path}.max_shift_s", raw.get("max_shift_s", 0.0), "s",
                        nonneg=True)
        limit = {"tol": tol, "tol_rel_percent": rel, "max_shift_s": shift}
        mkey = f"marginal_{unit}"
        for key in raw:
            if key.startswith("marginal_") and key != mkey:
                raise _err(source, f"{key_path}.{key}", f"{target} is in {unit}: expected "
                           f"{mkey}")
        if raw.get(mkey) is not None:
            limit["marginal"] = _number(source, f"{key_path}.{mkey}", raw[mkey], unit,
                                        nonneg=True)
        used.update({tol_key, "tol_rel_percent", "max_shift_s", mkey})
        window = _window(source, key_path, raw, used)
        _check_keys(source, key_path, raw, used, f"channel, {tol_key}, tol_rel_percent, "
                    f"max_shift_s, {mkey}, after, from_s, to_s, last_s, why")
        return Criterion(name, "baseline", key_path, target, unit, limit, window,
                         params={"baseline": str(p)}, why=why)

    if form == "fault":
        device = raw["fault"]
        if not isinstance(device, str) or not device:
            raise _err(source, f"{key_path}.fault", f"expected the device the fault is "
                       f"detected on (e.g. hub_sensor, bus), got {device!r}")
        kind = raw.get("kind")
        if not isinstance(kind, str) or not kind:
            raise _err(source, f"{key_path}.kind", f"expected the kind the monitor reports "
                       f"(e.g. silent, frames lost; see 'harness faults'), got {kind!r}")
        used.update({"kind", "within_ticks"})
        limit = {}
        if raw.get("within_ticks") is not None:
            n = raw["within_ticks"]
            if isinstance(n, bool) or not isinstance(n, int) or n < 0:
                raise _err(source, f"{key_path}.within_ticks", f"expected an integer >= 0 "
                           f"(ticks after the injected fault's at_s), got {n!r}")
            limit["max"] = n
        _check_keys(source, key_path, raw, used, "fault, kind, within_ticks, why")
        return Criterion(name, "fault", key_path, device, "count", limit,
                         params={"kind": kind}, why=why)

    # left_safe
    if raw["left_safe"] is not True:
        raise _err(source, f"{key_path}.left_safe", f"expected true, got {raw['left_safe']!r}")
    _check_keys(source, key_path, raw, used, "left_safe, why")
    return Criterion(name, "left_safe", key_path, "can.blf", "count", {"max": 0}, why=why)


MODE_KEYS = ("omega_rad_s", "damping_ratio", "sigma_omega_rad_s", "sigma_damping")


def _modes(source: str, path: str, raw: Any) -> tuple[tuple[float, float], ...]:
    """A ``modal_residual:`` criterion's modes: ``[{omega_rad_s, damping_ratio}, ...]`` (the
    identification's sigmas may stay beside them, for the record)."""
    if not isinstance(raw, list) or not raw:
        raise _err(source, path, "expected a list of modes [{omega_rad_s: W, damping_ratio: "
                   f"Z}}, ...] (harness identify's), got {raw!r}")
    out = []
    for i, m in enumerate(raw):
        where = f"{path}[{i}]"
        if not isinstance(m, Mapping):
            raise _err(source, where, f"expected {{omega_rad_s, damping_ratio}}, got {m!r}")
        unknown = sorted(set(map(str, m)) - set(MODE_KEYS))
        if unknown:
            raise _err(source, f"{where}.{unknown[0]}", "unknown key (expected "
                       f"{', '.join(MODE_KEYS)})")
        if "omega_rad_s" not in m:
            raise _err(source, f"{where}.omega_rad_s", "missing; expected the mode's "
                       "undamped frequency, a number > 0 (rad/s)")
        w = _number(source, f"{where}.omega_rad_s", m["omega_rad_s"], "rad/s", positive=True)
        z = _number(source, f"{where}.damping_ratio", m.get("damping_ratio", 0.0), "ratio",
                    nonneg=True)
        if z >= 1:
            raise _err(source, f"{where}.damping_ratio", f"expected a ratio in [0, 1) (an "
                       f"oscillating mode), got {z!r}")
        for k in ("sigma_omega_rad_s", "sigma_damping"):
            if k in m:
                _number(source, f"{where}.{k}", m[k], "rad/s" if "omega" in k else "ratio",
                        nonneg=True)
        out.append((w, z))
    return tuple(out)


def unit_of_measure_name(path: str) -> str | None:
    from harness.testing.measures import unit_of_name
    return unit_of_name(path.rsplit(".", 1)[-1]) or (
        unit_of_name(path.split(".")[-2]) if "." in path else None)


def _items(raw: Any, source: str, key: str) -> list[tuple[str, str, Any]]:
    """(name, key path, raw criterion) of a mapping ``name: criterion`` (``null`` removes a
    criterion, for variants) or of a list (names from ``name:`` or the measure)."""
    if raw is None:
        return []
    if isinstance(raw, Mapping):
        out = []
        for name, c in raw.items():
            if not isinstance(name, str) or not name:
                raise _err(source, key, f"criterion names must be strings, got {name!r}")
            if c is not None:
                out.append((name, f"{key}.{name}", c))
        return out
    if isinstance(raw, list):
        out = []
        seen: set[str] = set()
        for i, c in enumerate(raw):
            path = f"{key}[{i}]"
            name = c.get("name") if isinstance(c, Mapping) else None
            if name is None and isinstance(c, Mapping):
                form = next((f for f in FORMS if f in c), None)
                name = f"{c.get(form)}" if form and form != "left_safe" else form
                name = str(name or path)
            if name in seen:
                name = f"{name}[{i}]"
            seen.add(name)
            if isinstance(c, Mapping):
                c = {k: v for k, v in c.items() if k != "name"}
            out.append((str(name), path, c))
        return out
    raise _err(source, key, f"expected a mapping NAME: criterion (or a list of criteria), "
               f"got {raw!r}")


def parse_criteria(raw: Any, source: str = "expect", known_measures: Iterable[str] | None = None,
                   channels: Iterable[str] | None = None, key: str = "expect",
                   base_dir: Path | None = None, check_files: bool = True,
                   open_paths: bool = False) -> list[Criterion]:
    """Every criterion of an ``expect:`` section (a mapping ``name: criterion`` or a list),
    checked; raises ConfigError naming ``source`` and the key path. ``channels`` defaults
    to the loop's recorded channels; pass ``channels=()`` to judge results without a
    recording (scalar criteria only)."""
    if channels is None:
        from harness.core.loop import CHANNELS
        channels = CHANNELS
    channels = list(channels)
    return [parse_criterion(name, c, source, path, known_measures, channels, base_dir,
                            check_files, open_paths) for name, path, c in _items(raw, source, key)]


OVERRIDABLE_PREFIXES = ("min_", "max_", "max_abs_", "equals_", "len_min_", "len_max_",
                        "marginal_", "tol_", "band_")
OVERRIDABLE_KEYS = ("within_s", "stays_s", "within_ticks", "max_shift_s", "tol_rel_percent")


def apply_overrides(expect: Any, overrides: Any, source: str,
                    key: str = "expect_overrides") -> Any:
    """``expect`` with a rig file's ``expect_overrides: {name: {limit key: value}}`` applied.
    Only limit keys may be overridden (a rig changes how much, not what is measured);
    names the run does not have are ignored (one rig file serves every run)."""
    if not overrides:
        return expect
    if not isinstance(overrides, Mapping):
        raise _err(source, key, f"expected a mapping NAME: {{limit key: value}}, got "
                   f"{overrides!r}")
    for name, over in overrides.items():
        if not isinstance(over, Mapping):
            raise _err(source, f"{key}.{name}", f"expected a mapping of limit keys, got "
                       f"{over!r}")
        for k in over:
            if not (str(k).startswith(OVERRIDABLE_PREFIXES) or k in OVERRIDABLE_KEYS):
                raise _err(source, f"{key}.{name}.{k}", "only limits can be overridden "
                           f"(keys starting {', '.join(OVERRIDABLE_PREFIXES)} or "
                           f"{', '.join(OVERRIDABLE_KEYS)})")
    if not isinstance(expect, Mapping):
        return expect  # a list has no names to override by; parse_criteria reports it
    out = copy.deepcopy(dict(expect))
    for name, over in overrides.items():
        if isinstance(out.get(name), Mapping):
            merged = dict(out[name])
            merged.update(over)
            out[name] = merged
    return out


def resolve_baselines(expect: Any, base_dir: Path) -> Any:
    """``expect`` with every relative ``baseline:`` made absolute against ``base_dir`` (the
    run file's folder), so config.yaml can be judged again from anywhere."""
    def fix(c: Any) -> Any:
        if isinstance(c, Mapping) and isinstance(c.get("baseline"), str) and c["baseline"]:
            p = Path(c["baseline"])
            return {**c, "baseline": str((p if p.is_absolute() else base_dir / p).resolve())}
        return c
    if isinstance(expect, Mapping):
        return {k: fix(v) for k, v in expect.items()}
    if isinstance(expect, list):
        return [fix(c) for c in expect]
    return expect
