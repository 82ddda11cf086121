"""What end-to-end checksums cost on the tick: the sgsrt-dbc2 rig as shipped (checksums on
its commands and on three of its telemetry frames) against the same rig file with its
``checksums:`` removed (the same DBC and frame lengths: only the checksums differ).

1. Per frame: each protected map's positional command encoder (the harness's, every tick)
   and telemetry decode (the harness's) and encoder (the virtual rig's), with and without
   its checksum, interleaved round by round (median ns a call).
2. The loop: slew-rw in lockstep on both rig files, interleaved run by run
   (``bench_loop.bench_rigs``): the loop's CPU per tick and the ratio of the two.

    .venv/bin/python benchmarks/bench_e2e.py [--repeats 5] [--number 20000]
"""

from __future__ import annotations

import argparse
import copy
import sys
import tempfile
import timeit
from pathlib import Path

import numpy as np
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from drivers.binding import build_binding  # noqa: E402
from rig_models.rig_file import load_rig  # noqa: E402
from rig_models.virtual_rig import TELEMETRY_QUANTITIES  # noqa: E402

COMMANDS = {"reaction_wheel": ("torque_cmd", "enable"),
            "thruster_valves": ("valve_pos", "valve_neg"),
            "piezo_amplifier": ("voltage_ch1", "voltage_ch2"),
            "disturbance_rotor": ("speed_cmd", "enable")}


def _without_checksums(data: dict) -> dict:
    data = copy.deepcopy(data)
    for cfg in data["devices"].values():
        if isinstance(cfg, dict):
            cfg.pop("checksums", None)
    return data


def bench_frames(repeats: int, number: int) -> list[tuple[str, float, float]]:
    rig = load_rig("sgsrt-dbc2")
    plain = build_binding(_without_checksums(rig.data))
    protected = rig.binding
    calls: list[tuple[str, object, object]] = []
    for device, names in COMMANDS.items():
        (a,), (b,) = protected.commands[device], plain.commands[device]
        if a.checksum is None:
            continue
        args = (0.01,) * len(names) + (7,)
        ea, eb = a.encoder(names), b.encoder(names)
        calls.append((f"command encode {a.codec.name} ({a.checksum.scheme})",
                      lambda e=ea, x=args: e(*x), lambda e=eb, x=args: e(*x)))
    for device, maps in protected.telemetry.items():
        for a, b in zip(maps, plain.telemetry[device], strict=True):
            if a.checksum is None:
                continue
            names = TELEMETRY_QUANTITIES[device]
            values = (1.0,) * len(names)
            ea, eb = a.encoder(names), b.encoder(names)
            data = ea(*values)
            calls.append((f"telemetry encode {a.codec.name} ({a.checksum.scheme})",
                          lambda e=ea, x=values: e(*x), lambda e=eb, x=values: e(*x)))
            calls.append((f"telemetry decode {a.codec.name} ({a.checksum.scheme})",
                          lambda m=a, d=data: m.decode(d), lambda m=b, d=data: m.decode(d)))
    out = []
    for name, fa, fb in calls:
        ta, tb = [], []
        for _ in range(repeats):  # interleaved: with, without, with, ...
            ta.append(timeit.timeit(fa, number=number) / number)
            tb.append(timeit.timeit(fb, number=number) / number)
        out.append((name, 1e9 * float(np.median(ta)), 1e9 * float(np.median(tb))))
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--number", type=int, default=20000)
    ap.add_argument("--loop-repeats", type=int, default=5)
    args = ap.parse_args()
    print("| frame | with checksum (ns) | without (ns) | added (ns) |")
    print("|---|---|---|---|")
    for name, a, b in bench_frames(args.repeats, args.number):
        print(f"| {name} | {a:.0f} | {b:.0f} | {a - b:+.0f} |")
    from benchmarks.bench_loop import bench_rigs

    with tempfile.TemporaryDirectory() as tmp:
        plain = Path(tmp) / "sgsrt-dbc2-no-checksums.yaml"
        data = _without_checksums(load_rig("sgsrt-dbc2").data)
        plain.write_text(yaml.safe_dump({"extends": "sgsrt-dbc2",
                                         "name": "sgsrt-dbc2-no-checksums",
                                         "devices": data["devices"]}))
        r = bench_rigs(args.loop_repeats, Path(tmp) / "logs", (str(plain), "sgsrt-dbc2"))
    a, b = r["sgsrt-dbc2"], r[str(plain)]
    print(f"\nslew-rw lockstep loop CPU a tick (interleaved, median of {args.loop_repeats}): "
          f"with checksums {a['cpu_us_per_tick']:.1f} us, without {b['cpu_us_per_tick']:.1f} "
          f"us; ratio {a['cpu_over_sgsrt']:.3f} (max {a['cpu_over_sgsrt_max']:.3f})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
