"""`harness frf RUN_DIR [--input wheel|piezo1|piezo2] [--output NAME ...] [--decay RUN_DIR]`:
frequency responses of a recorded run, and the modes fitted to them (docs/frf.md).

The input is the MEASURED one: the wheel's torque telemetry ``/wheel/torque_n_m`` (the
torque on the hub), or the piezo amplifier's command ``/piezo/cmd_ch1_v`` / ``cmd_ch2_v``
(the amplifier has no read-back). Outputs: ``hub_rate`` (rad/s, from
``/attitude/rate_deg_s``), ``tip_accel`` (m/s^2), ``piezo_sensor1`` / ``piezo_sensor2`` (V);
by default the hub rate and the tip acceleration for the wheel, the tip acceleration and the
same channel's sensor patch for a piezo.

After a periodic ``multisine`` run (its design in summary.json) the settling periods are
dropped and every whole measured period is one average at the excited lines; after any
other run (a ``signal: random`` multisine, a ``chirp``, a recording of your own) Welch
segments of ``--segment-s`` (default: one period of a random multisine, one sweep of a
chirp, else 20 s). H1, H2, the coherence and each point's 1-sigma of |H|
(Bendat & Piersol: sqrt(1 - coh) / (sqrt(2 n_avg) sqrt(coh))). Modes: a sum of second-order
modes fitted to H1 by weighted least squares, started from the FRF's peaks near the rig
model's hub-free modes in the band; 1-sigma from the Jacobian. Each is compared with the
model's mode, with the measured-to-model magnitude ratio at it, and with ``harness
identify``'s result of a free-decay run (``--decay``).

The recording is read block by block into the sums over periods or segments (memory does
not grow with the record's length); an analysis that takes more than a second tells its
progress on stderr.

Writes frf.json, frf.csv, frf.png (Bode magnitude, phase and coherence: measured with
its 1-sigma band, the model) and frf.rrd (the same in the Rerun viewer, over a frequency
timeline in mHz, with its layout: ``harness.review.bode``) in the run directory; prints the
modes' table.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from harness.commands import examples
from harness.core.frf import INPUTS, OUTPUTS, analyse


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("frf", help="frequency responses of a run, with the modes fitted to them",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter,
                       epilog=examples("harness frf logs/20260101T120000.000000Z-frf-wheel",
                                       "harness frf RUN --output tip_accel --decay DECAY_RUN",
                                       "harness frf RUN --input piezo1 --json"))
    p.add_argument("source", type=Path, help="run directory")
    p.add_argument("--input", choices=sorted(INPUTS),
                   help="the input channel (default: the run's excitation's, else wheel)")
    p.add_argument("--output", action="append", choices=sorted(OUTPUTS),
                   help="an output channel; repeat for several (default: see above)")
    p.add_argument("--decay", type=Path, metavar="RUN_DIR",
                   help="a free-decay run: its 'harness identify' modes in the table")
    p.add_argument("--segment-s", type=float,
                   help="Welch segment length (s) for a non-periodic excitation")
    p.add_argument("--no-plot", action="store_true", help="do not write frf.png nor frf.rrd")
    p.add_argument("--json", action="store_true", help="frf.json's content on stdout")
    p.set_defaults(func=cmd_frf)


PROGRESS_AFTER_S = 1.0
"""Progress goes to stderr only once the analysis has taken this long (a short record's
analysis says nothing until its table)."""


class Progress:
    """Prints the analysis's steps to stderr, from ``PROGRESS_AFTER_S`` after the start."""

    def __init__(self, after_s: float | None = None) -> None:
        self.start = time.monotonic()
        self.after_s = PROGRESS_AFTER_S if after_s is None else after_s

    def __call__(self, message: str) -> None:
        if time.monotonic() - self.start >= self.after_s:
            print(f"harness frf: {message} ...", file=sys.stderr, flush=True)


def cmd_frf(args: argparse.Namespace) -> int:
    try:
        doc = analyse(args.source, args.input, args.output, args.decay, args.segment_s,
                      plot=not args.no_plot, progress=Progress())
    except (ValueError, OSError, KeyError) as exc:
        print(f"harness frf: {exc}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(doc, default=float))
        return 0
    nan = float("nan")
    print(f"{'output':>14} {'mode':>4} {'rad/s':>9} {'+-':>8} {'zeta':>7} {'+-':>7} "
          f"{'model rad/s':>11} {'err %':>7} {'model zeta':>10} {'coh':>6} {'|H|/model':>9} "
          f"{'decay rad/s':>11} {'decay zeta':>10}")
    for name, e in doc["outputs"].items():
        for m in e["modes"]:
            print(f"{name:>14} {m['model_mode']:>4} {m['omega_rad_s']:>9.4f} "
                  f"{m['sigma_omega_rad_s']:>8.4f} {m['damping_ratio']:>7.4f} "
                  f"{m['sigma_damping']:>7.4f} {m['model_omega_rad_s']:>11.4f} "
                  f"{m['omega_error_percent']:>7.3f} {m['model_damping_ratio']:>10.4f} "
                  f"{m['coherence_at_mode']:>6.3f} {m['magnitude_ratio_to_model']:>9.4f} "
                  f"{m.get('decay_omega_rad_s', nan):>11.4f} "
                  f"{m.get('decay_damping_ratio', nan):>10.4f}"
                  + ("" if m["determined"] else "  (not determined)"))
        if "fit_error" in e:
            print(f"{name}: no modal fit: {e['fit_error']}")
    for key, path in doc["files"].items():
        print(f"{key}: {path}", file=sys.stderr)
    return 0
