"""What a criterion can measure: summary.json's fields and the recorded channels, with units.

The unit of a measure is the suffix of its name (``final_angle_error_deg`` is in ``deg``,
``lateness_ms.p99`` in ``ms`` from its parent); names without a unit suffix are dimensionless:
``count`` (integers: ``overruns``, ``frames.missing``, names ending ``_count``) or ``ratio``
(``real_time_factor``, ``beta``). A criterion's limit keys carry the same unit
(``max_abs_deg``, ``max_count``).

Paths (``resolve``) are dotted, with ``[N]`` / ``[*]`` into lists, and keys may contain dots
(the longest key that matches wins): ``modes[*].omega_error_percent``,
``laws.tip_deflection_m.best_beta_median_lambda_gt_0.5``.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable, Mapping
from typing import Any

from drivers.binding.quantities import DEVICES

UNIT_SUFFIXES = ("deg_s", "rad_s", "m_s2", "n_m", "percent", "count", "hz", "ms", "deg", "rad",
                 "kg", "m", "s", "v", "a")
"""Unit suffixes, longest first where one ends another (``deg_s`` before ``s``)."""

DIMENSIONLESS = ("count", "ratio")

# summary.json (harness/core/session.py summarise / periodic_summary): path -> unit. Every
# numeric or boolean leaf is here; tests check it against a real summary.json.
SUMMARY_MEASURES: dict[str, str] = {
    "rate_hz": "hz",
    "ticks": "count",
    "target_angle_deg": "deg",
    "final_angle_deg": "deg",
    "final_angle_error_deg": "deg",
    "slew_profile_end_s": "s",
    "settle_time_s": "s",
    "settle_band_deg": "deg",
    "peak_tip_accel_m_s2": "m_s2",
    "residual_tip_accel_m_s2": "m_s2",
    "residual_tip_accel_rms_m_s2": "m_s2",
    "residual_window_s": "s",
    "max_wheel_torque_cmd_n_m": "n_m",
    "max_wheel_torque_measured_n_m": "n_m",
    "wheel_torque_limit_n_m": "n_m",
    "wheel_torque_within_limit": "bool",
    "overruns": "count",
    "lateness_ms.p50": "ms",
    "lateness_ms.p99": "ms",
    "lateness_ms.max": "ms",
    "work_ms.p50": "ms",
    "work_ms.p99": "ms",
    "work_ms.max": "ms",
    "bus_load_percent": "percent",
    "frames.sent": "count",
    "frames.received": "count",
    "frames.unknown": "count",
    "frames.malformed": "count",
    "frames.missing": "count",
    "frames.missing_in_ticks_on_time": "count",
    "overrun_episodes": "count",
    "frames.missing_in_ticks_host_delayed": "count",
    "frames.missing_in_ticks_rig_preempted": "count",
    "frames.missing_in_ticks_held_by_both": "count",
    "frames.missing_rig_answered_after_window": "count",
    "frames.error_frames": "count",
    "frames.not_sent": "count",
    "frames.dropped_by_kernel": "count",
    "wall_time_s": "s",
    "simulated_time_s": "s",
    "real_time_factor": "ratio",
    "virtual_rig.watchdog_trips": "count",
    "virtual_rig.steps": "count",
    "virtual_rig.malformed": "count",
    "virtual_rig.unknown": "count",
    "virtual_rig.repeated": "count",
    "dry_run": "bool",
    # the controller's step() time per tick against its budget (docs/controllers.md)
    "controller.step_budget_ms": "ms",
    "controller.step_mean_ms": "ms",
    "controller.step_max_ms": "ms",
    "controller.ticks_over_budget": "count",
    "controller.over_budget": "bool",
    # periodic disturbance runs (case-a/b/c)
    "rotor_speed_rad_s": "rad_s",
    "rotor_period_s": "s",
    "beta": "ratio",
    "frequency_ratio": "ratio",
    "disturbance_amplitude_n_m": "n_m",
    "compensation_amplitude_n_m": "n_m",
    "steady_window_s": "s",
    "steady_tip_accel_amplitude_m_s2": "m_s2",
    "steady_angle_amplitude_deg": "deg",
    # computed by the judge from summary.json's lists
    "faults.count": "count",
    # computed by the judge from summary.json's timing (BENCH_MEASURES): the bench's health
    "timing.overruns_percent": "percent",
    "timing.lateness_p99_period_percent": "percent",
    "timing.missing_held_percent": "percent",
    # the fault monitor's warnings, per kind (harness.core.monitor.WARNING_KINDS)
    "monitor_warnings.wheel_speed": "count",
    "monitor_warnings.torque_saturated": "count",
    "monitor_warnings.hub_angle": "count",
    "monitor_warnings.hub_rate": "count",
    "monitor_warnings.tip_accel": "count",
    "monitor_warnings.accel_range": "count",
    "monitor_warnings.telemetry_missing": "count",
    # what the monitor held to be the bench's, not a device's (docs/faults.md)
    "monitor_bench.stalls": "count",
    "monitor_bench.behind_episodes": "count",
    "monitor_bench.longest_stall_s": "s",
    "monitor_bench.stale_physics_windows": "count",
    # timing on the wire (harness.core.wire_timing): null where the bus cannot measure it
    "wire_timing.syncs_time_stamped": "count",
    "wire_timing.sync_echoes_late": "count",
    **{f"wire_timing.sync_period_jitter_ms.{k}": "ms"
       for k in ("p50", "p99", "max", "min_signed", "max_signed")},
    **{f"wire_timing.command_margin_ms.{k}": "ms" for k in ("p50", "p99", "max", "min")},
    "wire_timing.command_margin_ms.commands_after_next_sync": "count",
    **{f"wire_timing.answer_latency_ms.{d}.{k}": "ms"
       for d in DEVICES for k in ("p50", "p99", "max")},
}

OPEN_PREFIXES = ("controller_design.",)
"""Summary sections whose fields depend on the controller: any path under them is accepted,
its unit read from its name (``ratio`` without a suffix); a path the run did not write is
missing data at judge time (ERROR)."""

BUDGET_MEASURES = ("overruns", "lateness_ms.", "work_ms.", "real_time_factor", "frames.missing",
                   "frames.dropped_by_kernel",
                   "timing.", "wire_timing.sync_period_jitter_ms.",
                   "wire_timing.command_margin_ms.")
"""Measures of the real-time budget: a criterion on them that fails makes the verdict
INCONCLUSIVE (the bench did not hold its time: the test measured nothing trustworthy), not
FAIL. A criterion's ``budget: true|false`` overrides this."""

TIME_EVENTS = ("slew_profile_end_s", "settle_time_s", "fault", "injected_fault")
"""Events a window can start ``after``: summary times, the first detected fault's time, the
first injected fault's ``at_s``."""

NULL_MEANS_FAIL = {
    "settle_time_s": "the hub never stayed within settle_band_deg of the target",
}
"""Summary fields whose null is a result (FAIL), not missing data (ERROR)."""


WORST_SAMPLE: dict[str, tuple[str, str]] = {
    "peak_tip_accel_m_s2": ("/tip/accel_m_s2", "abs"),
    "residual_tip_accel_m_s2": ("/tip/accel_m_s2", "abs_residual"),
    "max_wheel_torque_cmd_n_m": ("/wheel/torque_cmd_n_m", "abs"),
    "max_wheel_torque_measured_n_m": ("/wheel/torque_n_m", "abs"),
    "final_angle_deg": ("/attitude/angle_deg", "last"),
    "final_angle_error_deg": ("/attitude/error_deg", "last"),
}
"""Summary peaks and finals whose sample the recording can name: (channel, how); the
judge reports that sample's time as the criterion's ``worst_time_s``."""


def unit_of_name(name: str) -> str | None:
    """The unit suffix of a name (``accel_m_s2`` -> ``m_s2``), or None."""
    for u in UNIT_SUFFIXES:
        if name == u or name.endswith("_" + u):
            return u
    return None


def unit_of_measure(path: str) -> str | None:
    """Unit of a summary path, or None if the path is not a known measure."""
    if path in SUMMARY_MEASURES:
        return SUMMARY_MEASURES[path]
    if path.startswith(OPEN_PREFIXES) and len(path) > len(path.split(".")[0]) + 1:
        parts = path.split(".")
        for part in reversed(parts[1:]):
            u = unit_of_name(part)
            if u is not None:
                return u
        return "ratio"
    return None


def unit_of_channel(entity: str) -> str:
    """Unit of a recorded channel from its last path segment (``count`` if it has none:
    ``/thrusters/firings``, ``/timing/frames_rx``)."""
    return unit_of_name(entity.rstrip("/").rsplit("/", 1)[-1]) or "count"


def is_budget(path: str) -> bool:
    return any(path == b or (b.endswith(".") and path.startswith(b)) for b in BUDGET_MEASURES)


_INDEX = re.compile(r"\[(\*|-?\d+)\]")


def unit_of_path(path: str) -> str | None:
    """Unit of a field of any JSON document (a study's ``--json``, ``identify --json``, the
    probe report, summary.json): summary.json's own table first, then the suffix of the
    key (or of its parent: ``lateness_ms.p99``); None if the name has none (dimensionless:
    the criterion says ``ratio`` or ``count``)."""
    plain = _INDEX.sub("", path)
    known = unit_of_measure(plain)
    if known is not None:
        return known
    parts = [p for p in plain.split(".") if p]
    for part in reversed(parts[-2:]):
        u = unit_of_name(part)
        if u is not None:
            return u
    return None


class FieldMissing(LookupError):
    """A path names nothing in the document (the message says where it stopped)."""


def path_error(path: str) -> str | None:
    """What is wrong with a path's syntax (None: fine)."""
    if not isinstance(path, str) or not path.strip():
        return f"expected a field path such as a.b[*].c, got {path!r}"
    rest = _INDEX.sub("", path)
    if "[" in rest or "]" in rest:
        return f"{path!r}: a list index is [N] or [*]"
    return None


def resolve(doc: Any, path: str) -> list[tuple[str, Any]]:
    """Every (concrete path, value) that ``path`` names in ``doc``: one for a plain path,
    one per element for ``[*]``. Keys may contain dots: at each level the longest key that
    matches the rest of the path wins. Raises FieldMissing."""
    out: list[tuple[str, Any]] = []

    def walk(node: Any, rest: str, here: str) -> None:
        if not rest:
            out.append((here, node))
            return
        m = _INDEX.match(rest)
        if m:
            if not isinstance(node, list):
                raise FieldMissing(f"{here or '(top)'}: not a list")
            idx = m.group(1)
            tail = rest[m.end():].removeprefix(".")
            if idx == "*":
                for i, v in enumerate(node):
                    walk(v, tail, f"{here}[{i}]")
            else:
                try:
                    walk(node[int(idx)], tail, f"{here}[{idx}]")
                except IndexError:
                    raise FieldMissing(f"{here}[{idx}]: no such element") from None
            return
        if not isinstance(node, Mapping):
            raise FieldMissing(f"{here or '(top)'}: not a mapping")
        for key in sorted((k for k in node if isinstance(k, str)), key=len, reverse=True):
            if rest == key or rest.startswith(key + ".") or rest.startswith(key + "["):
                walk(node[key], rest[len(key):].removeprefix("."),
                     f"{here}.{key}" if here else key)
                return
        raise FieldMissing(f"{here + '.' if here else ''}{rest.split('.')[0]}: no such field "
                           f"(fields here: {', '.join(sorted(map(str, node)))[:300]})")

    walk(doc, path, "")
    return out


def find(measures: Mapping[str, Any], path: str) -> list[tuple[str, Any]]:
    """``resolve`` with the judge's computed measures (``faults.count``: the length of the
    faults list). Raises FieldMissing."""
    if path == "faults.count":
        faults = measures.get("faults")
        if not isinstance(faults, list):
            raise FieldMissing("faults: no faults list")
        return [(path, len(faults))]
    if path in BENCH_MEASURES:
        return [(path, BENCH_MEASURES[path](measures))]
    return resolve(measures, path)


def _number(measures: Mapping[str, Any], path: str) -> float:
    found = resolve(measures, path)
    v = found[0][1] if len(found) == 1 else None
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        raise FieldMissing(f"{path}: not a number ({v!r})")
    return float(v)


def _share(part: float, whole: float) -> float:
    return 100.0 * part / whole if whole > 0 else 0.0


BENCH_MEASURES: dict[str, Any] = {
    # overruns: ticks whose work ended after the next tick's deadline, of all ticks
    "timing.overruns_percent": lambda m: _share(_number(m, "overruns"), _number(m, "ticks")),
    # the loop's lateness (how long after its deadline a tick started), p99, of the period
    "timing.lateness_p99_period_percent": lambda m: _share(
        _number(m, "lateness_ms.p99"), 1e3 / _number(m, "rate_hz")),
    # telemetry frames missing in ticks the loop held, of the frames due (received + missing)
    "timing.missing_held_percent": lambda m: _share(
        _number(m, "frames.missing_in_ticks_on_time"),
        _number(m, "frames.received") + _number(m, "frames.missing")),
}
"""The bench's health as shares, computed by the judge from summary.json: the measures of
the timing criteria every real-time run gets (``harness.testing.bench``)."""


def numeric_leaves(data: Mapping[str, Any], prefix: str = "") -> Iterable[str]:
    """Dotted paths of every number or bool in a nested mapping (lists excluded)."""
    for k, v in data.items():
        p = f"{prefix}{k}"
        if isinstance(v, Mapping):
            yield from numeric_leaves(v, p + ".")
        elif isinstance(v, bool | int | float) and not (isinstance(v, float) and math.isnan(v)):
            yield p


UNIT_TEXT = {"n_m": "N m", "n_m_s": "N m s", "m_s2": "m/s^2", "deg_s": "deg/s",
             "rad_s": "rad/s", "m_s": "m/s", "percent": "%", "hz": "Hz", "v": "V", "a": "A",
             "bool": "", "count": "", "ratio": ""}
"""How a unit suffix reads where people read it (messages, the printed block, the docs'
tables); the keys keep the suffix (``max_n_m``)."""


def unit_text(unit: str) -> str:
    """``n_m`` -> ``N m``, ``m_s2`` -> ``m/s^2``; a unit without a spelling (deg, s, m) as it
    is."""
    return UNIT_TEXT.get(unit, unit)
