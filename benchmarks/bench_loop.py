"""Loop and plant benchmarks, measured in one run; prints a table.

0. The floor tick against the harness's tick, interleaved run by run: the floor
   does only what a lockstep tick must (SYNC and heartbeat out, the rig's one plant step and
   its output, every due telemetry frame encoded, sent, received and decoded, the run's
   command frames likewise, one recorded row), with the same codecs, the same bus
   (``harness.bus.CopyingVirtualBus``) and the same recorder; the harness's tick is a whole
   lockstep `slew-rw` run's loop time per tick. Their ratio is what the harness costs beyond
   the floor (`--floor` runs only this).
0b. What is left beyond the floor (`--parts` runs only this): the harness's loop CPU a tick
   with the fault monitor off, with the CAN log's writes skipped (frames queued, written
   after the loop), with neither, and as it is, interleaved with the floor run by run; each
   as a ratio to the floor of its round. Measures only: a run with a part off is not a run.
1. Lockstep real-time factor of `slew-rw` through the full CAN path at 500 Hz (codecs,
   python-can virtual bus, drivers, virtual rig, BLF log, Rerun recording).
1b. The same lockstep run on python-can's stock VirtualBus, interleaved with ours.
1c. The monitor's warnings: slew-rw with `monitor.warnings` on and off, interleaved, and
   the warning checks alone per tick against the whole tick (`--warnings` runs only this).
2. (Real time moved to benchmarks/bench_realtime.py and bench_rig_options.py.)
3. The plant step (exact ZOH, one matrix-vector product) against scipy.signal.lsim and
   solve_ivp on the same model, the same piecewise-constant input and comparable accuracy.

    .venv/bin/python benchmarks/bench_loop.py [--repeats 3] [--json] [--warnings] [--floor]
        [--parts] [--rig sgsrt]
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import can
import numpy as np
import scipy.signal as sig
from scipy.integrate import solve_ivp

from harness.core.runs import load_run
from harness.core.session import (
    LOCKSTEP_BLOCK_ROWS,
    LOCKSTEP_FLUSH_EVERY_BLOCKS,
    execute_run,
)
from rig_models.rig_file import load_rig


def _stock_virtual_bus(spec, receive_own_messages: bool = False):  # noqa: ANN001, ANN202
    """python-can's own VirtualBus (deepcopy per frame, queue.Queue), for comparison."""
    from can.interfaces.virtual import VirtualBus

    return VirtualBus(channel=spec.channel, receive_own_messages=receive_own_messages)


def bench_lockstep(repeats: int, out: Path) -> dict[str, float]:
    """Our bus and python-can's stock VirtualBus, interleaved run by run so that the ratio is
    measured under the same machine load."""
    import harness.core.session as session

    ours: list[float] = []
    stock: list[float] = []
    own_open_bus = session.open_bus
    for _ in range(repeats):
        for factors, opener in ((ours, own_open_bus), (stock, _stock_virtual_bus)):
            session.open_bus = opener
            try:
                res = execute_run(load_run("slew-rw"), out_dir=out, show_progress=False)
            finally:
                session.open_bus = own_open_bus
            factors.append(res.summary["real_time_factor"])
    return {"median": float(np.median(ours)), "min": float(np.min(ours)),
            "max": float(np.max(ours)), "stock_median": float(np.median(stock)),
            "ours_over_stock": float(np.median(np.array(ours) / np.array(stock)))}


def floor_tick_us(run_name: str, n_ticks: int, out: Path) -> tuple[float, float]:
    """Microseconds per floor tick (see the module docstring) over ``n_ticks`` ticks of the
    run's rate, frames and actuators: (wall, CPU of the process, Rerun's threads incl.)."""
    from drivers.dbc import load_protocol
    from harness.bus import open_bus, parse_bus
    from harness.core.loop import CHANNELS
    from harness.record.recording import Recorder

    run = load_run(run_name)
    protocol = load_protocol()
    spec = parse_bus("virtual:floor-bench")
    harness_bus, rig_bus = open_bus(spec), open_bus(spec)
    plant = run.rig.plant.discretise(run.dt_s)
    ad, bd, c, d = plant.ad, plant.bd, plant.c, plant.d
    x = np.zeros(ad.shape[0])
    u = np.zeros(bd.shape[1])
    div = run.rig.data["bus"]["sync_divider"]
    tlm = {"hub_sensor": "HUB_TLM", "accelerometer": "ACCEL_TLM",
           "reaction_wheel": "WHEEL_TLM", "thruster_valves": "VALVE_TLM",
           "piezo_amplifier": "PIEZO_TLM", "disturbance_rotor": "ROTOR_TLM"}
    cmd = {"reaction_wheel": "WHEEL_CMD", "thruster_valves": "VALVE_CMD",
           "piezo_amplifier": "PIEZO_CMD", "disturbance_rotor": "ROTOR_CMD"}
    due = [(protocol[tlm[name]], div[name]) for name in tlm]
    commands = [protocol[cmd[name]] for name in run.actuators if name in cmd]
    sync, heartbeat = protocol["SYNC"], protocol["HEARTBEAT"]
    by_id = protocol.by_id
    heartbeat_every = max(1, round(run.data["rate_hz"] / run.data["heartbeat_hz"]))
    # recorded as the harness records in lockstep (the same blocks, the same waits)
    recorder = Recorder(out / "floor.rrd", CHANNELS, n_ticks, "floor",
                        block_rows=LOCKSTEP_BLOCK_ROWS,
                        flush_every_blocks=LOCKSTEP_FLUSH_EVERY_BLOCKS)
    Message = can.Message
    # the rig side hands its fresh frames over as the virtual rig does (send_owned)
    send_h, send_r = harness_bus.send, rig_bus.send_owned
    recv_h, recv_r = harness_bus.recv, rig_bus.recv
    values: dict[int, dict[str, float]] = {}
    perf, cpu = time.perf_counter, time.process_time
    t0, c0 = perf(), cpu()
    for tick in range(n_ticks):
        if tick % heartbeat_every == 0:
            send_h(Message(arbitration_id=heartbeat.frame_id, is_extended_id=False,
                           data=heartbeat.encode({"counter": tick & 0xFF, "armed": 1})))
        send_h(Message(arbitration_id=sync.frame_id, is_extended_id=False,
                       data=sync.encode({"tick": tick})))
        while (msg := recv_r(0.0)) is not None:  # the rig: commands, then SYNC
            values[msg.arbitration_id] = by_id[msg.arbitration_id].decode(msg.data)
        x = ad @ x + bd @ u
        y = c @ x + d @ u
        for codec, every in due:
            if tick % every == 0:
                send_r(Message(arbitration_id=codec.frame_id, is_extended_id=False,
                               data=codec.encode({"angle": y[0], "rate": y[1],
                                                  "accel": y[2]})))
        while (msg := recv_h(0.0)) is not None:  # the harness: telemetry
            values[msg.arbitration_id] = by_id[msg.arbitration_id].decode(msg.data)
        for codec in commands:
            send_h(Message(arbitration_id=codec.frame_id, is_extended_id=False,
                           data=codec.encode({"torque_cmd": 0.0, "enable": 1,
                                              "counter": tick & 0xFF})))
        row = recorder.row(tick * run.dt_s)
        row[:] = y[0]
        recorder.commit()
        recorder.drain()
    elapsed, elapsed_cpu = perf() - t0, cpu() - c0
    recorder.close()
    harness_bus.shutdown()
    rig_bus.shutdown()
    return 1e6 * elapsed / n_ticks, 1e6 * elapsed_cpu / n_ticks


def bench_floor(repeats: int, out: Path, run_name: str = "slew-rw") -> dict[str, float]:
    """The floor tick and the harness's tick (whole lockstep runs of ``run_name``),
    interleaved run by run; the ratio is taken pair by pair (same machine load). Both in
    wall time and in the process's CPU time over the loop only (Rerun's threads included;
    on a shared machine CPU time is the steadier of the two)."""
    import harness.core.session as session

    own_loop = session.run_loop
    loop_cpu: list[float] = []

    def timed_loop(*args, **kwargs):  # noqa: ANN002, ANN003, ANN202
        c0 = time.process_time()
        try:
            return own_loop(*args, **kwargs)
        finally:
            loop_cpu.append(time.process_time() - c0)

    floor: list[float] = []
    floor_cpu: list[float] = []
    harness: list[float] = []
    harness_cpu: list[float] = []
    rtf: list[float] = []
    session.run_loop = timed_loop
    try:
        for _ in range(repeats):
            res = execute_run(load_run(run_name), out_dir=out, show_progress=False)
            ticks = res.summary["ticks"]
            harness.append(1e6 * res.stats.wall_s / ticks)
            harness_cpu.append(1e6 * loop_cpu[-1] / ticks)
            rtf.append(res.summary["real_time_factor"])
            del res
            wall_us, cpu_us = floor_tick_us(run_name, ticks, out)
            floor.append(wall_us)
            floor_cpu.append(cpu_us)
    finally:
        session.run_loop = own_loop
    ratio = np.array(harness) / np.array(floor)
    ratio_cpu = np.array(harness_cpu) / np.array(floor_cpu)
    return {"floor_us": float(np.median(floor)), "harness_us": float(np.median(harness)),
            "ratio": float(np.median(ratio)), "ratio_min": float(np.min(ratio)),
            "ratio_max": float(np.max(ratio)),
            "floor_cpu_us": float(np.median(floor_cpu)),
            "harness_cpu_us": float(np.median(harness_cpu)),
            "ratio_cpu": float(np.median(ratio_cpu)), "ratio_cpu_min": float(np.min(ratio_cpu)),
            "ratio_cpu_max": float(np.max(ratio_cpu)),
            "real_time_factor": float(np.median(rtf)),
            "real_time_factor_max": float(np.max(rtf))}


PARTS = ("as is", "no monitor", "no CAN log writes", "neither")


def bench_parts(repeats: int, out: Path, run_name: str = "slew-rw") -> dict[str, Any]:
    """The harness's loop CPU a tick with its fault monitor and its CAN log's writes
    switched off (see the module docstring, 0b), each round interleaved with the floor."""
    import harness.core.session as session

    own_loop = session.run_loop
    part = {"now": PARTS[0]}
    loop_cpu: list[float] = []

    def timed_loop(interface, *args, **kwargs):  # noqa: ANN001, ANN002, ANN003, ANN202
        log = interface.can_log
        if part["now"] in ("no monitor", "neither"):
            kwargs["monitor"] = None
        if part["now"] in ("no CAN log writes", "neither") and log is not None:
            log.drain = lambda: 0  # queued only; close() writes them after the loop
        c0 = time.process_time()
        try:
            return own_loop(interface, *args, **kwargs)
        finally:
            loop_cpu.append(time.process_time() - c0)
            if log is not None:
                log.__dict__.pop("drain", None)

    cpu: dict[str, list[float]] = {p: [] for p in PARTS}
    floor_cpu: list[float] = []
    session.run_loop = timed_loop
    try:
        for _ in range(repeats):
            for name in PARTS:
                part["now"] = name
                res = execute_run(load_run(run_name), out_dir=out, show_progress=False)
                ticks = res.summary["ticks"]
                cpu[name].append(1e6 * loop_cpu[-1] / ticks)
                del res
            floor_cpu.append(floor_tick_us(run_name, ticks, out)[1])
    finally:
        session.run_loop = own_loop
    f = np.array(floor_cpu)
    return {"floor_cpu_us": float(np.median(f)),
            **{name: {"cpu_us": float(np.median(v)),
                      "over_floor": float(np.median(np.array(v) / f)),
                      "over_floor_min": float(np.min(np.array(v) / f)),
                      "over_floor_max": float(np.max(np.array(v) / f))}
               for name, v in cpu.items()}}


def _parts_rows(r: dict[str, Any], repeats: int) -> str:
    return "\n".join(
        f"| slew-rw lockstep loop CPU, {name} (interleaved with the floor, median of "
        f"{repeats}) | {r[name]['cpu_us']:.1f} us a tick, {r[name]['over_floor']:.2f}x the "
        f"floor's {r['floor_cpu_us']:.1f} (min {r[name]['over_floor_min']:.2f}, max "
        f"{r[name]['over_floor_max']:.2f}) |" for name in PARTS)


RIGS = ("sgsrt", "sgsrt-canopen", "sgsrt-dbc2")


def bench_rigs(repeats: int, out: Path, rigs: tuple[str, ...] = RIGS) -> dict[str, Any]:
    """slew-rw in lockstep over each rig's device binding (the sgsrt DBC, CANopen PDOs with
    the SYNC counter and the nodes' emulation, the custom DBC's Motorola and multiplexed
    frames), interleaved run by run; the loop's CPU per tick and the real-time factor, and
    each rig's ratio to sgsrt taken pair by pair (same machine load)."""
    import harness.core.session as session

    own_loop = session.run_loop
    loop_cpu: list[float] = []

    def timed_loop(*args, **kwargs):  # noqa: ANN002, ANN003, ANN202
        c0 = time.process_time()
        try:
            return own_loop(*args, **kwargs)
        finally:
            loop_cpu.append(time.process_time() - c0)

    cpu_us: dict[str, list[float]] = {r: [] for r in rigs}
    rtf: dict[str, list[float]] = {r: [] for r in rigs}
    session.run_loop = timed_loop
    try:
        for _ in range(repeats):
            for rig in rigs:
                res = execute_run(load_run("slew-rw", {"rig": rig}), out_dir=out,
                                  show_progress=False)
                cpu_us[rig].append(1e6 * loop_cpu[-1] / res.summary["ticks"])
                rtf[rig].append(res.summary["real_time_factor"])
                del res
    finally:
        session.run_loop = own_loop
    base = np.array(cpu_us[rigs[0]])
    return {r: {"cpu_us_per_tick": float(np.median(cpu_us[r])),
                "real_time_factor": float(np.median(rtf[r])),
                "cpu_over_sgsrt": float(np.median(np.array(cpu_us[r]) / base)),
                "cpu_over_sgsrt_max": float(np.max(np.array(cpu_us[r]) / base))}
            for r in rigs}


def _rigs_rows(r: dict[str, Any], repeats: int) -> str:
    return "\n".join(
        f"| slew-rw lockstep on {rig} (interleaved, median of {repeats}) | "
        f"{v['real_time_factor']:.1f}x real time, loop CPU {v['cpu_us_per_tick']:.1f} us a "
        f"tick, {v['cpu_over_sgsrt']:.2f}x sgsrt's (max {v['cpu_over_sgsrt_max']:.2f}) |"
        for rig, v in r.items())


def bench_warnings(repeats: int, out: Path, n_calls: int = 200_000) -> dict[str, float]:
    """slew-rw (20 s) with the monitor's warnings on and off, interleaved run by run; and
    the warning checks alone (``FaultMonitor._warnings`` on a run's interface, state within
    every threshold) in microseconds per tick against the run's wall time per tick."""
    from drivers.dbc import load_protocol
    from harness.bus.rig_interface import RigInterface
    from harness.core.session import make_monitor
    from harness.state import RigCommand, RigState

    on: list[float] = []
    off: list[float] = []
    tick_us: list[float] = []
    for _ in range(repeats):
        for factors, flag in ((on, True), (off, False)):
            run = load_run("slew-rw", {"duration_s": 20.0, "monitor": {"warnings": flag}})
            res = execute_run(run, out_dir=out, show_progress=False)
            factors.append(res.summary["real_time_factor"])
            if flag:
                tick_us.append(1e6 * res.summary["wall_time_s"] / res.summary["ticks"])
    run = load_run("slew-rw")
    bus = type("NoBus", (), {"send": lambda self, m: None})()
    iface = RigInterface(bus, load_protocol(), run.rig, None, run.actuators)
    mon = make_monitor(run, iface, realtime=False)
    state, sent = RigState(), RigCommand(wheel_torque_n_m=0.01)
    state.wheel_speed_rad_s, state.hub_rate_rad_s = 100.0, 0.01
    for d in iface.drivers.values():
        d.last_tick = 0
    t0 = time.perf_counter()
    for _ in range(n_calls):
        mon._warnings(0, state, sent)
    per_us = (time.perf_counter() - t0) * 1e6 / n_calls
    assert not any(mon.warning_counts.values())
    return {"on_median": float(np.median(on)), "off_median": float(np.median(off)),
            "on_over_off": float(np.median(np.array(on) / np.array(off))),
            "warnings_us_per_tick": per_us, "tick_us": float(np.median(tick_us))}


def bench_plant(n_steps: int = 20000) -> dict[str, float]:
    plant = load_rig("sgsrt").plant
    dt = 0.002
    d = plant.discretise(dt)
    t = np.arange(n_steps) * dt
    u = np.zeros((n_steps, plant.b.shape[1]))
    u[:, 0] = 0.05 * np.sign(np.sin(2 * np.pi * 0.2 * t))
    x = np.zeros(plant.n_states)
    t0 = time.perf_counter()
    ad, bd = d.ad, d.bd
    xs = np.empty((n_steps, plant.n_states))
    for k in range(n_steps):
        xs[k] = x
        x = ad @ x + bd @ u[k]
    zoh_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    _, _, x_lsim = sig.lsim((plant.a, plant.b, np.eye(plant.n_states),
                             np.zeros((plant.n_states, plant.b.shape[1]))), u, t, interp=False)
    lsim_s = time.perf_counter() - t0
    # solve_ivp, one call per step (the loop's situation: the input changes every tick)
    n_ivp = min(n_steps, 2000)
    x = np.zeros(plant.n_states)
    t0 = time.perf_counter()
    for k in range(n_ivp):
        uk = u[k]
        x = solve_ivp(lambda _t, y, uk=uk: plant.a @ y + plant.b @ uk, (0, dt), x,
                      method="RK45", rtol=1e-10, atol=1e-13).y[:, -1]
    ivp_s = (time.perf_counter() - t0) * n_steps / n_ivp
    err_ivp = float(np.max(np.abs(x - xs[n_ivp]))) if n_ivp < n_steps else float("nan")
    err_lsim = float(np.max(np.abs(x_lsim - xs)))
    per = 1e6 / n_steps
    return {"zoh_us_per_step": zoh_s * per, "lsim_us_per_step": lsim_s * per,
            "solve_ivp_us_per_step": ivp_s * per, "lsim_over_zoh": lsim_s / zoh_s,
            "solve_ivp_over_zoh": ivp_s / zoh_s, "max_state_diff_lsim": err_lsim,
            "max_state_diff_solve_ivp": err_ivp}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--warnings", action="store_true", help="only 1c, the monitor's warnings")
    ap.add_argument("--floor", action="store_true", help="only 0, the floor tick")
    ap.add_argument("--parts", action="store_true",
                    help="only 0b: the loop with the monitor / the CAN log's writes off")
    ap.add_argument("--rigs", action="store_true",
                    help="only the device bindings: slew-rw on sgsrt, sgsrt-canopen, sgsrt-dbc2")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp)
        if args.parts:
            print("benchmark: the harness's parts beyond the floor ...", file=sys.stderr)
            parts = bench_parts(args.repeats, out)
            print(json.dumps(parts, indent=2) if args.json else _parts_rows(parts, args.repeats))
            return 0
        # --rigs and --floor run only their own part (the rest of the table is not measured)
        if not args.floor and not args.warnings:
            print("benchmark: slew-rw over each rig's device binding ...", file=sys.stderr)
            rigs = bench_rigs(args.repeats, out)
            if args.rigs:
                print(json.dumps(rigs, indent=2) if args.json
                      else _rigs_rows(rigs, args.repeats))
                return 0
        if not args.warnings:
            print("benchmark: floor tick and the harness's tick ...", file=sys.stderr)
            floor = bench_floor(args.repeats, out)
            if args.floor:
                print(json.dumps(floor, indent=2) if args.json
                      else _floor_row(floor, args.repeats))
                return 0
        print("benchmark: monitor warnings ...", file=sys.stderr)
        warn = bench_warnings(args.repeats, out)
        if args.warnings:
            print(json.dumps(warn, indent=2) if args.json else _warnings_row(warn, args.repeats))
            return 0
        print("benchmark: lockstep ...", file=sys.stderr)
        lock = bench_lockstep(args.repeats, out)
    print("benchmark: plant step ...", file=sys.stderr)
    plant = bench_plant()
    result = {"machine": f"{platform.machine()} {platform.processor() or ''}".strip(),
              "python": platform.python_version(), "date": time.strftime("%Y-%m-%d"),
              "lockstep_real_time_factor": lock, "plant": plant, "warnings": warn,
              "floor": floor, "rigs": rigs}
    if args.json:
        print(json.dumps(result, indent=2))
        return 0
    print(f"| measure ({result['date']}, {result['machine']}, Python {result['python']}) | value |")
    print("|---|---|")
    print(_floor_row(floor, args.repeats))
    print(_rigs_rows(rigs, args.repeats))
    print(f"| lockstep real-time factor, slew-rw at 500 Hz, full CAN path (median of "
          f"{args.repeats}) | {lock['median']:.1f}x (min {lock['min']:.1f}, max "
          f"{lock['max']:.1f}) |")
    print(f"| same, on python-can's stock VirtualBus (interleaved runs) | "
          f"{lock['stock_median']:.1f}x; ours / stock {lock['ours_over_stock']:.2f} |")
    print(_warnings_row(warn, args.repeats))
    print(f"| plant step, exact ZOH (matrix-vector) | {plant['zoh_us_per_step']:.2f} us |")
    print(f"| scipy.signal.lsim, same input | {plant['lsim_us_per_step']:.2f} us/step "
          f"({plant['lsim_over_zoh']:.2f}x ZOH; max state diff "
          f"{plant['max_state_diff_lsim']:.1e}) |")
    print(f"| solve_ivp RK45 per tick, rtol 1e-10 | {plant['solve_ivp_us_per_step']:.0f} us/step "
          f"({plant['solve_ivp_over_zoh']:.0f}x ZOH; max state diff "
          f"{plant['max_state_diff_solve_ivp']:.1e}) |")
    return 0


def _floor_row(f: dict[str, float], repeats: int) -> str:
    return (f"| slew-rw lockstep tick / floor tick (sgsrt, interleaved, median of {repeats}) "
            f"| wall {f['harness_us']:.1f} / {f['floor_us']:.1f} us, ratio {f['ratio']:.2f} "
            f"(min {f['ratio_min']:.2f}, max {f['ratio_max']:.2f}); CPU "
            f"{f['harness_cpu_us']:.1f} / {f['floor_cpu_us']:.1f} us, ratio "
            f"{f['ratio_cpu']:.2f} (min {f['ratio_cpu_min']:.2f}, max "
            f"{f['ratio_cpu_max']:.2f}); real-time factor {f['real_time_factor']:.1f}x "
            f"(max {f['real_time_factor_max']:.1f}x) |")


def _warnings_row(w: dict[str, float], repeats: int) -> str:
    return (f"| monitor warnings on / off, slew-rw 20 s lockstep (interleaved, median of "
            f"{repeats}) | real-time factor {w['on_median']:.1f}x / {w['off_median']:.1f}x, "
            f"ratio {w['on_over_off']:.2f}; the checks {w['warnings_us_per_tick']:.2f} us of "
            f"a {w['tick_us']:.0f} us tick |")


if __name__ == "__main__":
    sys.exit(main())
