"""The ``frf:`` criterion: a mode fitted to a measured frequency response (``harness frf``)
held to the rig model's.

    mode1_frequency:
      frf: mode_1            # the rig model's hub-free mode 1
      input: wheel           # wheel | piezo1 | piezo2 (default: the run's excitation's)
      output: tip_accel      # hub_rate | tip_accel | piezo_sensor1 | piezo_sensor2
      quantity: frequency    # frequency (default) or damping
      max_ratio_error: 0.0025
      marginal_ratio_error: 0.0005   # optional
      why: ...

The value is the measured-to-model ratio of the mode's undamped frequency (or damping
ratio), judged within 1 -+ ``max_ratio_error``; the message names the mode and gives the
ratio's 1-sigma (the fit's). The limits in verdict.json are ``min_ratio`` and ``max_ratio``
(so the history plots them beside the value). A mode the fit did not determine (its sigma
too large, ``harness.core.frf.DETERMINED``) fails; one outside the measured band is an
ERROR (nothing to judge).

The analysis is ``harness frf``'s, once per input for every output its criteria name; it
writes frf.json, frf.png and frf.rrd in the run directory as the command does.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from typing import Any

from harness.testing.criteria import Criterion, _check_keys, _err, _number

INPUTS = ("wheel", "piezo1", "piezo2")
OUTPUTS = ("hub_rate", "tip_accel", "piezo_sensor1", "piezo_sensor2")
QUANTITIES = ("frequency", "damping")
MODE = re.compile(r"mode_([1-9][0-9]*)")

FrfSource = Callable[[str | None, tuple[str, ...]], Mapping[str, Any]]
"""(input or None: the run's excitation's, outputs) -> ``harness frf``'s document."""


def parse_frf(name: str, raw: Mapping[str, Any], source: str, key_path: str,
              why: str) -> Criterion:
    """An ``frf:`` criterion (see the module docstring); ConfigError naming the key."""
    mode = raw["frf"]
    m = MODE.fullmatch(mode) if isinstance(mode, str) else None
    if m is None:
        raise _err(source, f"{key_path}.frf", f"expected a mode of the rig model, mode_N "
                   f"(N from 1), got {mode!r}")
    inp = raw.get("input")
    if inp is not None and inp not in INPUTS:
        raise _err(source, f"{key_path}.input", f"expected one of {list(INPUTS)}, got {inp!r}")
    out = raw.get("output")
    if out not in OUTPUTS:
        raise _err(source, f"{key_path}.output", f"expected one of {list(OUTPUTS)}, "
                   f"got {out!r}")
    quantity = raw.get("quantity", "frequency")
    if quantity not in QUANTITIES:
        raise _err(source, f"{key_path}.quantity", f"expected one of {list(QUANTITIES)}, "
                   f"got {quantity!r}")
    if "max_ratio_error" not in raw:
        raise _err(source, f"{key_path}.max_ratio_error", "missing; expected the largest "
                   "|measured / model - 1|, a number > 0")
    err = _number(source, f"{key_path}.max_ratio_error", raw["max_ratio_error"], "ratio",
                  positive=True)
    limit = {"min": 1.0 - err, "max": 1.0 + err}
    if raw.get("marginal_ratio_error") is not None:
        marginal = _number(source, f"{key_path}.marginal_ratio_error",
                           raw["marginal_ratio_error"], "ratio", nonneg=True)
        if marginal > err:
            raise _err(source, f"{key_path}.marginal_ratio_error", f"{marginal:g} is wider "
                       f"than max_ratio_error {err:g}")
        limit["marginal"] = marginal
    used = {"frf", "input", "output", "quantity", "max_ratio_error", "marginal_ratio_error"}
    _check_keys(source, key_path, raw, used, "frf, input, output, quantity, "
                "max_ratio_error, marginal_ratio_error, why")
    return Criterion(name, "frf", key_path, out, "ratio", limit,
                     params={"mode": int(m.group(1)), "input": inp, "quantity": quantity},
                     why=why)


def frf_source(run_dir: Path, criteria: Iterable[Criterion]) -> FrfSource:
    """``harness frf``'s analysis of ``run_dir``, once per input, for every output the
    ``frf:`` criteria on that input name."""
    wanted: dict[str | None, list[str]] = {}
    for c in criteria:
        if c.kind == "frf":
            outs = wanted.setdefault(c.params["input"], [])
            if c.target not in outs:
                outs.append(c.target)
    done: dict[str | None, Mapping[str, Any]] = {}

    def get(inp: str | None, outputs: tuple[str, ...]) -> Mapping[str, Any]:
        if inp not in done:
            from harness.core.frf import analyse

            done[inp] = analyse(run_dir, inp, wanted.get(inp) or list(outputs))
        return done[inp]

    return get


def judge_frf(c: Criterion, frf: FrfSource) -> Any:
    """An ``frf:`` criterion's CriterionResult from ``harness frf``'s document."""
    from harness.testing.evaluate import FAIL, MissingData, _fmt, _result, _verb, grade

    try:
        doc = frf(c.params["input"], (c.target,))
    except (ValueError, OSError, KeyError) as exc:
        raise MissingData(f"harness frf: {exc}") from exc
    entry = doc["outputs"].get(c.target)
    if entry is None:
        raise MissingData(f"harness frf gave no {c.target}")
    number = c.params["mode"]
    what = f"{doc['input']} -> {c.target} mode {number}"
    found = [m for m in entry["modes"] if m["model_mode"] == number]
    if not found:
        band = f"{entry['freq_hz'][0]:.3g}-{entry['freq_hz'][-1]:.3g} Hz"
        fit_error = f"; {entry['fit_error']}" if "fit_error" in entry else ""
        raise MissingData(f"{what}: not fitted (the model's mode is outside the measured "
                          f"band {band}{fit_error})")
    m = found[0]
    if c.params["quantity"] == "frequency":
        ratio = m["omega_rad_s"] / m["model_omega_rad_s"]
        sigma = m["sigma_omega_rad_s"] / m["model_omega_rad_s"]
        label = "frequency"
    else:
        ratio = m["damping_ratio"] / m["model_damping_ratio"]
        sigma = m["sigma_damping"] / m["model_damping_ratio"]
        label = "damping"
    shown = f"{what}: {label} / model = {ratio:.5f} +- {sigma:.5f} (1 sigma)"
    err = c.limit["max"] - 1.0
    margin = err - abs(ratio - 1.0)
    if not m["determined"]:
        return _result(c, ratio, margin, FAIL, None, f"{shown}: not determined by the fit")
    verdict = grade(margin, c.marginal)
    return _result(c, ratio, margin, verdict, None,
                   f"{shown} {_verb(verdict)} max_ratio_error {_fmt(err)} "
                   f"(margin {_fmt(margin)})")
