"""`harness twin RUN_DIR [--rig R] [--json]`: how far the rig has moved from its model.

Replays the run's own recorded commands (wheel torque, valves, piezo voltages) through the
virtual rig's physics built from the same rig file (its config.yaml's, or ``--rig``'s), and
reports per sensor channel the mismatch with the recording: the residual's rms, its worst
sample and that sample's time, and the rms over the channel's noise in the rig file (about
1 when the rig matches its model). Beside it the run's identified modes against the
model's. The bus is bypassed: the twin checks the physics, not the protocol (see
docs/history.md). Every channel is judged: one without a noise in the rig file takes the
resolution its device reports it in (the rig file's device data) or the recording's
smallest step. The channels are listed worst first. Exit 0 every channel within
``--max-ratio`` (default 3) of its noise, 1 a channel beyond it (an ALARM line names each,
worst first), 2 bad input.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from harness.commands import examples


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("twin", help="a run's commands through the model: the twin's residual",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("run_dir", type=Path, help="a recorded run directory")
    p.add_argument("--rig", help="the rig file the twin is built from (default: the run's)")
    p.add_argument("--max-ratio", type=float, default=None, metavar="R",
                   help="alarm threshold: exit 1 when a channel's residual rms is more than R "
                   "times its noise rms (default 3)")
    p.add_argument("--json", action="store_true", help="JSON on stdout")
    p.epilog = examples(
        "harness twin logs/20260101T120000.000000Z-slew-rw",
        "harness twin logs/20260101T120000.000000Z-slew-rw --rig sgsrt --json")
    p.set_defaults(func=cmd_twin)


def cmd_twin(args: argparse.Namespace) -> int:
    import math

    # imported when used: start-up of `harness --help`
    from harness.history.twin import MAX_RATIO, TwinError, twin_residual

    ratio = MAX_RATIO if args.max_ratio is None else args.max_ratio
    if not (math.isfinite(ratio) and ratio > 0):
        print(f"harness twin: --max-ratio: expected a number > 0, got {ratio!r}",
              file=sys.stderr)
        return 2
    try:
        out = twin_residual(args.run_dir, args.rig, ratio)
    except TwinError as exc:
        print(f"harness twin: {exc}", file=sys.stderr)
        return 2
    code = 1 if out["beyond"] else 0
    if args.json:
        print(json.dumps(out, indent=2))
        return code
    print(f"twin of {out['run_dir']} on {out['rig']} ({out['ticks']} ticks at "
          f"{out['rate_hz']:g} Hz)")
    from harness.review.units import split_unit, unit_text

    def unit(channel: str) -> str:
        return unit_text(split_unit(channel.rsplit("/", 1)[-1])[1])

    # every value with its unit, as in verdicts (the channel's)
    print(f"{'channel':<22} {'rms':>14} {'worst':>14} {'at':>9} {'recorded rms':>14} "
          f"{'rms / noise':>11}")
    for r in out["channels"]:
        u = unit(r["channel"])
        ratio = "-" if r["rms_over_noise"] is None else f"{r['rms_over_noise']:.2f}"
        rms, worst, rec = (f"{r[k]:.3g} {u}".rstrip() for k in ("rms", "worst",
                                                                  "recorded_rms"))
        at = f"{r['worst_time_s']:.3f} s"
        print(f"{r['channel']:<22} {rms:>14} {worst:>14} {at:>9} {rec:>14} {ratio:>11}")
    if out["worst_channel"]:
        w = next(r for r in out["channels"] if r["channel"] == out["worst_channel"])
        print(f"largest residual over its noise: {w['channel']}, worst {w['worst']:.3g} "
              f"{unit(w['channel'])} at t = {w['worst_time_s']:.3f} s "
              f"({w['rms_over_noise']:.2f} x the noise rms)")
    if out["identified_modes"]:
        print("identified modes against the model's:")
        for m in out["identified_modes"]:
            sig = m["sigma_omega_rad_s"]
            s = f" +- {sig:.3g}" if sig else ""
            cs = "" if m["change_sigmas"] is None else f", {m['change_sigmas']:+.1f} sigma"
            print(f"  mode {m['model_mode']}: {m['omega_rad_s']:.4f}{s} rad/s, model "
                  f"{m['model_omega_rad_s']:.4f} rad/s ({m['change_percent']:+.2f} %{cs})")
    for n in out["notes"]:
        print(f"note: {n}")
    for name in out["beyond"]:  # worst first
        r = next(r for r in out["channels"] if r["channel"] == name)
        print(f"ALARM {name}: residual rms {r['rms_over_noise']:.3g} x its noise rms "
              f"({r['noise_from']}), beyond {out['max_ratio']:g}", file=sys.stderr)
    return code
