"""Hu (2006)'s five thruster slews on the virtual SGSRT, through the harness over CAN.

The five built-in runs are shortened to 12 s: the first (saturated, continuous) firing lasts
from 1 s to about 9.4 s, then the PWPF pulses in both directions. The virtual rig is
subclassed to keep its true state at every step, so the energy estimate read from the
recording can be checked against the physics.
"""

from __future__ import annotations

import math
from pathlib import Path

import can
import numpy as np
import pytest

from drivers.dbc import load_protocol
from harness.controllers.oppf import OPPFWeights, design_oppf, stability_matrix
from harness.controllers.thruster_slew import (
    THRUSTER_SLEW_SCHEMA,
    build_thruster_slew,
    linear_closed_loop,
    rig_ppf_design_model,
    scaled_pd_gains,
)
from harness.core.runs import build_controller, load_run
from harness.record.reader import read_scalar_channel
from harness.state import RigState
from harness.studies.hu2006_rig import (
    RUNS,
    analyse_run,
    format_report,
    ordering,
    recorded_energy,
)
from rig_models.reference.hu2006_hub_beam import Hu2006HubBeam
from rig_models.rig_file import load_rig
from rig_models.schema import ConfigError, validate
from rig_models.virtual_rig import VirtualRig

RUN_NAMES = [name for name, _, _ in RUNS]
OPPF_RUNS = {"thruster-oppf", "thruster-csvs1-oppf", "thruster-csvs12-oppf"}
DURATION_S = 12.0


class TruthRig(VirtualRig):
    """The virtual rig, keeping its true state after every physics step (tests only)."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.states = [self.x.copy()]
        self.add_step_hook(lambda rig: rig.states.append(rig.x.copy()))


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    import harness.core.session as session

    out = Path(tmp_path_factory.mktemp("thruster_logs"))
    results = {}
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(session, "VirtualRig", TruthRig)
        for name in RUN_NAMES:
            run = load_run(name, {"duration_s": DURATION_S})
            results[name] = (run, session.execute_run(run, out_dir=out, show_progress=False))
    return results


@pytest.mark.slow
def test_five_runs_complete_over_can(runs):
    protocol = load_protocol()
    for name, (run, result) in runs.items():
        s = result.summary
        assert s["stopped_by"] == "completed", (name, s["error"], s["faults"])
        assert s["bus"] == "virtual:sgsrt" and s["ticks"] == run.n_ticks
        assert s["frames"]["missing"] == 0 and s["frames"]["malformed"] == 0
        ids = [m.arbitration_id for m in can.LogReader(str(result.run_dir / "can.blf"))]
        for frame in ("VALVE_CMD", "PIEZO_CMD", "VALVE_TLM", "PIEZO_TLM"):
            assert ids.count(protocol[frame].frame_id) >= run.n_ticks // 5, (name, frame)
        # the wheel is not used: only the safe-state frame at the end goes to it
        assert ids.count(protocol["WHEEL_CMD"].frame_id) == 1, name


def test_recording_holds_firings_on_time_and_piezo_voltage(runs):
    for name, (_, result) in runs.items():
        rrd = result.run_dir / "run.rrd"
        t, firings = read_scalar_channel(rrd, "/thrusters/firings")
        _, on_time = read_scalar_channel(rrd, "/thrusters/on_time_s")
        _, sensor = read_scalar_channel(rrd, "/piezo/sensor_ch1_v")
        _, cmd1 = read_scalar_channel(rrd, "/piezo/cmd_ch1_v")
        _, cmd2 = read_scalar_channel(rrd, "/piezo/cmd_ch2_v")
        assert len(t) == result.summary["ticks"]
        assert np.all(np.diff(firings) >= 0) and np.all(np.diff(on_time) >= -1e-9)
        assert firings[-1] >= 10, name  # the first long firing, then PWPF pulses
        assert 8.0 < on_time[-1] < DURATION_S, name
        # the valves' on-time counter agrees with the commands through the valve model
        cmd_on = analyse_run(result, runs[name][0])["on_time_from_commands_s"]
        assert abs(on_time[-1] - cmd_on) <= 5 * 0.002 + 1e-4, name  # VALVE_TLM every 5 ticks
        assert np.max(np.abs(sensor)) > 1.0, name  # the beam bends under the thrust
        assert np.all(cmd2 == 0.0), name  # channel 2 is not used by the five runs
        if name in OPPF_RUNS:
            assert 10.0 < np.max(np.abs(cmd1)) <= 200.0, name
        else:
            assert np.all(cmd1 == 0.0), name


def test_valve_commands_never_both_directions(runs):
    protocol = load_protocol()
    cmd_codec, tlm_codec = protocol["VALVE_CMD"], protocol["VALVE_TLM"]
    seen = set()
    for name, (_, result) in runs.items():
        _, cmd = read_scalar_channel(result.run_dir / "run.rrd", "/thrusters/valve_cmd")
        assert set(np.unique(cmd)) <= {-1.0, 0.0, 1.0}, name
        seen |= set(np.unique(cmd))
        n_cmd = 0
        for m in can.LogReader(str(result.run_dir / "can.blf")):
            if m.arbitration_id == cmd_codec.frame_id:
                v = cmd_codec.decode(bytes(m.data))
                assert not (v["valve_pos"] and v["valve_neg"]), name
                n_cmd += 1
            elif m.arbitration_id == tlm_codec.frame_id:
                v = tlm_codec.decode(bytes(m.data))
                assert not (v["valve_pos_open"] and v["valve_neg_open"]), name
        assert n_cmd >= result.summary["ticks"]
    assert seen == {-1.0, 0.0, 1.0}  # both directions were commanded: the check can fail


def test_oppf_gains_come_from_the_optimiser_with_eq7_met():
    run = load_run("thruster-oppf")
    ctrl = build_controller(run)
    design = ctrl.oppf[1]
    model = rig_ppf_design_model(run.rig, 1, 2)
    fresh = design_oppf(model, OPPFWeights(voltage_weight=1e-8))
    np.testing.assert_allclose(design.gains, fresh.gains, rtol=1e-9)
    np.testing.assert_allclose(design.comp_freqs_rad_s, fresh.comp_freqs_rad_s, rtol=1e-9)
    assert design.success and design.cost < design.open_loop_cost
    # eq (7): Omega - C^T G C > 0, with the required margin
    assert np.all(np.linalg.eigvalsh(stability_matrix(model, design.gains)) > 0)
    assert design.stability_condition_holds() and design.margin >= 0.05 - 1e-9
    assert not np.all(np.linalg.eigvalsh(stability_matrix(model, np.array([1.0, 1.0]))) > 0)
    # the bank the controller runs is the design's (paper eq 6 gains)
    bank = ctrl.banks[1]
    np.testing.assert_allclose([c.params.output_gain for c in bank.compensators],
                               model.output_gains(design.gains))
    report = ctrl.design_report()
    assert report["oppf"]["1"]["stability_condition_holds"] is True
    cl = report["closed_loop"]
    assert cl["max_real_eig_with_ppf"] < 0
    assert cl["damping_with_ppf"][0] > cl["damping_pd_only"][0] + 0.05
    assert cl["damping_with_ppf"][1] > cl["damping_pd_only"][1] + 0.02
    # the rig's patch pushes +a V where eq (2) has -B e_a: V = -e_a is the stable sign
    a = linear_closed_loop(run.rig, ctrl.gains.kp_n_m_per_rad, ctrl.gains.kd_n_m_s_per_rad,
                           ctrl.oppf)
    ns = run.rig.plant.a.shape[0]
    assert np.max(np.linalg.eigvals(a).real) < 0
    a[:ns, ns:] *= -1.0
    assert np.max(np.linalg.eigvals(a).real) > 0


def _ringing(result, channel: str = "/piezo/sensor_ch1_v") -> float:
    from harness.studies.hu2006_rig import firing_ringing

    rec = result.columns()
    return firing_ringing(rec.time_s[: rec.rows], rec.column("/thrusters/valve_cmd"),
                          rec.column(channel))


def test_ppf_damps_the_rig_beam(runs):
    """During the long first firing the beam rings about its deflection; the PPF bank on the
    root patch damps the ringing (measured on the patch sensor, read back over CAN)."""
    plain = _ringing(runs["thruster-pd-pwpf"][1])
    damped = _ringing(runs["thruster-oppf"][1])
    assert plain > 0.1  # mode 1 rings visibly without PPF (sensor noise is 1 mV)
    assert damped < 0.3 * plain
    # CSVS on the reference cannot shape the saturated first firing: same ringing
    assert _ringing(runs["thruster-csvs"][1]) == pytest.approx(plain, rel=0.05)


def test_energy_estimate_matches_the_rig_truth(runs):
    for name in ("thruster-pd-pwpf", "thruster-oppf"):
        run, result = runs[name]
        energy = recorded_energy(result, run.rig, run.dt_s)
        x = np.array(result.virtual_rig.states)[: len(energy)]
        nq = run.rig.plant.n_modes + 1
        lam = run.rig.plant.modes.omega_rad_s**2
        truth = np.sum(x[:, nq + 1:] ** 2, axis=1) + np.sum(lam * x[:, 1:nq] ** 2, axis=1)
        assert len(x) == len(energy)
        assert energy.max() == pytest.approx(truth.max(), rel=0.02), name
        assert np.max(np.abs(energy - truth)) < 0.05 * truth.max(), name


def paper_plant_scale() -> tuple[float, float]:
    """(inertia kg m^2, thruster torque N m) of the paper's plant, from our reference model."""
    plant = Hu2006HubBeam()
    return float(plant.inertia), float(plant.params.thruster_torque)


def test_run_files_give_the_paper_plant_of_the_reference_model():
    # the controller takes the paper plant's scale from the run file (it does not import the
    # paper's model); every built-in run's values are the reference model's
    for name in RUN_NAMES:
        pd = load_run(name).controller["pd"]
        if pd["gains"] == "paper_scaled":
            assert (pd["paper_inertia_kg_m2"], pd["paper_torque_n_m"]) == paper_plant_scale()
    with pytest.raises(ValueError, match="pd.paper_inertia_kg_m2"):
        _controller(pd={"gains": "paper_scaled"})


def test_scaled_pd_gains_keep_the_paper_loop_dimensionless():
    rig = load_rig("sgsrt")
    j_p, u_p = paper_plant_scale()
    j_r, u_r = rig.plant.inertia_kg_m2, rig.section("thruster_valves")["couple_n_m"]
    g = scaled_pd_gains(15.0, 50.0, j_r, u_r, j_p, u_p)
    paper_poles = np.sort(np.roots([j_p, 50.0, 15.0]).real)
    rig_poles = np.sort(np.roots([j_r, g.kd_n_m_s_per_rad, g.kp_n_m_per_rad]).real)
    np.testing.assert_allclose(rig_poles * g.time_scale, paper_poles, rtol=1e-9)
    assert g.kp_n_m_per_rad / u_r == pytest.approx(15.0 / u_p)  # same dead zone in angle
    assert g.time_scale == pytest.approx(math.sqrt((u_p / j_p) / (u_r / j_r)))
    with pytest.raises(ValueError, match="rig_couple"):
        scaled_pd_gains(15.0, 50.0, j_r, 0.0, j_p, u_p)


def _controller(**section):
    rig = load_rig("sgsrt")
    j_p, u_p = paper_plant_scale()
    section.setdefault("pd", {"paper_inertia_kg_m2": j_p, "paper_torque_n_m": u_p})
    c = validate({"type": "thruster_pd_pwpf", "angle_deg": 60.0, **section},
                 THRUSTER_SLEW_SCHEMA, "test")
    return build_thruster_slew(c, rig, 0.002)


def test_csvs_reference_is_the_staircase_of_the_rig_modes():
    ctrl = _controller(csvs={"modes": [1, 2], "orders": [2, 0]})
    seq = ctrl.csvs
    assert seq.n_components == 8  # mode 1: 4 components, x mode 2: 2 components
    assert ctrl.csvs_modes[0].freq_rad_s == pytest.approx(
        load_rig("sgsrt").plant.hub_free_modes()[0][0])
    assert ctrl.reference(0.5)[0] == 0.0
    cum = np.cumsum(seq.amplitudes)
    for tk, c in zip(seq.times, cum, strict=True):
        assert ctrl.reference(1.0 + tk + 1e-6)[0] == pytest.approx(math.radians(60.0) * c)
    assert ctrl.reference(100.0)[0] == pytest.approx(math.radians(60.0))
    assert _controller().reference(1.0)[0] == pytest.approx(math.radians(60.0))


def test_bad_sections_name_the_parameter():
    with pytest.raises(ValueError, match="csvs.orders"):
        _controller(csvs={"modes": [1, 2], "orders": [2]})
    with pytest.raises(ValueError, match="csvs.modes"):
        _controller(csvs={"modes": [7]})
    with pytest.raises(ValueError, match="piezo.channels"):
        _controller(piezo={"channels": [1, 1]})
    with pytest.raises(ValueError, match="pd.kp_n_m_per_rad"):
        _controller(pd={"gains": "given"})
    with pytest.raises(ConfigError, match="piezo.channels"):
        load_run("thruster-oppf", {"controller": {"piezo": {"channels": [3]}}})


def test_valve_command_held_for_the_minimum_pulse():
    ctrl = _controller(min_pulse_s=0.1)
    ctrl.reset()
    # 60 deg error: the PWPF fires at its next step (its trigger acts on the filter state)
    first = [ctrl.step(RigState(time_s=1.0)).valve_direction for _ in range(2)]
    # now on target: the PWPF alone would close within ~12 ms; the command holds 100 ms
    out = [ctrl.step(RigState(time_s=1.0, hub_angle_rad=math.radians(60.0))).valve_direction
           for _ in range(60)]
    assert first == [0, 1]
    assert out[:49] == [1] * 49 and out[-1] == 0
    assert ctrl.extended_pulses > 0


def test_study_table_and_ordering(runs):
    rows = []
    for name, key, label in RUNS:
        run, result = runs[name]
        row = analyse_run(result, run)
        row.update(key=key, label=label, paper={"peak_energy_rel": 1.0})
        rows.append(row)
    o = ordering(rows)
    assert sorted(o["ours_highest_to_lowest"]) == sorted(o["paper_highest_to_lowest"])
    fake = [{"key": k, "peak_energy": e} for k, e in zip(
        o["paper_highest_to_lowest"], [5.0, 4.0, 3.0, 2.0, 1.0], strict=True)]
    assert ordering(fake)["matches"] is True
    assert ordering(list(reversed([{**f, "peak_energy": -f["peak_energy"]}
                                   for f in fake])))["matches"] is False


@pytest.mark.slow
def test_study_command_json(paper_suites):
    """`harness study hu2006-rig --json` as paper001's suite runs it (its JSON and its runs'
    folder; the five runs at their full 120 s, shared for the session by conftest's
    paper_suites, so the study does not run twice)."""
    study = paper_suites.document("hu2006-rig")
    [out] = paper_suites.out.glob("*/study-hu2006-rig/logs")  # the study's --out
    assert [r["run"] for r in study["results"]] == RUN_NAMES
    assert all(r["stopped_by"] == "completed" for r in study["results"])
    assert study["designs"]["thruster-oppf"]["oppf"]["1"]["stability_condition_holds"]
    assert len(list(out.glob("*-thruster-*/run.rrd"))) == 5
    assert len(list(out.glob("*-thruster-*/design.json"))) == 5
    assert "PD + PWPF" in format_report(study)
    m = study["measures"]  # the paper suite's flat measures
    assert m["pd_pwpf_peak_energy_ratio"] == 1.0 and m["pd_pwpf_oppf_completed"] is True
    assert m["oppf_mode1_damping_gain"] > 1.0 and m["oppf_stability_margin"] > 0
