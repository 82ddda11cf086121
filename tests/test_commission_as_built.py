"""`harness commission` against a rig as built (rig_models/rigs/sgsrt-as-built.yaml: bearing
friction, a slower torque loop, sensor biases, a heavier hub, a lightly damped beam whose
modes are a few % off, valves that are not a matched pair), wired correctly: it PASSes, and
what it measured is the emulated truth within 3 sigma. A rig beyond its file's tolerances
is no binding error: DIFFERS (exit 7) naming each key; the rig file --write-rig writes then
PASSes. The binding errors FAIL against these devices too (tests/test_commission.py)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
import yaml

from harness.commissioning.workflow import Options, commission
from rig_models.devices import G0_M_S2
from rig_models.rig_file import RIGS_DIR, load_rig
from tests.in_process import harness_in_process

DT = 0.002


def _row(result, key: str):
    (row,) = [c for c in result.checks if c.key == key]
    return row


def _within(row, truth: float, extra_sigma: float = 0.0) -> None:
    sigma = math.hypot(row.sigma, extra_sigma)
    assert abs(row.value - truth) <= 3 * sigma, (row.key, row.value, truth, sigma)


def _on_time(tv: dict, negative: bool) -> float:
    """A valve's effective on-time for the 0.2 s pulse: its delays as the emulated valve
    applies them, whole ticks (rig_models.devices.ThrusterValves)."""
    sfx = "_negative" if negative else ""
    opening = tv.get(f"open_delay{sfx}_s") or tv["open_delay_s"]
    closing = tv.get(f"close_delay{sfx}_s") or tv["close_delay_s"]
    return 0.2 + (round(closing / DT) - round(opening / DT)) * DT


@pytest.fixture(scope="module")
def as_built(tmp_path_factory):
    out = tmp_path_factory.mktemp("as-built")
    return commission(Options(rig="sgsrt", out=out, devices_rig="sgsrt-as-built"))


def test_a_rig_as_built_and_correctly_bound_passes(as_built):
    res = as_built
    assert res.verdict == "PASS" and res.exit_code == 0, [
        f"{c.name}: {c.check}: {c.value} {c.cause}" for c in res.checks
        if c.verdict not in ("PASS", "INFO", "NOT RUN")]
    folder = Path(res.folder)
    data = json.loads((folder / "commission.json").read_text())
    assert data["verdict"] == "PASS" and data["measured"]["hub.inertia_kg_m2"]["sigma"] > 0
    html = (folder / "report.html").read_text()
    assert "model, measured</h2>" in html and "hub.inertia_kg_m2" in html


def test_each_estimate_is_the_emulated_truth_within_3_sigma(as_built):
    res = as_built
    model = load_rig("sgsrt")
    truth = load_rig("sgsrt-as-built").as_built_rig().data
    rw, tv, hs, acc = (truth[k] for k in ("reaction_wheel", "thruster_valves", "hub_sensor",
                                           "accelerometer"))
    _within(_row(res, "hub.inertia_kg_m2"), truth["hub"]["inertia_kg_m2"])
    _within(_row(res, "reaction_wheel.friction_coulomb_n_m"), rw["friction_coulomb_n_m"])
    _within(_row(res, "reaction_wheel.friction_viscous_n_m_s"), rw["friction_viscous_n_m_s"])
    _within(_row(res, "reaction_wheel.torque_lag_s"), rw["torque_lag_s"])
    # a couple is measured as the hub's impulse over the on-time the file's delays give
    # (the read-back's 10 ms period does not resolve the delays): its truth is that impulse
    file_on = _on_time(model.data["thruster_valves"], False)
    for key, negative in (("couple_n_m", False), ("couple_negative_n_m", True)):
        row = _row(res, f"thruster_valves.{key}")
        couple = tv[key] if tv.get(key) is not None else tv["couple_n_m"]
        _within(row, couple * _on_time(tv, negative) / file_on)
    # the rate's bias at rest walks (rate_random_walk_rad_s_sqrt_s): by the rest run's
    # samples, about one second of it
    _within(_row(res, "hub_sensor.rate_bias_rad_s"), hs["rate_bias_rad_s"],
            hs["rate_random_walk_rad_s_sqrt_s"] * 1.0)
    # at rest the accelerometer reads its bias and the gravity its tilted axis picks up at
    # the hub's angle (0 at rest), times its scale error
    at_rest = acc["bias_m_s2"] + (1 + acc["scale_error"]) * G0_M_S2 * math.sin(
        acc["tilt_rad"]) * math.cos(0.0 - acc["tilt_azimuth_rad"])
    _within(_row(res, "accelerometer.bias_m_s2"), at_rest)
    beam = truth["beam"]
    for k in (0, 1):  # the modes the ring-down shows
        _within(_row(res, f"beam.frequency_factors[{k}]"), beam["frequency_factors"][k])
        _within(_row(res, f"beam.damping_ratios[{k}]"), beam["damping_ratio"])


def _differing_truth(tmp_path: Path, base: str = "sgsrt-as-built") -> Path:
    """The rig as built, 15 % heavier and its beam a quarter as damped: beyond sgsrt's
    tolerances (inertia 5 %, damping 80 %)."""
    built = load_rig(base).as_built_rig().data
    path = tmp_path / f"{base}-heavy-soft.yaml"
    path.write_text(yaml.safe_dump({
        "extends": base, "name": f"{base}-heavy-soft",
        "as_built": {"hub": {"inertia_kg_m2": 1.15 * built["hub"]["inertia_kg_m2"]},
                     "beam": {"damping_ratio": 0.25 * built["beam"]["damping_ratio"]}}}))
    return path


def test_a_rig_beyond_its_files_tolerance_differs_and_its_measured_file_passes(tmp_path):
    truth = _differing_truth(tmp_path)
    written = tmp_path / "sgsrt.measured.yaml"
    r = harness_in_process("commission", "--rig", "sgsrt", "--devices-rig", str(truth),
                           "--out", str(tmp_path / "a"), "--write-rig", str(written), "--json")
    assert r.returncode == 7, r.stdout + r.stderr
    data = json.loads(r.stdout)
    assert data["verdict"] == "DIFFERS" and not data["failed"]
    differs = {c["key"] for c in data["checks"] if c["verdict"] == "DIFFERS"}
    assert {"hub.inertia_kg_m2", "beam.damping_ratios[0]"} <= differs
    assert not differs & {"beam.frequency_factors[0]", "reaction_wheel.torque_lag_s"}
    (inertia,) = [c for c in data["checks"] if c["key"] == "hub.inertia_kg_m2"]
    assert "15 in the file" in inertia["cause"] and "--write-rig" in inertia["cause"]
    assert inertia["value"] == pytest.approx(1.15 * 15.6, rel=0.02)
    # the measured file: extends the file under test, the measured keys with their sigma
    text = written.read_text()
    assert text.startswith("# Written by harness commission") and "extends: sgsrt\n" in text
    assert "inertia_kg_m2:" in text and "damping_ratios:" in text and "+-" in text
    assert load_rig(written).data["hub"]["inertia_kg_m2"] == pytest.approx(17.94, rel=0.02)
    r2 = harness_in_process("commission", "--rig", str(written), "--devices-rig", str(truth),
                            "--out", str(tmp_path / "b"))
    assert r2.returncode == 0, r2.stdout + r2.stderr
    assert "PASS" in r2.stdout.splitlines()[-1]


def test_a_binding_error_on_a_differing_rig_fails_and_nothing_is_judged_or_written(tmp_path):
    """Two answers never mixed: the wheel's speed sign flipped on a rig that also differs
    from its file: FAIL (the binding), the model's differences not judged, no rig file."""
    truth = _differing_truth(tmp_path, "sgsrt-dbc2-as-built")
    wheel = load_rig("sgsrt-dbc2").data["devices"]["reaction_wheel"]
    wheel["telemetry"]["speed"]["scale"] = -wheel["telemetry"]["speed"]["scale"]
    rig = tmp_path / "sign.yaml"
    rig.write_text(yaml.safe_dump({"extends": "sgsrt-dbc2", "name": "sign",
                                   "devices": {"reaction_wheel": wheel}}))
    written = tmp_path / "never.yaml"
    res = commission(Options(rig=str(rig), out=tmp_path / "logs", devices_rig=str(truth),
                             write_rig=written))
    assert res.verdict == "FAIL" and res.exit_code == 1
    assert any(c.name == "reaction_wheel.speed" and c.verdict == "FAIL" for c in res.checks)
    assert not res.differs() and not written.exists()
    assert _row(res, "beam.damping_ratios[0]").verdict == "NOT JUDGED"
    assert any("not written" in n for n in res.notes)


@pytest.mark.parametrize("target, why", [
    ("measured.txt", ".yaml or .yml"),
    ("no-such-folder/measured.yaml", "does not exist"),
    ("hand-written.yaml", "not written by harness commission"),
    (str(RIGS_DIR / "sgsrt-measured.yaml"), "built-in rigs"),
    ("me as.yaml", "not a safe file name"),
])
def test_write_rig_refuses_a_bad_target_before_anything_moves(tmp_path, target, why):
    (tmp_path / "hand-written.yaml").write_text("name: mine\n")
    path = target if Path(target).is_absolute() else str(tmp_path / target)
    r = harness_in_process("commission", "--rig", "sgsrt", "--out", str(tmp_path / "logs"),
                           "--write-rig", path)
    assert r.returncode == 2 and why in r.stderr and "Traceback" not in r.stderr
    assert not (tmp_path / "logs").exists()
    assert (tmp_path / "hand-written.yaml").read_text() == "name: mine\n"


def test_write_rig_never_writes_over_the_rig_under_test(tmp_path):
    rig = tmp_path / "mine.yaml"
    rig.write_text(f"{'# Written by harness commission'}\nextends: sgsrt\nname: mine\n")
    r = harness_in_process("commission", "--rig", str(rig), "--out", str(tmp_path / "logs"),
                           "--write-rig", str(rig))
    assert r.returncode == 2 and "the rig file under test" in r.stderr
