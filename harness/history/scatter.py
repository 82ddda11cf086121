"""Flaky or real: the virtual rig's predicted scatter of each criterion.

The run's own configuration (its config.yaml: run file and rig, or ``model_rig``'s rig
file instead) is run on the virtual rig, lockstep on a private virtual bus, once per noise
seed (the rig file's ``noise_seed``: seeds 1001, 1002, ... so that no prediction repeats
the recorded run's own draw), each judged by the run's criteria. Each criterion's values
give its mean and standard deviation. Done once per rig file and run file: the result is
cached under ``<logs>/scatter/`` keyed by the SHA-256 of the rig (its noise seed aside) and
of the run (its rig reference aside), and by the number of seeds.

A recorded value is *within* the predicted scatter when ``|value - mean| <= k std`` (k = 3)
and *beyond* it otherwise; a criterion the noise does not move (std 0) is within only at
its predicted value. A failure within the scatter is the noise the model predicts (the
limit leaves no room for it); a failure beyond it is a real change.
"""

from __future__ import annotations

import json
import math
import os
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import yaml

from harness.history.record import canonical_sha256

SEED_BASE = 1000
CACHE_DIR = "scatter"


class ScatterError(Exception):
    """The run cannot be predicted (no config.yaml, a run the virtual rig refuses)."""


MAX_PREDICTED_S = 600.0
"""The longest run the scatter is predicted for (simulated seconds a virtual run): each seed
simulates the whole run, so a 30-day run would keep the command busy for hours before it
said anything. Refused before the first virtual run, with the reason."""


def _config(run_dir: Path) -> dict[str, Any]:
    from harness.record.run_folder import RunFolderError, load_run_folder

    try:  # checked as every reader of a run folder checks it
        folder = load_run_folder(run_dir)
    except RunFolderError as exc:
        raise ScatterError(str(exc)) from exc
    if not isinstance(folder.config.get("rig"), dict):
        raise ScatterError(f"{run_dir / 'config.yaml'}: rig: expected the rig file's data "
                           "(a mapping)")
    return folder.config


def _number(path: Path, where: str, v: Any, nonneg: bool = False) -> float:
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v) \
            or (nonneg and v < 0):
        raise ScatterError(f"{path}: {where}: expected a finite number"
                           f"{' >= 0' if nonneg else ''}, got {v!r} (an edited cache: "
                           "delete it to predict again)")
    return float(v)


def read_cache(path: Path) -> dict[str, Any]:
    """A scatter cache file, checked: ``criteria`` a mapping of name -> {mean, std >= 0, n};
    ScatterError naming the file and the field otherwise."""
    try:
        doc = json.loads(path.read_text(encoding="utf-8", errors="replace"))
    except (OSError, ValueError, RecursionError) as exc:
        raise ScatterError(f"{path}: unreadable ({exc}): delete it to predict again") from None
    crit = doc.get("criteria") if isinstance(doc, dict) else None
    if not isinstance(crit, dict):
        raise ScatterError(f"{path}: criteria: expected a mapping (an edited cache: delete "
                           "it to predict again)")
    for name, c in crit.items():
        if not isinstance(c, dict):
            raise ScatterError(f"{path}: criteria.{name}: expected an object")
        _number(path, f"criteria.{name}.mean", c.get("mean"))
        _number(path, f"criteria.{name}.std", c.get("std"), nonneg=True)
    return doc


def _rig_data(cfg: dict[str, Any], model_rig: str | None) -> dict[str, Any]:
    if model_rig is None:
        return dict(cfg["rig"])
    from rig_models.rig_file import load_rig
    from rig_models.schema import ConfigError

    try:
        return dict(load_rig(model_rig).data)
    except ConfigError as exc:
        raise ScatterError(str(exc)) from exc


def cache_key(run: dict[str, Any], rig: dict[str, Any], seeds: int) -> str:
    rig_hash = canonical_sha256({k: v for k, v in rig.items() if k != "noise_seed"})
    run_hash = canonical_sha256({k: v for k, v in run.items()
                                 if k not in ("rig", "rig_overrides")})
    return f"{rig_hash[:16]}-{run_hash[:16]}-n{seeds}"


def _numbers(criteria: list[dict[str, Any]]) -> dict[str, float]:
    out = {}
    for c in criteria:
        v = c.get("value")
        if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v):
            out[str(c["name"])] = float(v)
    return out


def predict(run: dict[str, Any], rig: dict[str, Any], cache: Path, seeds: int = 5,
            progress: Callable[[str], None] | None = None) -> dict[str, Any]:
    """Each criterion's mean and std over ``seeds`` virtual runs (cached in ``cache``)."""
    if cache.is_file():
        return read_cache(cache)
    duration = run.get("duration_s")
    if isinstance(duration, int | float) and duration > MAX_PREDICTED_S:
        raise ScatterError(f"run.duration_s {duration:g} s: the scatter is predicted for runs "
                           f"of at most {MAX_PREDICTED_S:g} s ({seeds} virtual runs of the "
                           "whole run); predict a shorter run of the same configuration")
    from harness.core.runs import run_from_dict
    from harness.core.session import execute_run
    from harness.testing.judge import judge_run
    from harness.testing.work import private_channel
    from rig_models.schema import ConfigError

    samples: dict[str, list[float]] = {}
    with tempfile.TemporaryDirectory(prefix="sgsrt-scatter-") as tmp:
        for i in range(seeds):
            seed = SEED_BASE + 1 + i
            if progress:
                progress(f"harness history: predicting the scatter: virtual run {i + 1}/"
                         f"{seeds} (noise seed {seed}) ...")
            rig_file = Path(tmp) / f"rig-{seed}.yaml"
            rig_file.write_text(yaml.safe_dump({**rig, "noise_seed": seed}, sort_keys=False))
            raw = {**run, "rig": str(rig_file), "rig_overrides": None,
                   "bus": "virtual:sgsrt", "clock": "lockstep"}
            try:
                cfg = run_from_dict(raw, source=f"scatter run (seed {seed})")
                res = execute_run(cfg, out_dir=Path(tmp), bus=private_channel(),
                                  show_progress=False)
            except ConfigError as exc:
                raise ScatterError(f"the virtual rig refuses the run: {exc}") from exc
            for name, v in _numbers([c.to_dict() for c in judge_run(res.run_dir).criteria]
                                    ).items():
                samples.setdefault(name, []).append(v)
    crit = {}
    for name, vals in samples.items():
        n = len(vals)
        mean = sum(vals) / n
        std = math.sqrt(sum((v - mean) ** 2 for v in vals) / (n - 1)) if n > 1 else 0.0
        crit[name] = {"mean": mean, "std": std, "n": n, "values": vals}
    out = {"seeds": seeds, "cache": str(cache), "criteria": crit}
    cache.parent.mkdir(parents=True, exist_ok=True)
    part = cache.with_suffix(f".{os.getpid()}.part")
    part.write_text(json.dumps(out, indent=2))
    os.replace(part, cache)  # parallel predictors: the last complete file wins, never a torn one
    return out


def predict_for_run(run_dir: Path, logs: Path, seeds: int = 5, model_rig: str | None = None,
                    progress: Callable[[str], None] | None = None) -> dict[str, Any]:
    if seeds < 2:
        raise ScatterError(f"seeds: expected 2 or more, got {seeds}")
    cfg = _config(Path(run_dir))
    rig = _rig_data(cfg, model_rig)
    path = Path(logs) / CACHE_DIR / f"{cache_key(cfg['run'], rig, seeds)}.json"
    return predict(cfg["run"], rig, path, seeds, progress)


def cached_prediction(logs: Path, run_dir: Path, criterion: str) -> dict[str, Any] | None:
    """A criterion's predicted mean and std from the cache for ``run_dir``'s configuration
    (any number of seeds), or None (nothing is run here)."""
    try:
        cfg = _config(Path(run_dir))
    except ScatterError:
        return None
    stem = cache_key(cfg["run"], cfg["rig"], 0).rsplit("-n", 1)[0]
    for path in sorted((Path(logs) / CACHE_DIR).glob(f"{stem}-n*.json")):
        try:
            c = read_cache(path)["criteria"].get(criterion)
        except ScatterError:
            continue  # an edited cache predicts nothing here (``predict`` names it)
        if c and c["std"] > 0:
            return c
    return None


def cached_spread(logs: Path, run_dir: Path, criterion: str) -> float | None:
    c = cached_prediction(logs, run_dir, criterion)
    return None if c is None else float(c["std"])


def within(value: float, prediction: dict[str, Any], k: float = 3.0) -> bool:
    return abs(value - prediction["mean"]) <= k * prediction["std"]


def classify(run_dir: Path, prediction: dict[str, Any], k: float = 3.0
             ) -> list[dict[str, Any]]:
    """Each of the run's criteria against its predicted scatter."""
    try:
        verdict = json.loads((Path(run_dir) / "verdict.json").read_text())
    except (OSError, ValueError) as exc:
        raise ScatterError(f"{run_dir}: verdict.json unreadable ({exc})") from exc
    out = []
    pred = prediction["criteria"]
    for c in verdict.get("criteria") or []:
        name = str(c.get("name"))
        value = _numbers([c]).get(name)
        p = pred.get(name)
        row: dict[str, Any] = {"name": name, "value": value, "unit": c.get("unit") or "",
                               "verdict": c.get("verdict"),
                               "mean": None, "std": None, "z": None,
                               "scatter": "not predicted", "message": ""}
        if value is None or p is None:
            out.append(row)
            continue
        row.update(mean=p["mean"], std=p["std"])
        if p["std"] > 0:
            z = (value - p["mean"]) / p["std"]
            row["z"] = z
            beyond = abs(z) > k
        else:  # the noise does not move it: any difference is a change
            beyond = not math.isclose(value, p["mean"], rel_tol=1e-9, abs_tol=1e-12)
        row["scatter"] = "beyond" if beyond else "within"
        if c.get("verdict") in ("FAIL", "MARGINAL"):
            zt = "" if row["z"] is None else f" (z = {row['z']:+.1f})"
            row["message"] = (
                f"{name} {c.get('verdict')} at {value:.4g}: beyond the virtual rig's predicted "
                f"scatter{zt} (mean {p['mean']:.4g}, std {p['std']:.3g}): a real change, not "
                "noise" if beyond else
                f"{name} {c.get('verdict')} at {value:.4g}: within the predicted scatter{zt} "
                f"(mean {p['mean']:.4g}, std {p['std']:.3g}): the noise the model predicts; "
                "the limit leaves it no room")
        out.append(row)
    return out
