"""Judging a run directory: criteria from its config.yaml (or an ``--expect`` file) against
its summary.json, run.rrd and can.blf; writes verdict.json and verdict.rrd beside them.

A pure function of the directory's files (and the judging code): the end of ``harness run``
and ``harness judge`` call the same ``judge_run`` and write the same verdict.json.
"""

from __future__ import annotations

import functools
import hashlib
import importlib.metadata
import json
import subprocess
import sys
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from harness.record.streams import save_with_blueprint, sweep_orphans
from harness.testing.bench import attribute, describe, is_realtime, timing_criteria
from harness.testing.criteria import Criterion, apply_overrides, parse_criteria
from harness.testing.evaluate import (
    ERROR,
    INCONCLUSIVE,
    MAX_EVENTS,
    NO_CRITERIA,
    CriterionResult,
    Facts,
    MissingData,
    evaluate,
    exit_code,
    not_judged,
    reason,
    run_checks,
    stopped_early,
    worst_verdict,
)
from harness.testing.frf_criterion import frf_source
from harness.testing.measures import unit_text
from harness.testing.steps import first_injection_s, step_results, without_sequence_faults
from rig_models.rig_file import binding_text, rig_identity
from rig_models.schema import ConfigError

APPLICATION_ID = "sgsrt-harness"  # as harness.record.recording's (same recording in the viewer)
PACKAGE = "sgsrt-harness"


class JudgeInputError(ValueError):
    """The directory or the criteria cannot be judged at all (exit 2)."""


@dataclass
class Verdict:
    verdict: str
    reason: str
    criteria: list[CriterionResult]
    identity: dict[str, Any]
    run_dir: Path | None = None
    exit_code: int = 0
    extra: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        d = {"verdict": self.verdict, "reason": self.reason, "exit_code": self.exit_code,
             "criteria": [c.to_dict() for c in self.criteria], "identity": self.identity}
        if "bench" in self.extra:  # an INCONCLUSIVE run: whose the lost time was
            d["bench"] = self.extra["bench"]
        return d


def make_verdict(results: list[CriterionResult], identity: Mapping[str, Any] | None = None,
                 run_dir: Path | None = None) -> Verdict:
    """The worst of ``results`` wins; no results is NO CRITERIA (nothing judged), not PASS."""
    v = worst_verdict(results) if results else NO_CRITERIA
    return Verdict(v, reason(v, results), results, dict(identity or {}), run_dir,
                   exit_code(v, results))


# ----------------------------------------------------------------------------- identity
def sha256_of(path: Path) -> str | None:
    if not path.is_file():
        return None
    h = hashlib.sha256()
    with path.open("rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _run_rrd_sha256(run_dir: Path) -> str | None:
    """run.rrd's own bytes (the verdict appended to it is not the run: harness.review)."""
    try:
        from harness.review.verdict import run_rrd_sha256

        return run_rrd_sha256(run_dir)
    except Exception:  # noqa: BLE001 - the whole file's hash then
        return sha256_of(run_dir / "run.rrd")


@functools.cache
def source_commit() -> str:
    """``git rev-parse HEAD`` of the harness's source tree, or "unknown"."""
    try:
        out = subprocess.run(["git", "rev-parse", "HEAD"], cwd=Path(__file__).parent,
                             capture_output=True, text=True, timeout=5, check=False)
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return out.stdout.strip() if out.returncode == 0 and out.stdout.strip() else "unknown"


def harness_version() -> str:
    try:
        return importlib.metadata.version(PACKAGE)
    except importlib.metadata.PackageNotFoundError:
        return "unknown"


def run_rig_identity(cfg: Mapping[str, Any], summary: Mapping[str, Any]) -> dict[str, Any]:
    """The rig identity of a run (``rig_models.rig_file.rig_identity``): summary.json's, as
    the run computed it, else computed from config.yaml's resolved rig (a run that wrote no
    summary, or one from before summaries named their rig)."""
    run = cfg.get("run") if isinstance(cfg.get("run"), Mapping) else {}
    rig = cfg.get("rig") if isinstance(cfg.get("rig"), Mapping) else None
    bus = summary.get("bus") or run.get("bus")
    bus = bus if isinstance(bus, str) else None
    if isinstance(summary.get("rig_sha256"), str) and isinstance(summary.get("rig"), str):
        binding = summary.get("binding")
        return {"rig": summary["rig"], "rig_sha256": summary["rig_sha256"], "bus": bus,
                "binding": binding if isinstance(binding, Mapping) else None}
    if rig is None:
        return {"rig": None, "rig_sha256": None, "bus": bus, "binding": None}
    return rig_identity(rig, bus)


def identity_of(run_dir: Path, cfg: Mapping[str, Any], summary: Mapping[str, Any],
                expect_file: Path | None) -> dict[str, Any]:
    run = cfg.get("run") if isinstance(cfg.get("run"), Mapping) else {}
    rig = run_rig_identity(cfg, summary)
    return {
        "run": summary.get("run") or run.get("name"),
        "recording_id": run_dir.name,
        "harness_version": harness_version(),
        "commit": source_commit(),
        "rig": rig["rig"],
        "rig_sha256": rig["rig_sha256"],
        "bus": rig["bus"],
        "binding": rig["binding"],
        "clock": summary.get("clock") or run.get("clock"),
        "config_sha256": sha256_of(run_dir / "config.yaml"),
        "summary_sha256": sha256_of(run_dir / "summary.json"),
        "run_rrd_sha256": _run_rrd_sha256(run_dir),
        "can_blf_sha256": sha256_of(run_dir / "can.blf"),
        "criteria_from": "config.yaml" if expect_file is None else expect_file.name,
        "expect_sha256": None if expect_file is None else sha256_of(expect_file),
    }


# ----------------------------------------------------------------------------- readers
def _scalars(chunk: Any, wanted: set[str] | None) -> tuple[np.ndarray, np.ndarray] | None:
    """(time s, values) of a chunk of a scalar channel on the ``time`` timeline, or None."""
    if chunk.is_static or "time" not in chunk.timeline_names or (
            wanted is not None and chunk.entity_path not in wanted):
        return None
    batch = chunk.to_record_batch()
    if "Scalars:scalars" not in batch.schema.names:
        return None
    t = batch.column("time").cast("int64").to_numpy(zero_copy_only=False) * 1e-9
    from harness.record.reader import scalar_values  # lazy, as _chunks

    return t, scalar_values(batch.column("Scalars:scalars"))


def _chunks(rrd: Path, wanted: set[str] | None) -> Any:
    from harness.record.reader import iter_chunks  # lazy, quiet on footer-less files

    return iter_chunks(rrd, content=sorted(wanted)) if wanted is not None \
        else iter_chunks(rrd, drop="/bus/**")


def read_channels(rrd: Path, wanted: set[str] | None = None
                  ) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The scalar channels of a recording on the ``time`` timeline (``wanted`` ones, or
    all), in one pass, each whole."""
    parts: dict[str, tuple[list[np.ndarray], list[np.ndarray]]] = {}
    for chunk in _chunks(rrd, wanted):
        if (tx := _scalars(chunk, wanted)) is None:
            continue
        ts, vs = parts.setdefault(chunk.entity_path, ([], []))
        ts.append(tx[0])
        vs.append(tx[1])
    return {entity: _in_time_order(ts, vs) for entity, (ts, vs) in parts.items()}


def _in_time_order(ts: list[np.ndarray], vs: list[np.ndarray]
                   ) -> tuple[np.ndarray, np.ndarray]:
    """A channel's chunks joined and sorted by time (stable: equal times keep their order)."""
    t, v = np.concatenate(ts), np.concatenate(vs)
    order = np.argsort(t, kind="stable")
    return t[order], v[order]


ENVELOPE_BUCKETS = 4000
"""Time buckets of a plotted channel (``read_envelopes``): a plot is a few hundred pixels
wide, so 4000 minimum/maximum pairs draw what every sample would."""


def read_envelopes(rrd: Path, wanted: set[str], t_end_s: float,
                   buckets: int = ENVELOPE_BUCKETS) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The ``wanted`` scalar channels for a plot, in memory bounded by ``buckets`` whatever
    the run's length, in one streaming pass: a channel of at most ``2 * buckets`` samples
    comes back whole; a longer one as its minimum and maximum in each of ``buckets`` equal
    time buckets over [0, ``t_end_s``] (later samples go to the last), two points per
    bucket at its centre, minimum first. NaNs are skipped. Without a length (``t_end_s`` 0:
    no summary) each channel comes back whole."""
    if t_end_s <= 0:
        return read_channels(rrd, wanted)
    width = t_end_s / buckets
    raw: dict[str, tuple[list[np.ndarray], list[np.ndarray], list[int]]] = {}
    env: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for chunk in _chunks(rrd, wanted):
        if (tx := _scalars(chunk, wanted)) is None:
            continue
        name = chunk.entity_path
        t, v = tx
        if name not in env:
            ts, vs, n = raw.setdefault(name, ([], [], [0]))
            ts.append(t)
            vs.append(v)
            n[0] += len(t)
            if n[0] <= 2 * buckets:
                continue
            t, v = np.concatenate(ts), np.concatenate(vs)
            del raw[name]
            env[name] = (np.full(buckets, np.inf), np.full(buckets, -np.inf))
        lo, hi = env[name]
        b = np.clip((t / width).astype(np.int64), 0, buckets - 1)
        order = np.argsort(b, kind="stable")
        b, v = b[order], v[order]
        starts = np.flatnonzero(np.r_[True, b[1:] != b[:-1]])
        idx = b[starts]
        lo[idx] = np.fmin(lo[idx], np.fmin.reduceat(v, starts))
        hi[idx] = np.fmax(hi[idx], np.fmax.reduceat(v, starts))
    out = {name: _in_time_order(ts, vs) for name, (ts, vs, _) in raw.items()}
    centres = (np.arange(buckets) + 0.5) * width
    for name, (lo, hi) in env.items():
        keep = np.isfinite(lo)
        out[name] = (np.repeat(centres[keep], 2), np.column_stack((lo[keep], hi[keep])).ravel())
    return out


class ChannelCache:
    """Reads a recording once, on first use (only ``wanted`` channels if given), each
    channel whole (a baseline run's)."""

    def __init__(self, rrd: Path, wanted: set[str] | None = None) -> None:
        self.rrd = rrd
        self.wanted = wanted
        self._data: dict[str, tuple[np.ndarray, np.ndarray]] | None = None

    def __call__(self, entity: str) -> tuple[np.ndarray, np.ndarray]:
        if self._data is None:
            self._data = _read(self.rrd, self.wanted)
        if entity not in self._data:
            raise KeyError(f"{self.rrd.name} has no channel {entity}")
        return self._data[entity]


def _read(rrd: Path, wanted: set[str] | None) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    if not rrd.is_file():
        raise MissingData(f"{rrd} does not exist")
    try:
        return read_channels(rrd, wanted)
    except Exception as exc:  # a damaged recording: rerun raises various kinds
        raise MissingData(f"{rrd}: cannot read ({type(exc).__name__}: {exc})") from exc


class ChannelSource:
    """The run's recording for the judge: ``blocks`` streams the channels asked for in one
    pass, a chunk at a time (memory bounded by a chunk, whatever the run's length);
    ``__call__`` reads one channel whole (a baseline criterion's own run, or a channel whose
    chunks are not in time order)."""

    def __init__(self, rrd: Path) -> None:
        self.rrd = rrd
        self._seen: set[str] | None = None  # the channels the last pass found

    def blocks(self, entities: list[str]) -> Iterator[tuple[str, np.ndarray, np.ndarray]]:
        if not self.rrd.is_file():
            raise MissingData(f"{self.rrd} does not exist")
        wanted, seen = set(entities), set()
        try:
            for chunk in _chunks(self.rrd, wanted):
                if (tx := _scalars(chunk, wanted)) is not None:
                    seen.add(chunk.entity_path)
                    yield chunk.entity_path, tx[0], tx[1]
        except Exception as exc:  # a damaged recording: rerun raises various kinds
            raise MissingData(f"{self.rrd}: cannot read ({type(exc).__name__}: {exc})"
                              ) from exc
        self._seen = seen

    def __call__(self, entity: str) -> tuple[np.ndarray, np.ndarray]:
        if self._seen is not None and entity not in self._seen:
            raise KeyError(f"{self.rrd.name} has no channel {entity}")
        data = _read(self.rrd, {entity})
        if entity not in data:
            raise KeyError(f"{self.rrd.name} has no channel {entity}")
        return data[entity]


class BaselineCache:
    def __init__(self, wanted: set[str] | None = None) -> None:
        self.wanted = wanted
        self._runs: dict[str, ChannelCache] = {}

    def __call__(self, base: str, entity: str) -> tuple[np.ndarray, np.ndarray]:
        p = Path(base)
        rrd = p if p.suffix == ".rrd" else p / "run.rrd"
        if base not in self._runs:
            self._runs[base] = ChannelCache(rrd, self.wanted)
        return self._runs[base](entity)


# what each device's last command must say for the rig to be left safe (quantities of
# drivers.binding.quantities: the same whatever the protocol)
SAFE_QUANTITIES = {
    "reaction_wheel": (("torque_cmd", "wheel torque"), ("enable", "wheel enable")),
    "thruster_valves": (("valve_pos", "positive valve"), ("valve_neg", "negative valve")),
    "piezo_amplifier": (("voltage_ch1", "piezo ch1 voltage"),
                        ("voltage_ch2", "piezo ch2 voltage")),
    "disturbance_rotor": (("speed_cmd", "rotor speed"), ("enable", "rotor enable")),
}
NMT_SAFE = {0x80: "pre-operational", 0x02: "stopped"}


def left_safe_problems(blf: Path, rig_data: Mapping[str, Any] | None = None) -> list[str]:
    """What the CAN log's last command frame of each device leaves unsafe, decoded through
    the run's rig binding (``rig_data``: config.yaml's rig; sgsrt's when absent): wheel
    torque 0 and disabled, valves closed, piezo 0 V, rotor stopped and disabled; the
    heartbeat disarmed (sgsrt, a DBC) or every CANopen node sent to pre-operational (or
    stopped) after the last command. A frame never sent is nothing commanded."""
    import can

    from drivers.binding import BindingError, build_binding
    from drivers.dbc import FrameError
    from harness.record.blf_frames import frame_tuple, read_frames

    if not blf.is_file():
        raise MissingData(f"{blf} does not exist")
    try:
        binding = build_binding(rig_data or {"bus": {}})
    except BindingError as exc:
        raise MissingData(f"the run's rig binding: {exc}") from exc
    cmd_keys = binding.commands_by_key()
    hb = binding.heartbeat if binding.canopen is None else None
    last: dict[tuple[int, bool], bytes] = {}
    last_nmt: int | None = None
    commanded_after_nmt = False
    # the harness's can.blf through the fast reader (python-can's for another format)
    frames = (read_frames(blf) if blf.suffix.lower() == ".blf" else
              map(frame_tuple, can.LogReader(str(blf))))
    try:
        for _ts, cid, ext, _remote, is_error, _rx, _dlc, data, _ch in frames:
            if is_error:
                continue
            key = (cid, ext)
            if key in cmd_keys or (hb is not None and key == hb.key):
                last[key] = data
                commanded_after_nmt = True
            elif binding.canopen is not None and key == (0, False) and len(data) >= 1:
                last_nmt, commanded_after_nmt = data[0], False
    except Exception as exc:  # python-can raises many kinds for a damaged file
        raise MissingData(f"{blf}: cannot read ({type(exc).__name__}: {exc})") from exc
    problems = []
    for key, cmaps in cmd_keys.items():
        if key not in last:
            continue
        for cmap in cmaps:
            try:
                values = cmap.decode(last[key])
            except FrameError:
                problems.append(f"last {cmap.codec.name} undecodable ({last[key].hex()})")
                continue
            if values is None:
                continue
            for quantity, what in SAFE_QUANTITIES.get(cmap.device, ()):
                if quantity in values and values[quantity] != 0:
                    problems.append(f"last {cmap.codec.name}: {what} {values[quantity]:g}")
    if hb is not None and hb.key in last:
        try:
            if hb.decode_armed(last[hb.key]):
                problems.append(f"last {hb.codec.name}: heartbeat armed 1")
        except FrameError:
            problems.append(f"last {hb.codec.name} undecodable ({last[hb.key].hex()})")
    if binding.canopen is not None and last:
        if last_nmt not in NMT_SAFE or commanded_after_nmt:
            problems.append("CANopen: the nodes were not sent to pre-operational (or stopped) "
                            "after the last command")
    return problems


# ----------------------------------------------------------------------------- judging
def _rig_data(cfg: Mapping[str, Any]) -> Mapping[str, Any] | None:
    rig = cfg.get("rig") if isinstance(cfg, Mapping) else None
    return rig if isinstance(rig, Mapping) else None


def _load_yaml(path: Path) -> Any:
    from rig_models.yaml_file import load_yaml

    try:
        return load_yaml(path, "YAML file")
    except ConfigError as exc:
        raise JudgeInputError(str(exc)) from exc


def _run_config(cfg_path: Path, loaded: Any, own_criteria: bool) -> Mapping[str, Any]:
    """config.yaml as the harness wrote it (``run:`` and ``rig:`` mappings); else
    ``JudgeInputError`` naming the key: a ``run:`` of another shape (a number) would read
    as a run without criteria (NO CRITERIA, exit 0) when its criteria were lost."""
    from rig_models.schema import short_repr

    if not isinstance(loaded, Mapping):
        raise JudgeInputError(f"{cfg_path}: expected a mapping with run: and rig: (as the "
                              f"harness writes it), got {short_repr(loaded)}")
    run = loaded.get("run")
    if run is None and own_criteria:
        raise JudgeInputError(f"{cfg_path}: run: missing; the run's criteria are under it "
                              "(or give --expect FILE)")
    if run is not None and not isinstance(run, Mapping):
        raise JudgeInputError(f"{cfg_path}: run: expected the run's mapping (as the harness "
                              f"writes it), got {short_repr(run)}")
    rig = loaded.get("rig")
    if rig is not None and not isinstance(rig, Mapping):
        raise JudgeInputError(f"{cfg_path}: rig: expected the rig's mapping (as the harness "
                              f"writes it), got {short_repr(rig)}")
    return loaded


def criteria_of(run_dir: Path, cfg: Mapping[str, Any], expect: Any = None
                ) -> tuple[list[Criterion], Path | None]:
    """The criteria to judge ``run_dir`` by: ``expect`` (a file with an ``expect:`` section,
    or the section itself) or the run's own (config.yaml), with the rig's
    ``expect_overrides`` applied."""
    rig = cfg.get("rig") if isinstance(cfg.get("rig"), Mapping) else {}
    overrides = rig.get("expect_overrides")
    expect_file = None
    if expect is None:
        run = cfg.get("run") if isinstance(cfg.get("run"), Mapping) else {}
        raw, source, base_dir, check = run.get("expect"), f"{run_dir / 'config.yaml'}: run", \
            run_dir, False
    elif isinstance(expect, str | Path):
        expect_file = Path(expect)
        if not expect_file.is_file():
            raise JudgeInputError(f"--expect {expect_file}: no such file")
        doc = _load_yaml(expect_file)
        raw = doc.get("expect") if isinstance(doc, Mapping) and "expect" in doc else doc
        source, base_dir, check = f"expect file {expect_file.name}", expect_file.parent, True
    else:
        raw, source, base_dir, check = expect, "expect", Path.cwd(), True
    raw = apply_overrides(raw, overrides, f"{run_dir / 'config.yaml'}: rig")
    return parse_criteria(raw, source, base_dir=base_dir, check_files=check), expect_file


def judge_run(run_dir: Path | str, expect: Any = None) -> Verdict:
    """Judge a run directory (see the module docstring). ``expect``: None (the run's own
    criteria from config.yaml), a path to a YAML file (an ``expect:`` section or a run
    file), or the section itself. Raises JudgeInputError / ConfigError for bad input."""
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise JudgeInputError(f"{run_dir}: not a directory")
    cfg_path = run_dir / "config.yaml"
    cfg: Mapping[str, Any] = {}
    results: list[CriterionResult] = []
    if cfg_path.is_file():
        cfg = _run_config(cfg_path, _load_yaml(cfg_path), own_criteria=expect is None)
    elif expect is None:
        raise JudgeInputError(f"{cfg_path}: no such file (not a run directory)")
    criteria, expect_file = criteria_of(run_dir, cfg, expect)
    summary: dict[str, Any] = {}
    sum_path = run_dir / "summary.json"
    try:
        from harness.record.summary_file import read_summary

        # a hand-edited field of the wrong shape is left out and named (ERROR), never a crash
        summary, shape_problems = read_summary(sum_path)
        results.extend(_missing("summary.json", p) for p in shape_problems)
    except FileNotFoundError:
        results.append(_missing("summary.json", "no summary.json (the harness was killed?)"))
    except (OSError, ValueError) as exc:
        results.append(_missing("summary.json", f"summary.json unreadable ({exc})"))
    for name in ("run.rrd", "can.blf"):
        if not (run_dir / name).is_file():
            results.append(_missing(name, f"no {name} in the run directory"))
    # a baseline run's channels are read whole: only those its criteria compare
    wanted = {c.target for c in criteria if c.kind == "baseline"}
    source = ChannelSource(run_dir / "run.rrd")
    facts = Facts(summary, source, BaselineCache(wanted),
                  lambda: left_safe_problems(run_dir / "can.blf", _rig_data(cfg)), source.blocks,
                  frf_source(run_dir, criteria))
    note = ""
    # criteria a dry run or a fault test leaves out: listed NOT JUDGED with why, never
    # dropped without a word
    left_out: list[CriterionResult] = []
    if summary.get("dry_run"):  # nothing was commanded: only the safe state and the checks
        left_out = [not_judged(c, "a dry run commanded nothing", ending="")
                    for c in criteria if c.kind != "left_safe"]
        criteria = [c for c in criteria if c.kind == "left_safe"]
        note = "dry run (nothing commanded): only left_safe and the run's own checks judged"
    elif first_injection_s(summary) is not None and summary.get("stopped_by") == "fault":
        # a sequence's injected fault stopped the motion: its steps say whether the rig was
        # made safe in time; the nominal run's criteria do not apply, as in a fault test
        left_out = [not_judged(c, "the sequence's injected fault stopped the run by design")
                    for c in criteria if c.kind != "left_safe" and not c.applies_to_stopped]
        criteria = [c for c in criteria if c.kind == "left_safe" or c.applies_to_stopped]
        note = "a sequence with an injected fault: its steps, left_safe and the criteria " \
               "that apply to a stopped run judged"
    elif any(c.kind == "fault" for c in criteria):
        # a fault test: the fault stops the run by design, so the nominal run's criteria
        # (final error, settling, a clean bus) do not apply; the rig must see it and be
        # safe. A criterion that says it applies to a stopped run is judged all the same
        keep = ("fault", "left_safe")
        left_out = [not_judged(c, "a fault test: its fault stops the run by design")
                    for c in criteria if c.kind not in keep and not c.applies_to_stopped]
        criteria = [c for c in criteria if c.kind in keep or c.applies_to_stopped]
        note = "fault test: only its fault expectations, left_safe, the criteria that apply " \
               "to a stopped run and the run's own checks judged"
    if is_realtime(summary):  # the bench's own timing, in every real-time run
        run = cfg.get("run") if isinstance(cfg.get("run"), Mapping) else {}
        criteria = criteria + timing_criteria(run, {c.name for c in criteria})
    why = stopped_early(summary) if not note else None
    judged = [c for c in criteria if not why or c.applies_to_stopped]
    done = dict(zip((id(c) for c in judged), evaluate(judged, facts), strict=True))
    results = step_results(summary) + [
        done[id(c)] if id(c) in done else not_judged(c, str(why))
        for c in criteria] + left_out + results + (
        run_checks(criteria, without_sequence_faults(summary)) if summary else [])
    verdict = make_verdict(results, identity_of(run_dir, cfg, summary, expect_file), run_dir)
    if note and verdict.verdict == "PASS":
        verdict.reason = f"{note}; {verdict.reason}"
    if verdict.verdict == INCONCLUSIVE:
        bench = attribute(summary, source.blocks if source.rrd.is_file() else None)
        verdict.extra["bench"] = bench
        verdict.reason = f"{verdict.reason}; {describe(bench)}"
    return verdict


def _missing(what: str, message: str) -> CriterionResult:
    return CriterionResult("run", "run", None, "", {}, None, ERROR, None,
                           f"missing data: {message}")


# ----------------------------------------------------------------------------- output
def verdict_markdown(v: Verdict) -> str:
    lines = [f"# Verdict: {v.verdict}", "", v.reason, "",
             "| criterion | value | limit | margin | verdict | worst at (s) |",
             "|---|---|---|---|---|---|"]
    for c in v.criteria:
        lim = ", ".join(f"{k} {val}" for k, val in c.limit.items())
        val = "-" if c.value is None else (f"{c.value:.4g}" if isinstance(c.value, float)
                                           else str(c.value))
        lines.append(f"| {c.name} | {val} {c.unit} | {lim} | "
                     f"{'-' if c.margin is None else f'{c.margin:.4g}'} | {c.verdict} | "
                     f"{'-' if c.worst_time_s is None else f'{c.worst_time_s:.3f}'} |")
    lines += ["", *[f"- **{c.name}** ({c.verdict}): {c.message}" for c in v.criteria]]
    ident = "\n".join(f"- {k}: {binding_text(val) if k == 'binding' else val}"
                      for k, val in v.identity.items())
    return "\n".join(lines) + "\n\n## Identity\n\n" + ident + "\n"


def write_verdict(v: Verdict, run_dir: Path | None = None) -> Path:
    """verdict.json and verdict.rrd (same application and recording id as run.rrd:
    ``/run/verdict`` and events under ``/events/verdict`` at each violation)."""
    import rerun as rr

    run_dir = Path(run_dir or v.run_dir or ".")
    from harness.record.output import fresh_output_path, write_text_atomic
    from harness.record.recording import close_stream

    out = run_dir / "verdict.json"
    # atomic: a full disk leaves the old verdict or none, never an empty one; neither file
    # is written through a link placed in the run folder
    write_text_atomic(out, json.dumps(v.to_dict(), indent=2) + "\n")
    rec = rr.RecordingStream(APPLICATION_ID, recording_id=run_dir.name)
    save_with_blueprint(rec, fresh_output_path(run_dir / "verdict.rrd"), _run_layout(run_dir))
    rec.log("/run/verdict", rr.TextDocument(_verdict_text(v, run_dir),
                                            media_type="text/markdown"), static=True)
    events = verdict_events(v)
    for t, c in events:
        rec.set_time("time", duration=t)
        rec.log("/events/verdict", rr.TextLog(event_text(c),
                                              level="ERROR" if c.verdict == ERROR else "WARN"))
    _mark_on_plots(rec, run_dir, [(t, f"VERDICT {c.name} {c.verdict}") for t, c in events])
    try:
        # without a bound it waited forever on a full disk
        close_stream(rec, run_dir / "verdict.rrd")
    finally:
        del rec
        sweep_orphans()  # the stream dropped: its threads end
    _into_run_rrd(run_dir, v, [(t, "ERROR" if c.verdict == ERROR else "WARN",
                                event_text(c)) for t, c in events])
    return out


def verdict_events(v: Verdict) -> list[tuple[float, CriterionResult]]:
    """One event per criterion that failed, at its worst sample (else its first violation),
    in time order (by time only: two criteria violated at one instant are not compared)."""
    out = []
    for c in v.criteria:
        t = c.worst_time_s if c.worst_time_s is not None else (
            c.violations_s[0] if c.violations_s else None)
        if c.violations_s and t is not None:
            out.append((float(t), c))
    return sorted(out, key=lambda e: e[0])


def event_text(c: CriterionResult) -> str:
    """A failed criterion's event: its name, verdict and message, and how often it was
    violated when more than once (each start is in ``violations_s``)."""
    n = len(c.violations_s)
    starts = "" if n < 2 else (f" ({n}{'+' if n >= MAX_EVENTS else ''} violations, from "
                               f"t = {min(c.violations_s):.3f} s)")
    return f"{c.name} {c.verdict}: {c.message}{starts}"


def _into_run_rrd(run_dir: Path, v: Verdict, events: list[tuple[float, str, str]]) -> None:
    """The verdict also into run.rrd (harness.review.verdict), so that run.rrd alone shows
    it; verdict.rrd stays for viewers of older runs."""
    try:
        from harness.review.verdict import write_into_run

        if (run_dir / "run.rrd").is_symlink():  # appending would write outside the folder
            print(f"harness judge: {run_dir / 'run.rrd'} is a link: the verdict is in "
                  "verdict.rrd only", file=sys.stderr)
            return
        if (run_dir / "run.rrd").is_file() and not write_into_run(run_dir, v.to_dict(), events):
            print(f"harness judge: {run_dir / 'run.rrd'} is cut short: the verdict is in "
                  "verdict.rrd only", file=sys.stderr)
    except Exception as exc:  # the verdict stands (verdict.json, verdict.rrd) without it
        print(f"harness judge: could not add the verdict to run.rrd ({exc})", file=sys.stderr)


def _verdict_text(v: Verdict, run_dir: Path) -> str:
    """The verdict document the reviewer reads (harness.review.verdict: root cause first,
    failing criteria first), else the plain table."""
    try:
        from harness.review.verdict import verdict_markdown as review_markdown

        summary = json.loads((run_dir / "summary.json").read_text()) \
            if (run_dir / "summary.json").is_file() else {}
        return review_markdown(v.to_dict(), summary if isinstance(summary, dict) else {})
    except Exception:  # noqa: BLE001 - the plain table still says it all
        return verdict_markdown(v)


def _run_layout(run_dir: Path) -> Any:
    """run.rrd's layout (harness.review), so the files open together in any order."""
    try:
        from harness.review.layouts import blueprint_for_run_dir

        return blueprint_for_run_dir(run_dir)
    except Exception:  # no config.yaml (a bare recording): the viewer keeps run.rrd's
        return None


def _mark_on_plots(rec: Any, run_dir: Path, events: list[tuple[float, str]]) -> None:
    """The violations marked on the run's plots at the run's values (harness.review)."""
    if not events or not (run_dir / "run.rrd").exists():
        return
    try:
        from harness.review.events import mark_events

        mark_events(rec, run_dir / "run.rrd", [(t, "verdict", name) for t, name in events])
    except Exception as exc:  # the verdict stands without its markers
        print(f"harness judge: could not mark the violations on the plots ({exc})",
              file=sys.stderr)


def format_block(v: Verdict, path: Path | None = None) -> str:
    """The verdict as printed at the end of ``harness run`` and by ``harness judge``."""
    lines = [f"VERDICT {v.verdict} (exit {v.exit_code}): {v.reason}"]
    w = max([len(c.name) for c in v.criteria] + [9])
    wv = max([len(c.verdict) for c in v.criteria] + [8])  # INCONCLUSIVE is 12 wide
    for c in v.criteria:
        val = "-" if c.value is None else (f"{c.value:.4g}" if isinstance(c.value, float)
                                           else str(c.value))
        lim = ", ".join(f"{k} {val_:g}" if isinstance(val_, float) else f"{k} {val_}"
                        for k, val_ in c.limit.items())
        margin = "" if c.margin is None else f"  margin {c.margin:.4g}"
        at = "" if c.worst_time_s is None else f"  worst at t = {c.worst_time_s:.3f} s"
        unit = unit_text(c.unit)
        if c.kind == "step" and val == c.verdict:
            val = ""  # a step's outcome is its verdict (TIMEOUT, ERROR shown as they are)
        lines.append(f"  {c.verdict:<{wv}} {c.name:<{w}}  {val} {unit}".rstrip()
                     + (f"  limit {lim}" if lim else "") + margin + at)
        if c.verdict != "PASS" or c.kind == "step":  # a step says what decided it
            lines.append(f"  {'':<{wv}} {'':<{w}}  {c.message}")
    if path is not None:
        lines.append(f"  verdict in {path}")
    return "\n".join(lines)


__all__ = ["ConfigError", "JudgeInputError", "Verdict", "format_block", "judge_run",
           "make_verdict", "write_verdict"]
