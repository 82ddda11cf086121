"""The frequency responses of a recorded run and the modes fitted to them: what
``harness frf`` prints and writes and what an ``frf:`` criterion judges (docs/frf.md;
the command's help says what it reads and computes).
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from harness.controllers.excitation import model_vectors

INPUTS = {"wheel": ("/wheel/torque_n_m", "N m"), "piezo1": ("/piezo/cmd_ch1_v", "V"),
          "piezo2": ("/piezo/cmd_ch2_v", "V")}
OUTPUTS = {"hub_rate": ("/attitude/rate_deg_s", math.pi / 180, "rad/s"),
           "tip_accel": ("/tip/accel_m_s2", 1.0, "m/s^2"),
           "piezo_sensor1": ("/piezo/sensor_ch1_v", 1.0, "V"),
           "piezo_sensor2": ("/piezo/sensor_ch2_v", 1.0, "V")}
DEFAULT_OUTPUTS = {"wheel": ["hub_rate", "tip_accel"],
                   "piezo1": ["tip_accel", "piezo_sensor1"],
                   "piezo2": ["tip_accel", "piezo_sensor2"]}
DEFAULT_SEGMENT_S = 20.0
HEAD_ROWS = 1000
"""The sample interval is the median step of the record's first this many rows."""
PROGRESS_EVERY_S = 1.0
"""The reading's progress is told at most this often (wall time)."""
DETERMINED = (0.05, 0.5)
"""A fitted mode counts as determined when its frequency's 1-sigma is below 5 % and its
damping's below 50 % of the value (as ``harness identify``)."""


def _load(run_dir: Path) -> tuple[dict[str, Any], dict[str, Any]]:
    from rig_models.yaml_file import load_yaml

    if not run_dir.is_dir() or not (run_dir / "run.rrd").exists():
        raise ValueError(f"{run_dir}: not a run directory (no run.rrd)")
    cfg_path, summary_path = run_dir / "config.yaml", run_dir / "summary.json"
    if not cfg_path.exists():
        raise ValueError(f"{run_dir}: no config.yaml (the run's rig is needed)")
    cfg = load_yaml(cfg_path, "config.yaml")
    summary = json.loads(summary_path.read_text()) if summary_path.exists() else {}
    return cfg, summary


def analyse(run_dir: Path, input_name: str | None = None, outputs: list[str] | None = None,
            decay: Path | None = None, segment_s: float | None = None,
            plot: bool = True, progress: Callable[[str], None] | None = None
            ) -> dict[str, Any]:
    """frf.json's document (and the files) for one run. ``progress`` is told what is being
    done (the reading at most once a second of wall time)."""
    import numpy as np

    from harness.identification.frf import fit_modes, refine_guess, state_space_frf
    from harness.record.output import fresh_output_path, write_text_atomic
    from rig_models.rig_file import rig_from_dict

    say = progress or (lambda _msg: None)
    cfg, summary = _load(run_dir)
    design = summary.get("controller_design") or {}
    if not isinstance(design, dict) or "excitation" not in design:
        design = {}
    input_name = input_name or design.get("input") or "wheel"
    outputs = outputs or DEFAULT_OUTPUTS[input_name]
    rig = rig_from_dict(cfg["rig"], source="config.yaml rig")
    in_ch, in_unit = INPUTS[input_name]
    dt, estimates = _estimate(run_dir, design, input_name, outputs, segment_s, say)
    wn, zeta = rig.plant.hub_free_modal_damping()
    doc: dict[str, Any] = {
        "run": str(run_dir), "input": input_name, "input_channel": in_ch,
        "input_unit": in_unit, "excitation": design or None, "dt_s": dt,
        "model_hub_free": {"omega_rad_s": wn.tolist(), "damping_ratio": zeta.tolist()},
        "outputs": {}}
    decay_modes = None
    if decay is not None:
        say(f"identifying the free decay {decay}")
        decay_modes = _decay_modes(decay)
        doc["decay"] = {"run": str(decay), "modes": decay_modes}
    for out in outputs:
        ch, _, unit = OUTPUTS[out]
        est = estimates[out]
        say(f"fitting the modes of {input_name} -> {out}")
        a, b, c, d = model_vectors(rig, input_name, out)
        h_model = state_space_frf(a, b, c, d, est.freq_hz)
        f_lo, f_hi = est.freq_hz.min(), est.freq_hz.max()
        in_band = [i for i, w in enumerate(wn) if f_lo < w / (2 * math.pi) < f_hi]
        entry: dict[str, Any] = {"channel": ch, "unit": f"{unit} per {in_unit}",
                                 **est.to_dict(),
                                 "model_mag": np.abs(h_model).tolist(),
                                 "model_phase_rad": np.angle(h_model).tolist()}
        fit = None
        if in_band:
            guesses = np.array([refine_guess(est.freq_hz, est.h1, wn[i]) for i in in_band])
            try:
                fit = fit_modes(est.freq_hz, est.h1, est.sigma_rel, guesses)
            except ValueError as exc:
                entry["fit_error"] = str(exc)
        modes = []
        if fit is not None:
            entry["fit"] = fit.to_dict()
            entry["fit_mag"] = np.abs(fit.evaluate(est.freq_hz)).tolist()
            for m, i in zip(fit.modes, in_band, strict=True):
                k = int(np.argmin(np.abs(est.freq_hz - m.freq_hz)))
                row = {**m.to_dict(), "model_mode": i + 1,
                       "model_omega_rad_s": float(wn[i]),
                       "model_damping_ratio": float(zeta[i]),
                       "omega_error_percent": 100 * (m.omega_rad_s / wn[i] - 1),
                       "damping_error_percent": 100 * (m.damping_ratio / zeta[i] - 1),
                       "coherence_at_mode": float(est.coherence[k]),
                       "magnitude_ratio_to_model": float(abs(est.h1[k]) / abs(h_model[k])),
                       "determined": bool(
                           m.sigma_omega_rad_s < DETERMINED[0] * m.omega_rad_s
                           and m.sigma_damping < DETERMINED[1] * m.damping_ratio)}
                if decay_modes is not None:
                    near = [dm for dm in decay_modes if dm.get("model_mode") == i + 1]
                    if near:
                        row["decay_omega_rad_s"] = near[0]["omega_rad_s"]
                        row["decay_sigma_omega_rad_s"] = near[0]["sigma_omega_rad_s"]
                        row["decay_damping_ratio"] = near[0]["damping_ratio"]
                        row["decay_sigma_damping"] = near[0]["sigma_damping"]
                modes.append(row)
        entry["modes"] = modes
        entry["min_coherence_at_modes"] = min((m["coherence_at_mode"] for m in modes),
                                              default=None)
        doc["outputs"][out] = entry
    write_text_atomic(fresh_output_path(run_dir / "frf.json"), json.dumps(doc, default=float))
    write_text_atomic(fresh_output_path(run_dir / "frf.csv"), _csv(doc))
    doc["files"] = {"json": str(run_dir / "frf.json"), "csv": str(run_dir / "frf.csv")}
    if plot:
        from harness.review.bode import write_frf_rrd

        say("writing frf.png and frf.rrd")

        doc["files"]["png"] = str(_plot(doc, fresh_output_path(run_dir / "frf.png")))
        doc["files"]["rrd"] = str(write_frf_rrd(fresh_output_path(run_dir / "frf.rrd"),
                                                run_dir, doc))
    return doc


def is_periodic(design: dict[str, Any]) -> bool:
    """Whether a run's excitation (its summary.json design) repeats whole periods."""
    return design.get("excitation") == "multisine" and design.get("signal") != "random"


def _estimate(run_dir: Path, design: dict[str, Any], input_name: str, outputs: list[str],
              segment_s: float | None, say: Callable[[str], None]
              ) -> tuple[float, dict[str, Any]]:
    """(the sample interval, each output's ``FrfEstimate``), the recording read block by
    block into the running sums (``PeriodicSpectra`` for a periodic excitation, else
    ``WelchSpectra``): memory does not grow with the record's length."""
    import numpy as np

    from harness.identification.frf import PeriodicSpectra, WelchSpectra
    from harness.record.reader import aligned_scalar_blocks

    in_ch = INPUTS[input_name][0]
    channels = [OUTPUTS[o][0] for o in outputs]
    scales = np.array([OUTPUTS[o][1] for o in outputs])[:, None]
    blocks = aligned_scalar_blocks(run_dir / "run.rrd", [in_ch, *channels])
    head: list[tuple[np.ndarray, dict[str, np.ndarray]]] = []
    held = 0
    for block in blocks:  # the first rows, for the sample interval
        head.append(block)
        held += len(block[0])
        if held >= HEAD_ROWS:
            break
    if not head:
        raise ValueError(f"{run_dir / 'run.rrd'}: no samples of {in_ch}")
    t_head = np.concatenate([b[0] for b in head])
    dt = float(np.median(np.diff(t_head[:HEAD_ROWS])))
    periodic = is_periodic(design)
    lo = design.get("measure_start_s", -math.inf) - dt / 2
    hi = design.get("end_s", math.inf) - dt / 2
    acc: PeriodicSpectra | WelchSpectra
    if periodic:
        acc = PeriodicSpectra(int(design["period_samples"]), len(outputs))
    else:
        seg = segment_s or design.get("segment_s") or design.get("sweep_s") \
            or DEFAULT_SEGMENT_S
        acc = WelchSpectra(int(round(seg / dt)), len(outputs), dt)
    u_min, u_max = math.inf, -math.inf
    end = design.get("end_s")
    clock = time.monotonic()

    def feed(t: np.ndarray, cols: dict[str, np.ndarray]) -> None:
        nonlocal u_min, u_max, clock
        u = cols[in_ch]
        if len(u):
            u_min, u_max = min(u_min, float(np.min(u))), max(u_max, float(np.max(u)))
        i0, i1 = int(np.searchsorted(t, lo)), int(np.searchsorted(t, hi))
        if i1 > i0:
            acc.add(u[i0:i1], np.vstack([cols[c][i0:i1] for c in channels]) * scales)
        if time.monotonic() - clock >= PROGRESS_EVERY_S and len(t):
            clock = time.monotonic()
            of = f" of {end:.0f}" if end else ""
            say(f"read {t[-1]:.0f}{of} s of the record")

    for t, cols in head:
        feed(t, cols)
    del head
    for t, cols in blocks:
        feed(t, cols)
    if not u_max > u_min:
        raise ValueError(f"{in_ch} is constant: the input {input_name} was not excited "
                         "in this run (--input names the excited channel)")
    if isinstance(acc, PeriodicSpectra):
        ests = acc.estimates(dt)
    else:
        ests = acc.estimates(design.get("f0_hz", 0.0), design.get("f1_hz", math.inf))
    return dt, dict(zip(outputs, ests, strict=True))


def _decay_modes(decay: Path) -> list[dict[str, Any]]:
    from harness.core.identify import identify_record, load_windows

    out = identify_record(load_windows(decay))  # the windows' samples only
    return [{k: m.get(k) for k in ("omega_rad_s", "sigma_omega_rad_s", "damping_ratio",
                                    "sigma_damping", "model_mode")} for m in out["modes"]]


def _csv(doc: dict[str, Any]) -> str:
    lines = ["output,freq_hz,h1_mag,h1_phase_rad,h2_mag,coherence,sigma_mag_rel,model_mag,"
             "model_phase_rad"]
    for name, e in doc["outputs"].items():
        for row in zip(e["freq_hz"], e["h1_mag"], e["h1_phase_rad"], e["h2_mag"],
                       e["coherence"], e["sigma_mag_rel"], e["model_mag"],
                       e["model_phase_rad"], strict=True):
            lines.append(",".join([name] + [f"{v:.9g}" for v in row]))
    return "\n".join(lines) + "\n"


def _plot(doc: dict[str, Any], path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    outs = doc["outputs"]
    fig, axes = plt.subplots(3, len(outs), figsize=(6 * len(outs), 9), squeeze=False,
                             sharex="col", gridspec_kw={"height_ratios": [3, 2, 1]})
    for j, (name, e) in enumerate(outs.items()):
        f = np.asarray(e["freq_hz"])
        mag, sig = np.asarray(e["h1_mag"]), np.asarray(e["sigma_mag_rel"])
        ax = axes[0, j]
        ax.fill_between(f, mag * (1 - sig), mag * (1 + sig), color="tab:blue", alpha=0.3,
                        label="measured H1 +-1 sigma")
        ax.loglog(f, mag, color="tab:blue", lw=1)
        ax.loglog(f, e["model_mag"], color="k", ls="--", lw=1, label="rig model")
        if "fit_mag" in e:
            ax.loglog(f, e["fit_mag"], color="tab:red", lw=0.8, label="modal fit")
        for m in e["modes"]:
            ax.axvline(m["freq_hz"], color="tab:red", lw=0.5, alpha=0.6)
        ax.set_title(f"{doc['input']} -> {name} ({e['unit']})")
        ax.set_ylabel("|H|")
        ax.legend(fontsize=8)
        ax = axes[1, j]
        ph = np.unwrap(np.asarray(e["h1_phase_rad"]))
        ax.fill_between(f, np.degrees(ph - sig), np.degrees(ph + sig), color="tab:blue",
                        alpha=0.3)
        ax.semilogx(f, np.degrees(ph), color="tab:blue", lw=1)
        mph = np.unwrap(np.asarray(e["model_phase_rad"]))
        mph += 2 * np.pi * np.round((ph[0] - mph[0]) / (2 * np.pi))
        ax.semilogx(f, np.degrees(mph), color="k", ls="--", lw=1)
        ax.set_ylabel("phase (deg)")
        ax = axes[2, j]
        ax.semilogx(f, e["coherence"], color="tab:green", lw=1)
        ax.axhline(0.9, color="grey", ls=":", lw=0.8)
        ax.set_ylim(0, 1.05)
        ax.set_ylabel("coherence")
        ax.set_xlabel("frequency (Hz)")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
