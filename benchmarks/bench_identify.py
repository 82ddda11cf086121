"""Monte-Carlo check of `identify()` against the Cramer-Rao lower bound.

For each scenario, ``--runs`` noisy free-decay records (500 Hz, 60 s, white noise
0.005 m/s^2 rms, quantised to 1e-3 m/s^2) are identified. Per mode the table gives:
the spread (std) of the parametric frequency and damping estimates, the CRLB (white noise,
all parameters unknown), their ratio, the mean reported 1-sigma, the bias, and the
fraction of runs whose error is within 2 reported sigma (about 95 % if the sigmas are
right). The FFT-peak view (the paper's method) is listed beside it: its bias is measured
against the damped frequency w sqrt(1 - zeta^2) that an FFT peak shows.

Run: .venv/bin/python benchmarks/bench_identify.py [--runs 50] [--seed 1]
Single-threaded on purpose (shared machine).
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from dataclasses import dataclass  # noqa: E402

import numpy as np  # noqa: E402

from harness.identification import DampedMode, cramer_rao_bound, identify  # noqa: E402

FS_HZ = 500.0
DURATION_S = 60.0
NOISE_RMS = 0.005
QUANT_STEP = 1e-3


@dataclass(frozen=True)
class Scenario:
    name: str
    modes: tuple[DampedMode, ...]


SCENARIOS = (
    Scenario(
        "rig, zeta 0.05",
        (
            DampedMode(2.9, 0.05, 0.5, 0.3),
            DampedMode(13.5, 0.05, 0.3, 1.0),
            DampedMode(37.0, 0.05, 0.2, 2.0),
        ),
    ),
    Scenario(
        "rig, zeta 0.005",
        (
            DampedMode(2.9, 0.005, 0.5, 0.3),
            DampedMode(13.5, 0.005, 0.3, 1.0),
            DampedMode(37.0, 0.005, 0.2, 2.0),
        ),
    ),
    Scenario(
        "rig, weak (0.1 m/s^2), zeta 0.05",
        (DampedMode(2.9, 0.05, 0.1, 0.3), DampedMode(13.5, 0.05, 0.1, 1.0)),
    ),
    Scenario(
        "close modes 2.0 / 2.15 rad/s, zeta 0.02",
        (DampedMode(2.0, 0.02, 0.5, 0.3), DampedMode(2.15, 0.02, 0.4, 1.0)),
    ),
)


def synth(modes: tuple[DampedMode, ...], rng: np.random.Generator) -> tuple[np.ndarray, ...]:
    t = np.arange(int(DURATION_S * FS_HZ)) / FS_HZ
    x = np.zeros_like(t)
    for m in modes:
        wd = m.omega_rad_s * np.sqrt(1.0 - m.damping_ratio**2)
        x += (
            m.amplitude
            * np.exp(-m.damping_ratio * m.omega_rad_s * t)
            * np.cos(wd * t + m.phase_rad)
        )
    x += NOISE_RMS * rng.standard_normal(t.size)
    return t, np.round(x / QUANT_STEP) * QUANT_STEP


def run_scenario(sc: Scenario, runs: int, rng: np.random.Generator) -> list[str]:
    k = len(sc.modes)
    est = np.full((runs, k, 2), np.nan)  # omega, zeta
    sig = np.full((runs, k, 2), np.nan)
    fft = np.full((runs, k), np.nan)
    failures = 0
    for r in range(runs):
        t, x = synth(sc.modes, rng)
        res = identify(t, x)
        for j, m in enumerate(sc.modes):
            if not res.modes:
                break
            best = min(res.modes, key=lambda q: abs(q.omega_rad_s - m.omega_rad_s))
            if abs(best.omega_rad_s / m.omega_rad_s - 1.0) > 0.02:
                failures += 1
                continue
            est[r, j] = (best.omega_rad_s, best.damping_ratio)
            sig[r, j] = (best.sigma_omega_rad_s, best.sigma_damping)
            peak = res.matching_fft_peak(best)
            if peak is not None:
                fft[r, j] = peak.omega_rad_s
    crlb = cramer_rao_bound(
        sc.modes, fs_hz=FS_HZ, n_samples=int(DURATION_S * FS_HZ), noise_rms=NOISE_RMS
    )
    rows = [f"\n## {sc.name}  ({runs} runs, modes missed: {failures})", ""]
    rows.append(
        "| mode | quantity | true | bias | std | CRLB | std/CRLB | mean sigma "
        "| std/sigma | within 2 sigma |"
    )
    rows.append("|---|---|---|---|---|---|---|---|---|---|")
    for j, m in enumerate(sc.modes):
        b = crlb.modes[j]
        for q, (name, true, bound) in enumerate(
            (
                ("omega rad/s", m.omega_rad_s, b.sigma_omega_rad_s),
                ("zeta", m.damping_ratio, b.sigma_damping),
            )
        ):
            e = est[:, j, q]
            s = sig[:, j, q]
            ok = np.isfinite(e)
            err = e[ok] - true
            std = float(np.std(e[ok], ddof=1)) if ok.sum() > 1 else float("nan")
            within = float(np.mean(np.abs(err) <= 2.0 * s[ok])) if ok.any() else float("nan")
            rows.append(
                f"| {j + 1} | {name} | {true:.4g} | {np.mean(err) / true:+.3%} | {std:.3g} "
                f"| {bound:.3g} | {std / bound:.2f} | {np.mean(s[ok]):.3g} "
                f"| {std / np.mean(s[ok]):.2f} | {within:.0%} |"
            )
    rows.append("")
    rows.append("FFT-peak view (paper's method), against the damped frequency:")
    rows.append("")
    rows.append("| mode | omega_d true | FFT mean | FFT bias | FFT std | param. std | found |")
    rows.append("|---|---|---|---|---|---|---|")
    for j, m in enumerate(sc.modes):
        wd = m.omega_rad_s * np.sqrt(1.0 - m.damping_ratio**2)
        f = fft[:, j]
        ok = np.isfinite(f)
        if not ok.any():
            rows.append(f"| {j + 1} | {wd:.4f} | - | - | - | - | 0/{runs} |")
            continue
        std_f = float(np.std(f[ok], ddof=1)) if ok.sum() > 1 else float("nan")
        std_p = float(np.nanstd(est[:, j, 0], ddof=1))
        rows.append(
            f"| {j + 1} | {wd:.4f} | {np.mean(f[ok]):.4f} | {np.mean(f[ok]) / wd - 1:+.3%} "
            f"| {std_f:.3g} | {std_p:.3g} | {ok.sum()}/{runs} |"
        )
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=50)
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args(argv)
    if args.runs < 2:
        parser.error("--runs must be >= 2")
    rng = np.random.default_rng(args.seed)
    print(
        f"# identify() Monte Carlo: {FS_HZ:g} Hz, {DURATION_S:g} s, noise {NOISE_RMS} m/s^2 rms,"
        f" quantisation {QUANT_STEP} m/s^2, seed {args.seed}"
    )
    for sc in SCENARIOS:
        t0 = time.perf_counter()
        print("\n".join(run_scenario(sc, args.runs, rng)))
        print(f"\n({time.perf_counter() - t0:.1f} s)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
