"""`harness calibrate`'s runs: excite, identify, design, verify, write (see docs/calibrate.md).

1. Excite: the plan (``plan.plan_excitation``: bursts at the rig model's predicted modes
   within the actuator's limits) run through the harness (``execute_run``).
2. Identify: the free-decay windows of that run, fitted as ``harness identify RUN_DIR``
   fits them (``identify_windows``): frequency, damping, 1-sigma. Each predicted mode is
   matched to an identified one (within ``MATCH_REL``); a miss is reported by name.
3. Design candidates over the identified modes and score them over their bands
   (``candidates``).
4. Verify: the unshaped slew and every feasible candidate run through the harness; each
   one's residual read over the same window after its own manoeuvre (``residual``): the
   identified modes fitted to the recorded residual (the recommendation uses this; a
   predicted mode that was not identified stays in the fit at its predicted frequency and
   damping, so the reading is not blind to it), the raw peak, and on the virtual rig the
   noise-free truth. The recommendation is the cheapest
   candidate whose fitted residual meets the target (``target_ratio`` x below unshaped, or
   ``target_m_s2``; ``judge``) and whose predicted worst case over the bands does too;
   failing that, the cheapest meeting the measured target; failing that, the lowest
   residual (target not met).
"""

from __future__ import annotations

import datetime as dt
import json
import math
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from harness.bus import parse_bus
from harness.calibration.candidates import (
    MARGIN_S,
    Candidate,
    SlewSpec,
    baseline_controller,
    build,
    modes_yaml,
    predict_ratios,
    run_dict,
    slew_spec,
    valve_candidates,
    wheel_candidates,
)
from harness.calibration.plan import (
    NYQUIST_FRACTION,
    ExcitationPlan,
    plan_excitation,
    rig_reference,
)
from harness.calibration.residual import fit_modal_residual, true_residual
from harness.controllers.shaped_wheel_slew import Mode
from harness.core.identify import (
    analysis_windows,
    identify_samples,
    load_windows,
    write_spectrum_rrd,
)
from harness.core.paths import safe_child, safe_name
from harness.core.runs import RunConfig, build_controller, run_from_dict, virtual_bus
from harness.core.session import RunResult, execute_run, refuse_beyond_limits
from rig_models.rig_file import RigConfig, load_rig
from rig_models.schema import ConfigError

MATCH_REL = 0.25  # an identified mode within 25 % of a predicted one is that mode
DEFAULT_ANGLE_DEG = {"wheel": 20.0, "valves": 5.0}
DEFAULT_TARGET_RATIO = 10.0
WINDOW_PERIODS = 3.0  # residual window: this many periods of the slowest identified mode
MIN_WINDOW_S, MAX_WINDOW_S = 2.0, 30.0


class CalibrationError(RuntimeError):
    """A stage could not go on (``exit_code``: 3 a fault stopped a run, 4 otherwise)."""

    def __init__(self, message: str, exit_code: int = 4) -> None:
        super().__init__(message)
        self.exit_code = exit_code


@dataclass
class Options:
    rig: str = "sgsrt"
    actuator: str = "wheel"
    angle_deg: float | None = None
    out: Path = Path("logs")
    bus: str | None = None
    rate_hz: float = 500.0
    target_ratio: float = DEFAULT_TARGET_RATIO
    target_m_s2: float | None = None
    excite_torque_n_m: float | None = None
    dry_run: bool = False
    max_verify: int | None = None


@dataclass
class Calibration:
    """Everything a calibration found (``to_dict`` is the JSON)."""

    options: Options
    plan: ExcitationPlan
    folder: Path | None = None
    excitation_dir: Path | None = None
    identification: Any = None
    modes: list[Mode] = field(default_factory=list)
    unidentified: list[Mode] = field(default_factory=list)  # predicted, not identified
    matches: list[dict[str, Any]] = field(default_factory=list)
    spec: SlewSpec | None = None
    candidates: list[Candidate] = field(default_factory=list)
    baseline: dict[str, Any] | None = None
    verified: dict[str, dict[str, Any]] = field(default_factory=dict)
    recommended: str | None = None
    target_met: bool = False
    recommendation_note: str = ""
    run_file: Path | None = None
    baseline_run_file: Path | None = None
    report: Path | None = None
    notes: list[str] = field(default_factory=list)

    @property
    def analysis_modes(self) -> list[Mode]:
        """The residual fit's basis: the identified modes, then the unidentified predicted."""
        return self.modes + self.unidentified

    def to_dict(self) -> dict[str, Any]:
        o = self.options
        out: dict[str, Any] = {
            "rig": o.rig, "actuator": o.actuator, "dry_run": o.dry_run,
            "plan": self.plan.to_dict(),
            "run_file": None if self.run_file is None else str(self.run_file),
            "baseline_run_file": (None if self.baseline_run_file is None
                                  else str(self.baseline_run_file)),
        }
        if o.dry_run:
            return out
        out.update({
            "folder": str(self.folder), "excitation_run_dir": str(self.excitation_dir),
            "identified_modes": [
                {"omega_rad_s": m.omega_rad_s, "freq_hz": m.omega_rad_s / (2 * math.pi),
                 "damping_ratio": m.damping_ratio, "sigma_omega_rad_s": m.sigma_omega_rad_s,
                 "sigma_damping": m.sigma_damping} for m in self.modes],
            "predicted_match": self.matches,
            "residual_fit_extra_modes": [{"omega_rad_s": m.omega_rad_s,
                                          "damping_ratio": m.damping_ratio}
                                         for m in self.unidentified],
            "angle_deg": None if self.spec is None else self.spec.angle_deg,
            "slew_torque_n_m": None if self.spec is None else self.spec.torque_n_m,
            "residual_window_s": None if self.spec is None else self.spec.window_s,
            "target": {"ratio": o.target_ratio, "m_s2": o.target_m_s2},
            "baseline": self.baseline,
            "candidates": [dict(c.to_dict(), measured=self.verified.get(c.key))
                           for c in self.candidates],
            "recommended": self.recommended, "target_met": self.target_met,
            "recommendation_note": self.recommendation_note,
            "report": None if self.report is None else str(self.report),
            "notes": self.notes,
        })
        return out


def output_folder(out: Path, rig_name: str, actuator: str) -> Path:
    """``out/<UTC time>-calibrate-<rig>-<actuator>`` (a safe name, inside ``out``)."""
    stamp = dt.datetime.now(dt.UTC).strftime("%Y%m%dT%H%M%SZ")
    folder = safe_child(out, f"{stamp}-calibrate-{rig_name}-{actuator}")
    folder.mkdir(parents=True, exist_ok=False)
    return folder


def _run(run: RunConfig, runs_dir: Path, bus: str | None, clock: str) -> RunResult:
    # the virtual rig's truth over the residual window, read forward (its longest window
    # and the margin before it; bounded whatever the run's length)
    result = execute_run(run, out_dir=runs_dir, bus=bus, clock=clock, show_progress=False,
                         truth_tail_s=MAX_WINDOW_S + 2 * MARGIN_S + 1.0)
    s = result.summary
    if s["stopped_by"] != "completed":
        faults = s.get("faults") or []
        code = 3 if faults else 4
        why = (f"{faults[0]['device']}: {faults[0]['kind']}: {faults[0]['message']} at t = "
               f"{faults[0]['time_s']:.3f} s" if faults else s.get("error") or "no reason given")
        raise CalibrationError(f"{run.name}: stopped by {s['stopped_by']}: {why} (recording "
                               f"in {result.run_dir})", code)
    return result


def identify_run(run_dir: Path) -> Any:
    """The modes of an excitation run, as ``harness identify RUN_DIR`` finds them (and its
    identify.rrd beside run.rrd)."""
    rec = load_windows(run_dir)  # the windows' samples only
    if analysis_windows(rec.cfg) is None:
        raise CalibrationError(f"{run_dir}: no free-decay windows in its config")
    ident = identify_samples(rec)
    write_spectrum_rrd(run_dir, ident)
    return ident


def match_predictions(plan: ExcitationPlan, modes: list[Mode]) -> tuple[list[dict[str, Any]],
                                                                        list[str]]:
    """Each predicted mode's identified counterpart (nearest within MATCH_REL), and a
    message for every reachable predicted mode the identification did not find."""
    rows, notes = [], []
    excited = {b.mode.index for b in plan.bursts}
    for p in plan.predicted:
        near = min(range(len(modes)), key=lambda i: abs(math.log(modes[i].omega_rad_s
                                                                 / p.omega_rad_s)),
                   default=None)
        hit = near is not None and abs(modes[near].omega_rad_s / p.omega_rad_s - 1) <= MATCH_REL
        row = {"mode": p.index, "predicted_omega_rad_s": p.omega_rad_s,
               "predicted_damping_ratio": p.damping_ratio, "excited": p.index in excited,
               "identified": (near + 1) if hit else None}
        if hit:
            row["omega_error_percent"] = 100 * (modes[near].omega_rad_s / p.omega_rad_s - 1)
        rows.append(row)
        if p.index in excited and not hit:
            found = ", ".join(f"{m.omega_rad_s:.4g}" for m in modes) or "none"
            notes.append(f"mode {p.index} (predicted {p.omega_rad_s:.4g} rad/s, "
                         f"{p.freq_hz:.4g} Hz) was excited but the identification found no "
                         f"mode within {100 * MATCH_REL:g} % of it (identified: {found} "
                         "rad/s); the shapers are designed without it")
    return rows, notes


def unidentified_modes(plan: ExcitationPlan, matches: list[dict[str, Any]]) -> list[Mode]:
    """Predicted modes without an identified counterpart that the accelerometer can see
    (below NYQUIST_FRACTION of its Nyquist frequency), at their predicted values."""
    found = {r["mode"] for r in matches if r["identified"] is not None}
    fs = plan.rate_hz / plan.rig.data["bus"]["sync_divider"]["accelerometer"]
    return [Mode(p.omega_rad_s, p.damping_ratio) for p in plan.predicted
            if p.index not in found and p.omega_damped_rad_s < NYQUIST_FRACTION * math.pi * fs]


def measure(result: RunResult, ctrl: Any, modes: list[Mode]) -> dict[str, Any]:
    """Residual of one slew over [end + MARGIN_S, run end]: raw, fitted, truth."""
    rec = result.columns()
    t = rec.time_s[: rec.rows]
    accel = rec.column("/tip/accel_m_s2")
    t0 = ctrl.end_s + MARGIN_S
    win = t >= t0 - 1e-9
    fitted = fit_modal_residual(t, accel, modes, t0, with_signal=True)
    row: dict[str, Any] = {
        "run_dir": str(result.run_dir), "manoeuvre_s": ctrl.duration_s,
        "window_s": [t0, float(t[-1])],
        "raw": {"peak_m_s2": float(np.max(np.abs(accel[win]))),
                "rms_m_s2": float(np.sqrt(np.mean(accel[win] ** 2)))},
        "fitted": fitted,
        "truth": (true_residual(result.virtual_rig, t0, with_signal=True)
                  if result.virtual_rig is not None else None),
        "final_angle_deg": float(np.mean(rec.column("/attitude/angle_deg")[win])),
    }
    row["series"] = {"t": t[win] - t0, "accel": accel[win], "fitted": fitted.pop("signal"),
                     "truth": None if row["truth"] is None else row["truth"].pop("signal")}
    return row


def window_for(modes: list[Mode]) -> float:
    """Residual window: ``WINDOW_PERIODS`` periods of the slowest identified mode, or its
    time constant 1 / (zeta omega) if longer (the fit then sees most of its decay), within
    [MIN_WINDOW_S, MAX_WINDOW_S]."""
    slow = min(modes, key=lambda m: m.omega_rad_s)
    tau = 1.0 / max(slow.damping_ratio * slow.omega_rad_s, 1e-9)
    w = max(WINDOW_PERIODS * 2 * math.pi / slow.omega_rad_s, tau)
    return round(float(min(MAX_WINDOW_S, max(MIN_WINDOW_S, w))), 3)


def threshold_m_s2(c: Calibration) -> float:
    """The fitted residual a candidate must not exceed (m/s^2)."""
    if c.options.target_m_s2 is not None:
        return c.options.target_m_s2
    assert c.baseline is not None
    return c.baseline["fitted"]["peak_m_s2"] / c.options.target_ratio


def judge(c: Calibration, row: dict[str, Any]) -> None:
    """A verified row against the target, in place: ``meets`` (the fitted peak, the best
    estimate, at or below the threshold; at the fit's noise the fitted peak reads the noise,
    so this errs on the safe side), ``confirmed`` (fitted + 2 sigma below the threshold: the
    measurement shows the target met beyond its noise)."""
    f = row["fitted"]
    thr = threshold_m_s2(c)
    row["threshold_m_s2"] = thr
    row["meets"] = f["peak_m_s2"] <= thr
    row["confirmed"] = f["peak_m_s2"] + 2 * f["sigma_m_s2"] <= thr


def recommend(c: Calibration) -> None:
    """The cheapest verified candidate meeting the target (module docstring), in place.

    Meeting it on the rig means its fitted residual is at or below the threshold
    (``judge``); among those, candidates whose predicted worst case over the bands meets the
    target ratio come first; failing every one, the lowest fitted residual."""
    by_key = {x.key: x for x in c.candidates}
    verified = [x.key for x in c.candidates if x.key in c.verified]
    meets = [k for k in verified if c.verified[k].get("meets")]
    robust = [k for k in meets if by_key[k].predicted_ratio >= c.options.target_ratio]
    if robust:
        c.recommended = min(robust, key=lambda k: by_key[k].cost())
        c.target_met = True
        c.recommendation_note = ("the cheapest candidate meeting the target on the rig and, "
                                 "predicted, over the identified bands")
    elif meets:
        c.recommended = min(meets, key=lambda k: by_key[k].cost())
        c.target_met = True
        c.recommendation_note = ("the cheapest candidate meeting the target on the rig; none "
                                 "is predicted to meet it over the whole identified bands")
    elif verified:
        c.recommended = min(verified, key=lambda k: c.verified[k]["fitted"]["peak_m_s2"])
        c.target_met = False
        c.recommendation_note = "no candidate met the target: the lowest residual measured"
    if c.recommended is not None and c.target_met and not c.verified[c.recommended].get(
            "confirmed"):
        c.recommendation_note += (
            "; the measurement does not confirm it beyond its noise: the fitted residual plus 2 "
            "sigma exceeds the threshold (the fit's noise over this window allows at most "
            f"{c.verified[c.recommended].get('ratio_resolvable', math.nan):.1f}x)")


SIGMAS = 3.0
"""A repeat of a verified slew reads its fitted residual within this many of the fit's
1-sigma (the accelerometer's noise over the window)."""


def _modes_criterion(c: Calibration) -> list[dict[str, float]]:
    """The residual fit's modes as a ``modal_residual:`` criterion takes them (the same basis
    calibrate fitted with: identified, then predicted but unidentified)."""
    return modes_yaml(c.analysis_modes)


def residual_limit_m_s2(c: Calibration, row: dict[str, Any]) -> float | None:
    """The largest fitted residual a run of this slew may leave: the target it met (the
    threshold), or, above it, what the calibration measured plus ``SIGMAS`` of the fit's
    uncertainty. None when that limit would not tell this slew from the unshaped one (it is
    not ``SIGMAS`` sigma below the unshaped slew's fitted residual): a criterion that the
    unshaped slew passes would catch no lost shaping."""
    assert c.baseline is not None
    f = row["fitted"]
    limit = max(threshold_m_s2(c), f["peak_m_s2"] + SIGMAS * f["sigma_m_s2"])
    base = c.baseline["fitted"]
    if not limit < base["peak_m_s2"] - SIGMAS * base["sigma_m_s2"]:
        return None
    return limit


def residual_expect(c: Calibration, row: dict[str, Any], label: str) -> dict[str, Any]:
    """The run file's ``expect:`` (docs/criteria.md) stating what the calibration measured
    of this slew: the identified modes fitted to the tip acceleration over the residual
    window (``MARGIN_S`` after the slew's own end, to the run's end) leave at most
    ``residual_limit_m_s2``. The unshaped slew, judged by it, FAILs: it leaves the
    unshaped residual. Empty (with a note) when no such limit exists."""
    assert c.baseline is not None
    limit = residual_limit_m_s2(c, row)
    if limit is None:
        c.notes.append(f"{label}: no residual criterion written: its fitted residual "
                       f"{row['fitted']['peak_m_s2']:.3g} +- {row['fitted']['sigma_m_s2']:.2g}"
                       " m/s^2 cannot be told from the unshaped slew's "
                       f"{c.baseline['fitted']['peak_m_s2']:.3g} m/s^2")
        return {}
    f, base = row["fitted"], c.baseline["fitted"]
    truth = (f"; noise-free truth {row['ratio_truth']:.1f}x" if "ratio_truth" in row else "")
    return {"residual_within_calibration": {
        "modal_residual": "/tip/accel_m_s2", "modes": _modes_criterion(c),
        "after": "slew_profile_end_s", "from_s": MARGIN_S,
        "max_m_s2": float(f"{limit:.4g}"),
        "why": (f"harness calibrate measured, with these modes fitted to the tip acceleration "
                f"from {MARGIN_S:g} s after the slew's end: {f['peak_m_s2']:.3g} +- "
                f"{f['sigma_m_s2']:.2g} m/s^2 (1 sigma) for the {label} slew, "
                f"{row['ratio_fitted']:.1f}x below the unshaped slew's {base['peak_m_s2']:.3g} "
                f"+- {base['sigma_m_s2']:.2g} m/s^2{truth}. The limit is the target "
                f"({threshold_m_s2(c):.3g} m/s^2) or, if larger, the measurement plus "
                f"{SIGMAS:g} sigma; the unshaped slew fails it")}}


def baseline_expect(c: Calibration, shaped_limit_m_s2: float) -> dict[str, Any]:
    """baseline.yaml's ``expect:``: the unshaped slew still leaves more residual than the
    recommended slew is allowed. Were it not so (a rig that no longer vibrates, a dead
    accelerometer, a shaper slipped into the baseline), the recommended run's criterion would
    pass without the shaping doing anything."""
    assert c.baseline is not None
    base = c.baseline["fitted"]
    return {"vibrates_beyond_shaped_limit": {
        "modal_residual": "/tip/accel_m_s2", "modes": _modes_criterion(c),
        "after": "slew_profile_end_s", "from_s": MARGIN_S,
        "min_m_s2": float(f"{shaped_limit_m_s2:.4g}"),
        "why": (f"harness calibrate measured {base['peak_m_s2']:.3g} +- "
                f"{base['sigma_m_s2']:.2g} m/s^2 for this unshaped slew; the limit is the "
                "recommended slew's (recommended.yaml's residual_within_calibration): below "
                "it, that criterion could not tell shaping from none")}}


TEMPLATE_RUNS = {"wheel": "slew-rw-zv", "valves": "slew-thruster-lhhl"}
"""The built-in run a calibrated slew of each actuator replaces. Its criteria (the final
error, at rest when the profile ends or settled in time, the actuator's limit, a clean bus,
left safe) stay the calibrated run file's criteria; its ``modal_residual:`` ones name the
modes and the limit of that run's rig, and the calibration's measured one takes their
place."""


def template_expect(actuator: str) -> dict[str, Any]:
    """The criteria of the run the calibrated slew replaces (``TEMPLATE_RUNS``), but the
    modal residual ones; empty when that run file cannot be read."""
    from harness.core.runs import RUNS_DIR

    try:
        raw = yaml.safe_load((RUNS_DIR / f"{TEMPLATE_RUNS[actuator]}.yaml").read_text())
    except (KeyError, OSError, yaml.YAMLError):
        return {}
    expect = raw.get("expect") if isinstance(raw, dict) else None
    if not isinstance(expect, dict):
        return {}
    return {k: v for k, v in expect.items()
            if not (isinstance(v, dict) and "modal_residual" in v)}


def _dump(path: Path, data: dict[str, Any], header: str) -> None:
    text = "".join(f"# {line}\n" for line in header.splitlines())
    path.write_text(text + yaml.safe_dump(data, sort_keys=False))


def calibrate(opts: Options, progress: Callable[[str], None] = lambda m: None) -> Calibration:
    if opts.actuator not in DEFAULT_ANGLE_DEG:
        raise ConfigError(f"--actuator: expected wheel or valves, got {opts.actuator!r}")
    if not opts.target_ratio > 1:
        raise ConfigError(f"--target-ratio: expected a ratio > 1, got {opts.target_ratio}")
    rig: RigConfig = load_rig(opts.rig)
    rig_ref = rig_reference(opts.rig)
    bus = opts.bus or virtual_bus(rig.name)
    spec_bus = parse_bus(bus)
    clock = "lockstep" if spec_bus.in_process else "realtime"
    plan = plan_excitation(rig, opts.actuator, rig_ref=rig_ref, rate_hz=opts.rate_hz,
                           torque_n_m=opts.excite_torque_n_m)
    c = Calibration(opts, plan)
    angle = opts.angle_deg if opts.angle_deg is not None else DEFAULT_ANGLE_DEG[opts.actuator]
    excite_run = run_from_dict(plan.run_dict(bus, clock), source="calibrate excitation")
    # the slew itself must be possible too (limits), before anything is sent: the
    # excitation and the unshaped slew at the predicted modes, each against the run's and
    # the rig's limits (the shaped slews stay within the unshaped one's angle)
    spec = slew_spec(rig, opts.actuator, angle, opts.rate_hz, rig_ref, bus, clock, 1.0)
    refuse_beyond_limits(excite_run, build_controller(excite_run))
    predicted = [Mode(p.omega_rad_s, p.damping_ratio) for p in plan.predicted]
    refuse_beyond_limits(*build(spec, "calibrate-unshaped", "",
                                baseline_controller(spec, predicted)))
    if opts.dry_run:
        return c
    c.folder = output_folder(opts.out, rig.name, opts.actuator)
    runs_dir = c.folder / "runs"
    freqs = ", ".join(f"{b.omega_rad_s:.4g}" for b in plan.bursts)
    progress(f"calibrate 1/4: exciting ({opts.actuator} bursts at {freqs} rad/s, "
             f"{plan.duration_s:.1f} s of rig time) ...")
    res = _run(excite_run, runs_dir, opts.bus, clock)
    c.excitation_dir = res.run_dir

    progress("calibrate 2/4: identifying the modes from the tip accelerometer ...")
    ident = identify_run(res.run_dir)
    c.identification = ident
    c.modes = [Mode(m.omega_rad_s, m.damping_ratio, m.sigma_omega_rad_s, m.sigma_damping)
               for m in ident.modes]
    c.matches, miss = match_predictions(plan, c.modes)
    c.notes += [u.message() for u in plan.unreachable] + miss + list(plan.notes)
    if not c.modes:
        raise CalibrationError("identification found no mode in the excitation run "
                               f"{res.run_dir}: " + "; ".join(ident.notes[-5:]))
    for m in c.modes:
        progress(f"  identified {m.omega_rad_s:.4f} +- {m.sigma_omega_rad_s:.2g} rad/s, "
                 f"damping {m.damping_ratio:.4f} +- {m.sigma_damping:.2g}")
    for n in miss:
        progress(f"  {n}")
    # predicted modes not identified (unreachable or missed) stay in the residual fit at
    # their predicted frequency and damping, so that it is not blind to what a slew leaves
    # in them; the shapers are designed on the identified modes only
    c.unidentified = unidentified_modes(plan, c.matches)
    if c.unidentified:
        c.notes.append("the residual fit also holds the predicted, unidentified mode(s) "
                       + ", ".join(f"{m.omega_rad_s:.4g} rad/s (damping {m.damping_ratio:.3g})"
                                   for m in c.unidentified)
                       + " so that it sees what the slews leave there")

    progress("calibrate 3/4: designing and scoring candidates ...")
    spec = slew_spec(rig, opts.actuator, angle, opts.rate_hz, rig_ref, bus, clock,
                     window_for(c.modes))
    c.spec = spec
    c.notes += list(spec.notes)
    if opts.actuator == "wheel":
        c.candidates = wheel_candidates(spec, c.modes)
    else:
        c.candidates = valve_candidates(spec, c.modes, 1.0 / opts.rate_hz)
    predict_ratios(c.candidates, None)
    for cand in c.candidates:
        progress(f"  {cand.label}: " + (
            f"+{cand.added_s:.3f} s, worst V over the bands "
            + " / ".join(f"{v:.2g}" for v in cand.worst_percent) + " %"
            if cand.feasible else f"not feasible: {cand.reason}"))

    feasible = [x for x in c.candidates if x.feasible]
    if opts.max_verify is not None:
        feasible = sorted(feasible, key=lambda x: (x.predicted_ratio < opts.target_ratio,
                                                   x.cost()))[: opts.max_verify]
    n_runs = 1 + len(feasible)
    desc = f"{opts.actuator} slew of {angle:g} deg on {rig.name}"
    base_name = safe_name(f"calibrate-{rig.name}-{opts.actuator}-unshaped")
    progress(f"calibrate 4/4: verifying on the rig: unshaped (1/{n_runs}) ...")
    run, ctrl = build(spec, base_name, f"harness calibrate: unshaped {desc} (baseline)",
                      baseline_controller(spec, c.modes))
    c.baseline = measure(_run(run, runs_dir, opts.bus, clock), ctrl, c.analysis_modes)
    c.baseline["ratio_fitted"] = 1.0
    c.baseline["run"] = run_dict(spec, base_name, run.data["description"],
                                 baseline_controller(spec, c.modes), run.data["duration_s"])
    weights = [m["amplitude_m_s2"]
               for m in c.baseline["fitted"]["by_mode_at_start"][: len(c.modes)]]
    predict_ratios(c.candidates, weights)
    ref = c.baseline
    for i, cand in enumerate(feasible):
        progress(f"calibrate 4/4: verifying on the rig: {cand.label} ({i + 2}/{n_runs}) ...")
        name = safe_name(f"calibrate-{rig.name}-{opts.actuator}-{cand.key}")
        run, ctrl = build(spec, name, f"harness calibrate: {cand.label} {desc}", cand.controller)
        row = measure(_run(run, runs_dir, opts.bus, clock), ctrl, c.analysis_modes)
        row["run"] = run_dict(spec, name, run.data["description"], cand.controller,
                              run.data["duration_s"])
        row["ratio_fitted"] = ref["fitted"]["peak_m_s2"] / row["fitted"]["peak_m_s2"]
        # below 2 sigma the fitted peak is the fit's noise: the ratio the window can show
        row["noise_limited"] = row["fitted"]["peak_m_s2"] < 2 * row["fitted"]["sigma_m_s2"]
        row["ratio_resolvable"] = ref["fitted"]["peak_m_s2"] / (2 * row["fitted"]["sigma_m_s2"])
        row["ratio_raw"] = ref["raw"]["peak_m_s2"] / row["raw"]["peak_m_s2"]
        if row["truth"] is not None:
            row["ratio_truth"] = ref["truth"]["peak_m_s2"] / row["truth"]["peak_m_s2"]
        judge(c, row)
        claim = residual_expect(c, row, cand.label)
        kept = template_expect(opts.actuator)
        if claim or kept:
            row["run"]["expect"] = {**kept, **claim}
        c.verified[cand.key] = row
        truth = (f", truth {row['truth']['peak_m_s2']:.2e} ({row['ratio_truth']:.1f}x)"
                 if row["truth"] is not None else "")
        noise = (f", at the fit's noise (2 sigma: {row['ratio_resolvable']:.1f}x)"
                 if row["noise_limited"] else "")
        progress(f"  fitted {row['fitted']['peak_m_s2']:.2e} m/s^2 "
                 f"({row['ratio_fitted']:.1f}x below unshaped{noise}){truth}")
    recommend(c)
    write_outputs(c)
    return c


def write_outputs(c: Calibration) -> None:
    """Run files (recommended, baseline, every verified candidate), results.json, report."""
    from harness.calibration.report import write_report

    assert c.folder is not None and c.baseline is not None
    cand_dir = c.folder / "candidates"
    cand_dir.mkdir(exist_ok=True)
    for key, row in c.verified.items():
        _dump(cand_dir / f"{safe_name(key)}.yaml", row["run"],
              f"harness calibrate candidate {key}: fitted residual {row['ratio_fitted']:.1f}x "
              "below the unshaped slew")
    claim = (c.verified[c.recommended]["run"].get("expect", {}).get(
        "residual_within_calibration") if c.recommended is not None else None)
    if claim is not None:
        c.baseline["run"]["expect"] = baseline_expect(c, claim["max_m_s2"])
    c.baseline_run_file = c.folder / "baseline.yaml"
    _dump(c.baseline_run_file, c.baseline["run"],
          "harness calibrate: the unshaped slew (baseline), same angle and torque")
    if c.recommended is not None:
        row = c.verified[c.recommended]
        c.run_file = c.folder / "recommended.yaml"
        truth = (f"; noise-free truth {row['ratio_truth']:.1f}x" if "ratio_truth" in row
                 else "")
        _dump(c.run_file, row["run"],
              f"harness calibrate: recommended shaped slew ({c.recommended}).\n"
              f"Measured residual (identified modes fitted to the recording): "
              f"{row['fitted']['peak_m_s2']:.3g} m/s^2, {row['ratio_fitted']:.1f}x below the "
              f"unshaped slew ({c.baseline['fitted']['peak_m_s2']:.3g} m/s^2){truth}.\n"
              f"Target {'met' if c.target_met else 'NOT met'}: {c.recommendation_note}.\n"
              f"Report: {c.folder / 'report.md'}")
    c.report = write_report(c)
    _write_recording(c)
    data = c.to_dict()
    (c.folder / "results.json").write_text(json.dumps(_jsonable(data), indent=2))


def _write_recording(c: Calibration) -> None:
    """calibration.rrd: modes, candidates' predicted and measured residuals and the
    verified pair in one layout (harness.review.calibration); the calibration stands
    without it."""
    try:
        from harness.review.calibration import write_calibration_rrd

        write_calibration_rrd(c)
    except Exception as exc:  # noqa: BLE001 - the run files and report are written
        print(f"harness calibrate: could not write calibration.rrd ({exc})", file=sys.stderr)


def _jsonable(x: Any) -> Any:
    if isinstance(x, dict):
        return {k: _jsonable(v) for k, v in x.items() if k != "series"}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, (np.floating, np.integer)):
        return x.item()
    if isinstance(x, float) and not math.isfinite(x):
        return None
    if isinstance(x, Path):
        return str(x)
    return x


def plan_run_dict(c: Calibration) -> dict[str, Any]:
    """The excitation run file (for --dry-run)."""
    return c.plan.run_dict(c.options.bus or virtual_bus(load_rig(c.options.rig).name))


__all__ = ["Calibration", "CalibrationError", "Options", "calibrate", "run_dict"]
