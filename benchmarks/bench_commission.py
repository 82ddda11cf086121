"""What `harness commission` measures of a rig as built, over noise seeds: the estimates
against the emulated truth, their reported sigma against their observed spread, and how
often a correctly wired rig within its file's tolerances is judged anything but PASS.

For each seed the devices rig is ``--devices`` (default sgsrt-as-built) with its
``noise_seed`` set to the seed (a rig file in a temporary folder that extends it), the rig
file under test ``--rig`` (default sgsrt), lockstep on the in-process virtual rig. Per
measured rig-file key the table gives: the emulated truth (``as_built_rig()``; the valves'
couples as the impulse they give over the on-time the file's delays assume, see
docs/commission.md), the mean estimate, the mean reported 1-sigma, the observed spread
(std over the seeds), the mean error in mean sigmas, and how many seeds were within 3
reported sigma. Then the verdicts (a binding FAIL here is a false FAIL; a DIFFERS is a
false difference) and the wall time of each commissioning (the command's own).

Run: .venv/bin/python benchmarks/bench_commission.py [--seeds 20] [--markdown]
Single-threaded on purpose (shared machine).
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import math  # noqa: E402
import statistics  # noqa: E402
import tempfile  # noqa: E402
from collections import Counter, defaultdict  # noqa: E402
from pathlib import Path  # noqa: E402

import yaml  # noqa: E402

from harness.commissioning.workflow import Options, commission  # noqa: E402
from rig_models.devices import G0_M_S2  # noqa: E402
from rig_models.rig_file import load_rig  # noqa: E402

DT_S = 0.002


def _on_time(tv: dict, negative: bool) -> float:
    """The 0.2 s pulse's on-time with a valve's delays as the emulated valve applies them
    (whole ticks)."""
    sfx = "_negative" if negative else ""
    opening = tv.get(f"open_delay{sfx}_s") or tv["open_delay_s"]
    closing = tv.get(f"close_delay{sfx}_s") or tv["close_delay_s"]
    return 0.2 + (round(closing / DT_S) - round(opening / DT_S)) * DT_S


def truths(devices: str, rig: str) -> dict[str, float]:
    t = load_rig(devices).as_built_rig().data
    model = load_rig(rig).data
    rw, tv, hs, acc, beam = (t[k] for k in ("reaction_wheel", "thruster_valves",
                                            "hub_sensor", "accelerometer", "beam"))
    file_on = _on_time(model["thruster_valves"], False)
    out = {"hub.inertia_kg_m2": t["hub"]["inertia_kg_m2"],
           "reaction_wheel.friction_coulomb_n_m": rw.get("friction_coulomb_n_m") or 0.0,
           "reaction_wheel.friction_viscous_n_m_s": rw.get("friction_viscous_n_m_s") or 0.0,
           "reaction_wheel.torque_lag_s": rw["torque_lag_s"],
           "thruster_valves.couple_n_m": tv["couple_n_m"] * _on_time(tv, False) / file_on,
           "thruster_valves.couple_negative_n_m":
               (tv.get("couple_negative_n_m") or tv["couple_n_m"]) * _on_time(tv, True)
               / file_on,
           "hub_sensor.rate_bias_rad_s": hs.get("rate_bias_rad_s") or 0.0,
           "accelerometer.bias_m_s2": (acc.get("bias_m_s2") or 0.0) + (
               1 + (acc.get("scale_error") or 0.0)) * G0_M_S2 * math.sin(
               acc.get("tilt_rad") or 0.0) * math.cos(-(acc.get("tilt_azimuth_rad") or 0.0))}
    factors = beam.get("frequency_factors") or []
    dampings = beam.get("damping_ratios") or []
    for k in range(beam["n_modes"]):
        out[f"beam.frequency_factors[{k}]"] = factors[k] if k < len(factors) else 1.0
        out[f"beam.damping_ratios[{k}]"] = dampings[k] if k < len(dampings) else \
            beam["damping_ratio"]
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--first-seed", type=int, default=1)
    ap.add_argument("--devices", default="sgsrt-as-built")
    ap.add_argument("--rig", default="sgsrt")
    ap.add_argument("--markdown", action="store_true", help="print the tables as markdown")
    args = ap.parse_args()
    truth = truths(args.devices, args.rig)
    est: dict[str, list[tuple[float, float]]] = defaultdict(list)
    verdicts: Counter[str] = Counter()
    failed: Counter[str] = Counter()
    differs: Counter[str] = Counter()
    walls = []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in range(args.first_seed, args.first_seed + args.seeds):
            devices = Path(tmp) / f"devices-{seed}.yaml"
            devices.write_text(yaml.safe_dump({"extends": args.devices, "name":
                                               f"{args.devices}-seed-{seed}",
                                               "noise_seed": seed}))
            c = commission(Options(rig=args.rig, out=Path(tmp) / "logs",
                                   devices_rig=str(devices)))
            verdicts[c.verdict] += 1
            walls.append(c.wall_time_s)
            for x in c.checks:
                if x.verdict == "FAIL":
                    failed[f"{x.name}: {x.check}"] += 1
                if x.verdict == "DIFFERS":
                    differs[x.key] += 1
                if x.key in truth and x.value is not None and x.sigma is not None:
                    est[x.key].append((float(x.value), float(x.sigma)))
            print(f"seed {seed}: {c.verdict} ({c.wall_time_s:.1f} s)", flush=True)
    rows = []
    for key, t in truth.items():
        got = est.get(key)
        if not got:
            rows.append((key, f"{t:.5g}", "not measured", "", "", "", ""))
            continue
        values = [v for v, _ in got]
        sigmas = [s for _, s in got]
        mean = statistics.fmean(values)
        sig = statistics.fmean(sigmas)
        spread = statistics.stdev(values) if len(values) > 1 else float("nan")
        inside = sum(abs(v - t) <= 3 * s for v, s in got)
        rows.append((key, f"{t:.5g}", f"{mean:.5g}", f"{sig:.2g}", f"{spread:.2g}",
                     f"{(mean - t) / sig:+.2f}", f"{inside}/{len(got)}"))
    head = ("key", "emulated truth", "mean estimate", "mean 1 sigma", "observed spread",
            "mean error / sigma", "within 3 sigma")
    _print(head, rows, args.markdown)
    print()
    n = sum(verdicts.values())
    print(f"{n} seeds, devices {args.devices}, rig file {args.rig}: "
          + ", ".join(f"{k} {v}" for k, v in sorted(verdicts.items())))
    print(f"binding FAILs (false): {sum(failed.values())}"
          + "".join(f"\n  {k}: {v}" for k, v in failed.most_common()))
    print(f"DIFFERS rows (false): {sum(differs.values())}"
          + "".join(f"\n  {k}: {v}" for k, v in differs.most_common()))
    print(f"wall time per commissioning (lockstep, in process): median "
          f"{statistics.median(walls):.1f} s, {min(walls):.1f} to {max(walls):.1f} s")


def _print(head: tuple[str, ...], rows: list[tuple[str, ...]], markdown: bool) -> None:
    if markdown:
        print("| " + " | ".join(head) + " |")
        print("|" + "---|" * len(head))
        for r in rows:
            print("| " + " | ".join(r) + " |")
        return
    widths = [max(len(h), *(len(r[i]) for r in rows)) for i, h in enumerate(head)]
    print("  ".join(h.ljust(w) for h, w in zip(head, widths, strict=True)))
    for r in rows:
        print("  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)))


if __name__ == "__main__":
    main()
