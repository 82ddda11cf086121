"""The rig as built: the rig file's model keys for a real rig's imperfections (friction,
sensor biases and latency, unequal valves, a table out of level, a beam off its model) and
the ``as_built:`` overlay the virtual rig emulates while the harness keeps the model
(docs/as_built.md)."""

from __future__ import annotations

import math
import threading
import time
from pathlib import Path
from typing import Any

import can
import numpy as np
import pytest
import yaml

from drivers.dbc import load_protocol
from harness.bus import CopyingVirtualBus
from harness.core.runs import load_run
from harness.core.session import execute_run
from harness.record.reader import RecordedColumns
from harness.testing.work import private_channel
from rig_models.devices import G0_M_S2, Accelerometer, NoiseSource, ReactionWheel, ThrusterValves
from rig_models.rig_file import RIGS_DIR, RigConfig, load_rig, rig_from_dict
from rig_models.schema import ConfigError
from rig_models.virtual_rig import VirtualRig

P = load_protocol()
DT = 0.002
SGSRT = load_rig("sgsrt")
ZERO_KEYS: dict[str, dict[str, Any]] = {
    "hub": {"gravity_torque_n_m": 0.0, "gravity_azimuth_rad": 0.0},
    "beam": {"frequency_factors": [], "damping_ratios": []},
    "reaction_wheel": {"friction_coulomb_n_m": 0.0, "friction_viscous_n_m_s": 0.0,
                       "friction_breakaway_n_m": None},
    "hub_sensor": {"angle_bias_rad": 0.0, "rate_bias_rad_s": 0.0, "angle_scale_error": 0.0,
                   "rate_scale_error": 0.0, "rate_random_walk_rad_s_sqrt_s": 0.0,
                   "latency_s": 0.0},
    "accelerometer": {"bias_m_s2": 0.0, "scale_error": 0.0, "tilt_rad": 0.0,
                      "tilt_azimuth_rad": 0.0, "latency_s": 0.0},
    "thruster_valves": {"couple_negative_n_m": None, "open_delay_negative_s": None,
                        "close_delay_negative_s": None},
}


def rig_with(changes: dict[str, dict[str, Any]] | None = None,
             as_built: dict[str, Any] | None = None, quiet: bool = False) -> RigConfig:
    """sgsrt with some sections' keys changed and an ``as_built:`` overlay; ``quiet``: no
    sensor noise (readings comparable tick by tick)."""
    data = yaml.safe_load((RIGS_DIR / "sgsrt.yaml").read_text())
    for section, keys in (changes or {}).items():
        data.setdefault(section, {}).update(keys)
    if quiet:
        data["hub_sensor"].update(angle_noise_rms_rad=0.0, rate_noise_rms_rad_s=0.0)
        data["accelerometer"]["noise_rms_m_s2"] = 0.0
    if as_built is not None:
        data["as_built"] = as_built
    return rig_from_dict(data, source="rig file test.yaml", base_dir=RIGS_DIR)


class Bench:
    """A virtual rig on a private in-process bus, ticked in lockstep as the harness does:
    SYNC out, ``service()``, the telemetry frames decoded."""

    def __init__(self, rig: RigConfig, name: str) -> None:
        self.bus = CopyingVirtualBus(channel=name)
        self.rig_bus = CopyingVirtualBus(channel=name)
        self.rig = VirtualRig(rig, self.rig_bus, DT)
        self.k = 0

    def send(self, frame: str, **values: float) -> None:
        self.bus.send(can.Message(arbitration_id=P[frame].frame_id,
                                  data=P[frame].encode(values), is_extended_id=False))

    def tick(self) -> dict[str, dict[str, float]]:
        self.send("SYNC", tick=self.k % 256)
        self.k += 1
        self.rig.service()
        frames = {}
        while (m := self.bus.recv(0)) is not None:
            frames[P.by_id[m.arbitration_id].name] = P.by_id[m.arbitration_id].decode(m.data)
        return frames

    def arm(self) -> None:
        self.send("HEARTBEAT", counter=1, armed=1)

    def close(self) -> None:
        self.bus.shutdown()
        self.rig_bus.shutdown()


@pytest.fixture
def bench(request):
    made: list[Bench] = []

    def make(rig: RigConfig, tag: str = "") -> Bench:
        b = Bench(rig, f"as-built-{request.node.name}-{tag}{len(made)}")
        made.append(b)
        return b
    yield make
    for b in made:
        b.close()


def hub_momentum(rig: VirtualRig) -> float:
    """The hub coordinate's generalised momentum J theta' + delta . eta' (what every torque
    on the hub changes, and only they)."""
    nq = rig.n_modes + 1
    return float(rig.rig.plant.mass[0] @ rig.x[nq:])


def drive(b: Bench, n: int, torque: float = 0.0, at: int = 0) -> list[dict]:
    """``n`` ticks, the wheel commanded ``torque`` from tick ``at`` (re-sent each tick: the
    heartbeat kept alive)."""
    out = []
    for k in range(n):
        b.send("HEARTBEAT", counter=(k + 2) % 256, armed=1)
        if k >= at:
            b.send("WHEEL_CMD", torque_cmd=torque, enable=1)
        out.append(b.tick())
    return out


# ----------------------------------------------------------------- the ideal rig unchanged
def test_explicit_zero_values_give_the_ideal_rigs_telemetry_and_truth_bit_for_bit(bench):
    """Every new key written out at its zero value, at the top level and as an as_built:
    overlay: the same frames and the same truth as sgsrt, tick by tick (the fast paths and
    the emulation agree); and the ideal rig emulates itself."""
    assert SGSRT.as_built_rig() is SGSRT and SGSRT.data["as_built"] is None
    zero = rig_with(ZERO_KEYS, as_built={k: v for k, v in ZERO_KEYS.items()
                                         if k != "thruster_valves"})
    runs = []
    for rig in (SGSRT, zero):
        b = bench(rig)
        b.arm()
        frames = drive(b, 60, torque=0.03, at=5) + drive(b, 60, torque=-0.02)
        b.send("VALVE_CMD", valve_pos=0, valve_neg=1)
        frames += drive(b, 40)
        truth = b.rig.truth
        runs.append((frames, truth.angle_rad, truth.rate_rad_s, truth.tip_accel_m_s2,
                     b.rig.wheel.speed_rad_s, b.rig.x.tolist()))
    assert runs[0] == runs[1]


def test_the_as_built_sensor_path_with_nothing_to_add_is_the_ideal_path(bench):
    """The rig's as-built sensor path (delay line, accelerometer's sensed input) forced on
    for the ideal rig gives the very same readings: it adds only what the rig file says."""
    readings = []
    for force in (False, True):
        b = bench(SGSRT)
        b.rig._sensor_terms = force
        b.arm()
        readings.append(drive(b, 80, torque=0.04, at=3))
    assert readings[0] == readings[1]


# ----------------------------------------------------------------- each term
def test_a_coasting_wheel_decelerates_by_its_friction_and_the_hub_takes_what_it_loses(bench):
    coulomb, viscous = 6.0e-4, 1.0e-6
    b = bench(rig_with({"reaction_wheel": {"friction_coulomb_n_m": coulomb,
                                           "friction_viscous_n_m_s": viscous}}))
    rig = b.rig
    j = rig.wheel.rotor_inertia_kg_m2
    rig.wheel.speed_rad_s = w0 = 300.0
    speeds = [w0]
    for _ in range(500):
        rig.step()
        speeds.append(rig.wheel.speed_rad_s)
    w = np.array(speeds)
    decel = -np.diff(w) / DT
    np.testing.assert_allclose(decel, (coulomb + viscous * np.abs(w[:-1])) / j, rtol=1e-9)
    # internal friction: the hub gains exactly the momentum the rotor lost
    assert hub_momentum(rig) == pytest.approx(-j * (w[-1] - w0), rel=1e-9)
    assert rig.wheel.torque_n_m == 0.0  # the telemetry's torque is the motor's only


def test_a_wheel_stops_at_zero_without_reversing_and_keeps_the_momentum_balance(bench):
    b = bench(rig_with({"reaction_wheel": {"friction_coulomb_n_m": 6.0e-4}}))
    rig = b.rig
    j = rig.wheel.rotor_inertia_kg_m2
    rig.wheel.speed_rad_s = w0 = -0.5  # ~1.3 s to stop
    for _ in range(1000):
        rig.step()
        assert rig.wheel.speed_rad_s <= 0.0
    assert rig.wheel.speed_rad_s == 0.0
    assert hub_momentum(rig) == pytest.approx(-j * (0.0 - w0), rel=1e-9)


def test_a_wheel_at_rest_stays_there_below_its_breakaway_torque():
    def wheel() -> ReactionWheel:
        w = ReactionWheel(max_torque_n_m=0.065, max_speed_rad_s=628.0,
                          rotor_inertia_kg_m2=0.0016, torque_lag_s=0.0, dt_s=DT,
                          friction_coulomb_n_m=6.0e-4, friction_breakaway_n_m=8.0e-4)
        return w

    below = wheel()
    below.command(7.5e-4, True)  # above Coulomb, below breakaway
    assert [below.step() for _ in range(200)] == [0.0] * 200
    assert below.speed_rad_s == 0.0 and below.torque_n_m == 7.5e-4
    above = wheel()
    above.command(9.0e-4, True)
    above.step()  # the lag-free motor torque takes hold over the first step
    hub = above.step()
    assert hub == pytest.approx(9.0e-4 - 6.0e-4)  # Coulomb once it slides
    assert above.speed_rad_s < 0.0
    # breakaway defaults to the Coulomb friction
    plain = ReactionWheel(0.065, 628.0, 0.0016, 0.0, DT, friction_coulomb_n_m=6.0e-4)
    plain.command(5.0e-4, True)
    for _ in range(10):
        plain.step()
    assert plain.speed_rad_s == 0.0


def test_a_gyro_bias_shows_in_the_mean_rate_at_rest_and_its_random_walk_grows(bench):
    b = bench(rig_with(as_built={"hub_sensor": {"rate_bias_rad_s": 3.0e-5,
                                                "angle_bias_rad": 1.0e-4}}))
    frames = [b.tick()["HUB_TLM"] for _ in range(2000)]
    rate = np.array([f["rate"] for f in frames])
    angle = np.array([f["angle"] for f in frames])
    assert rate.mean() == pytest.approx(3.0e-5, abs=3e-6)  # noise 2e-5 / sqrt(2000)
    assert angle.mean() == pytest.approx(1.0e-4, abs=1e-6)
    assert b.rig.truth.rate_rad_s == 0.0  # the hub did not move: only the sensor reads it
    # the random walk: increments of q sqrt(dt) a sample
    q = 1.0e-3
    walk = bench(rig_with(as_built={"hub_sensor": {"rate_random_walk_rad_s_sqrt_s": q}},
                          quiet=True))
    walks = []
    for _ in range(4000):
        walk.tick()
        walks.append(walk.rig.hub_sensor.rate_walk_rad_s)
    steps = np.diff(walks)
    assert steps.std() == pytest.approx(q * math.sqrt(DT), rel=0.05)


def test_a_hub_sensors_scale_error_scales_its_readings(bench):
    b = bench(rig_with(as_built={"hub_sensor": {"angle_scale_error": 0.02,
                                                "rate_scale_error": -0.01}}, quiet=True))
    b.arm()
    frames = drive(b, 200, torque=0.05)
    truth = b.rig.truth
    assert frames[-1]["HUB_TLM"]["angle"] == pytest.approx(1.02 * truth.angle_rad, abs=2e-7)
    assert frames[-1]["HUB_TLM"]["rate"] == pytest.approx(0.99 * truth.rate_rad_s, abs=2e-7)


def test_an_accelerometers_bias_scale_error_and_tilt():
    acc = Accelerometer(range_m_s2=19.6, bandwidth_hz=400.0, noise_rms_m_s2=0.0,
                        lsb_m_s2=0.0, dt_s=DT, noise=NoiseSource(1), bias_m_s2=0.03,
                        scale_error=0.015)
    for _ in range(50):  # the filter settles on a constant input
        reading = acc.sample(acc.sensed(2.0, 0.0))
    assert reading == pytest.approx(1.015 * 2.0 + 0.03, rel=1e-9)
    tilted = Accelerometer(19.6, 400.0, 0.0, 0.0, DT, NoiseSource(1), tilt_rad=0.01,
                           tilt_azimuth_rad=0.5)
    assert tilted.sensed(0.0, 0.5) == pytest.approx(G0_M_S2 * math.sin(0.01))
    assert tilted.sensed(0.0, 0.5 + math.pi / 2) == pytest.approx(0.0, abs=1e-12)


def test_an_accelerometer_at_rest_reads_its_bias_and_tilt_on_the_rig(bench):
    b = bench(rig_with(as_built={"accelerometer": {"bias_m_s2": 0.03, "scale_error": 0.015,
                                                   "tilt_rad": 1.0e-3,
                                                   "tilt_azimuth_rad": 0.5}}))
    accel = np.array([b.tick()["ACCEL_TLM"]["accel"] for _ in range(2000)])
    expected = 0.03 + 1.015 * G0_M_S2 * math.sin(1.0e-3) * math.cos(-0.5)
    assert accel.mean() == pytest.approx(expected, abs=5e-4)  # noise 5e-3 / sqrt(2000)


def test_a_sensors_latency_shifts_its_readings_by_whole_ticks(bench):
    ideal = bench(rig_with(quiet=True))
    late = bench(rig_with(as_built={"hub_sensor": {"latency_s": 0.006},
                                    "accelerometer": {"latency_s": 0.004}}, quiet=True))
    assert (late.rig.hub_latency_ticks, late.rig.accel_latency_ticks) == (3, 2)
    runs = []
    for b in (ideal, late):
        b.arm()
        runs.append(drive(b, 120, torque=0.05, at=10))
    a, d = runs
    hub = [f["HUB_TLM"] for f in a]
    acc = [f["ACCEL_TLM"]["accel"] for f in a]
    assert [f["HUB_TLM"] for f in d[3:]] == hub[:-3]
    assert [f["HUB_TLM"] for f in d[:3]] == [{"angle": 0.0, "rate": 0.0}] * 3
    # the accelerometer's own filter runs on the delayed input: the same values 2 ticks on
    assert [f["ACCEL_TLM"]["accel"] for f in d[2:]] == acc[:-2]
    assert any(v != 0.0 for v in acc) and hub[-1]["angle"] != 0.0


def test_each_valve_has_its_own_couple_and_delays():
    v = ThrusterValves(couple_n_m=0.095, open_delay_s=0.004, close_delay_s=0.004,
                       min_on_time_s=0.0, dt_s=DT, couple_negative_n_m=0.094,
                       open_delay_negative_s=0.010, close_delay_negative_s=0.002)

    def run(direction: int, n: int) -> list[float]:
        v.command(direction)
        return [v.step() for _ in range(n)]

    assert run(1, 4) == [0.0, 0.0, 0.095, 0.095]  # opens 2 steps (4 ms) on
    assert run(0, 4) == [0.095, 0.095, 0.0, 0.0]  # closes 2 steps on
    assert run(-1, 7) == [0.0] * 5 + [-0.094] * 2  # the negative valve: 5 steps (10 ms)
    assert run(0, 3) == [-0.094, 0.0, 0.0]  # closes after 1 step (2 ms)
    same = ThrusterValves(0.1, 0.004, 0.004, 0.0, DT)
    same.command(-1)
    assert [same.step() for _ in range(3)] == [0.0, 0.0, -0.1]


def test_frequency_factors_move_the_hub_free_modes():
    w0 = SGSRT.plant.hub_free_modes()[0]
    uniform = rig_with({"beam": {"frequency_factors": [1.1, 1.1, 1.1]}})
    np.testing.assert_allclose(uniform.plant.hub_free_modes()[0], 1.1 * w0, rtol=1e-9)
    factors = [1.02, 0.975, 1.03]
    each = rig_with({"beam": {"frequency_factors": factors}})
    np.testing.assert_allclose(each.plant.hub_free_modes()[0] / w0, factors, rtol=2e-3)
    np.testing.assert_allclose(each.plant.modes.omega_rad_s,
                               SGSRT.beam_modes.omega_rad_s * factors, rtol=1e-12)
    first = rig_with({"beam": {"frequency_factors": [0.9]}})  # missing entries: 1
    np.testing.assert_allclose(first.plant.hub_free_modes()[0] / w0, [0.9, 1.0, 1.0],
                               rtol=3e-3)


def test_damping_ratios_per_mode():
    rig = rig_with({"beam": {"damping_ratios": [0.01, 0.02]}})
    np.testing.assert_array_equal(rig.plant.damping_ratio, [0.01, 0.02, 0.05])
    # the hub-free poles' damping follows each mode's ratio
    base = SGSRT.plant.hub_free_modal_damping()[1]
    np.testing.assert_allclose(rig.plant.hub_free_modal_damping()[1] / base,
                               [0.2, 0.4, 1.0], rtol=0.02)


def test_a_table_out_of_level_drives_the_hub_angle(bench):
    g, j = 2.0e-3, SGSRT.data["hub"]["inertia_kg_m2"]
    # the hub at 90 deg from the table's low point: torque +g at the start
    b = bench(rig_with({"hub": {"gravity_torque_n_m": g, "gravity_azimuth_rad": math.pi / 2}},
                       quiet=True))
    for _ in range(1000):
        b.tick()
    t = b.rig.time_s
    assert b.rig.truth.angle_rad == pytest.approx(0.5 * g / j * t * t, rel=0.03)
    assert hub_momentum(b.rig) == pytest.approx(g * t, rel=1e-3)
    # at its low point the hub stays; off it, the torque pulls it back
    level = bench(rig_with({"hub": {"gravity_torque_n_m": g}}, quiet=True))
    for _ in range(200):
        level.tick()
    assert level.rig.truth.angle_rad == 0.0
    level.rig.x[0] = 0.1
    level.rig.step()
    assert hub_momentum(level.rig) == pytest.approx(-g * math.sin(0.1) * DT, rel=1e-9)


# ----------------------------------------------------------------- the overlay
@pytest.mark.parametrize(("as_built", "names"), [
    ({"hub": {"inertia_kg_m2": -1.0}}, "as_built.hub.inertia_kg_m2: expected a finite number > 0"),
    ({"hub": {"inertia_kgm2": 15.6}}, "as_built.hub.inertia_kgm2: unknown key"),
    ({"bus": {"bitrate_bit_s": 500000}}, "as_built.bus: unknown key"),
    ({"beam": {"frequency_factors": [1.0, -1.0]}}, "as_built.beam.frequency_factors"),
    ({"timing": {"answer_latency_s": 1.0}}, "as_built.timing.answer_latency_s"),
    ({"reaction_wheel": {"friction_coulomb_n_m": 1e-3, "friction_breakaway_n_m": 5e-4}},
     "as_built: reaction_wheel.friction_breakaway_n_m: expected >= friction_coulomb_n_m"),
    ({"beam": {"damping_ratios": [0.01, 0.01, 0.01, 0.01]}},
     "as_built: beam.damping_ratios: 4 entries for beam.n_modes = 3"),
    ([1, 2], "as_built: expected a mapping of keys"),
])
def test_a_bad_as_built_key_is_refused_naming_it(as_built, names):
    with pytest.raises(ConfigError, match=r"rig file test\.yaml: ") as exc:
        rig_with(as_built=as_built)
    assert names in str(exc.value)


def test_model_keys_are_checked_across_keys_too():
    with pytest.raises(ConfigError, match="beam.frequency_factors: 4 entries"):
        rig_with({"beam": {"frequency_factors": [1.0] * 4}})
    with pytest.raises(ConfigError, match="reaction_wheel.friction_breakaway_n_m"):
        rig_with({"reaction_wheel": {"friction_coulomb_n_m": 1e-3,
                                     "friction_breakaway_n_m": 1e-4}})


def test_the_overlay_is_merged_for_the_virtual_rig_only():
    rig = load_rig("sgsrt-as-built")
    built = rig.as_built_rig()
    # the harness's model: sgsrt's data exactly, but for the name and the overlay
    assert {k: v for k, v in rig.data.items() if k not in ("name", "as_built")} == {
        k: v for k, v in SGSRT.data.items() if k not in ("name", "as_built")}
    assert rig.data["hub"]["inertia_kg_m2"] == 15.0
    # the rig as built: the overlay merged key by key, the section gone
    assert built.data["as_built"] is None and built.name == "sgsrt-as-built"
    assert built.data["hub"] == {**SGSRT.data["hub"], "inertia_kg_m2": 15.6,
                                 "gravity_torque_n_m": 2.0e-4}
    assert built.data["beam"]["damping_ratio"] == 0.012
    assert built.data["beam"]["length_m"] == SGSRT.data["beam"]["length_m"]
    assert built.binding is rig.binding
    assert rig.answer_timing == (2.0e-4, 1.0e-4) and SGSRT.answer_timing == (0.0, 0.0)
    # the virtual rig emulates the rig as built
    vr = VirtualRig(rig, None, DT)  # type: ignore[arg-type]
    assert vr.model_rig is rig and vr.rig is built
    assert vr.wheel.friction_coulomb_n_m == 6.0e-4 and vr.wheel.torque_lag_s == 0.012
    assert vr.rig.plant.inertia_kg_m2 == 15.6 and vr.valves._couple_neg == 0.094


def test_the_as_built_rig_values_stay_within_the_models_tolerances():
    rig = load_rig("sgsrt-as-built")
    tol, built = rig.data["tolerances"], rig.as_built_rig().data
    assert abs(built["hub"]["inertia_kg_m2"] / rig.data["hub"]["inertia_kg_m2"] - 1) <= \
        tol["inertia_fraction"]
    for key in ("couple_n_m", "couple_negative_n_m"):
        assert abs(built["thruster_valves"][key] / rig.data["thruster_valves"]["couple_n_m"]
                   - 1) <= tol["couple_fraction"]
    assert abs(built["hub_sensor"]["rate_bias_rad_s"]) <= tol["rate_bias_rad_s"]
    acc = built["accelerometer"]
    at_rest = acc["bias_m_s2"] + (1 + acc["scale_error"]) * G0_M_S2 * math.sin(
        acc["tilt_rad"]) * math.cos(-acc["tilt_azimuth_rad"])
    assert abs(at_rest) <= tol["accel_bias_m_s2"]


def test_the_three_as_built_rigs_share_one_overlay():
    rigs = [load_rig(n) for n in ("sgsrt-as-built", "sgsrt-canopen-as-built",
                                  "sgsrt-dbc2-as-built")]
    assert [r.name for r in rigs] == ["sgsrt-as-built", "sgsrt-canopen-as-built",
                                      "sgsrt-dbc2-as-built"]
    assert rigs[0].data["as_built"] == rigs[1].data["as_built"] == rigs[2].data["as_built"]
    assert rigs[1].data["devices"] == load_rig("sgsrt-canopen").data["devices"]
    assert rigs[2].data["devices"] == load_rig("sgsrt-dbc2").data["devices"]
    assert "as_built" not in yaml.safe_load((RIGS_DIR / "sgsrt.yaml").read_text())


def test_as_built_from_takes_the_other_files_section_under_its_own(tmp_path):
    (tmp_path / "a.yaml").write_text("extends: sgsrt-canopen\nname: a\n"
                                     "as_built_from: sgsrt-as-built\n"
                                     "as_built: {hub: {inertia_kg_m2: 15.3}}\n")
    rig = load_rig(tmp_path / "a.yaml")
    assert rig.data["as_built"]["hub"]["inertia_kg_m2"] == 15.3
    assert rig.data["as_built"]["beam"]["damping_ratio"] == 0.012
    (tmp_path / "b.yaml").write_text("extends: sgsrt\nname: b\nas_built_from: sgsrt\n")
    with pytest.raises(ConfigError, match="b.yaml: as_built_from: its rig file has no"):
        load_rig(tmp_path / "b.yaml")
    (tmp_path / "c.yaml").write_text("extends: sgsrt\nname: c\nas_built_from: c.yaml\n")
    with pytest.raises(ConfigError, match="a circle"):
        load_rig(tmp_path / "c.yaml")


def test_the_rig_process_file_keeps_the_overlay(tmp_path):
    """The rig process's child reads the harness's rig data back from a file
    (harness.bus.rig_process writes ``rig.data``): it emulates the same rig as built."""
    rig = load_rig("sgsrt-dbc2-as-built")
    path = tmp_path / "rig.yaml"
    path.write_text(yaml.safe_dump(rig.data, sort_keys=False))
    child = load_rig(path)
    assert child.data == rig.data
    assert child.as_built_rig().data == rig.as_built_rig().data


# ----------------------------------------------------------------- timing, real time only
def test_late_answers_are_emulated_in_real_time_and_not_in_lockstep(request):
    latency = 0.03
    rig_cfg = rig_with(as_built={"timing": {"answer_latency_s": latency}})
    name = f"as-built-timing-{request.node.name}"
    bus, rig_bus = CopyingVirtualBus(channel=name), CopyingVirtualBus(channel=name)
    stop = threading.Event()
    try:
        rig = VirtualRig(rig_cfg, rig_bus, DT)
        sync = can.Message(arbitration_id=P["SYNC"].frame_id, data=P["SYNC"].encode({"tick": 0}),
                           is_extended_id=False)
        bus.send(sync)
        t0 = time.perf_counter()
        rig.service()  # lockstep: at once
        assert bus.recv(0) is not None and time.perf_counter() - t0 < latency
        while bus.recv(0) is not None:
            pass
        thread = threading.Thread(target=rig.run_forever, args=(stop.is_set, 0.01),
                                  daemon=True)
        thread.start()
        sync = can.Message(arbitration_id=P["SYNC"].frame_id, data=P["SYNC"].encode({"tick": 1}),
                           is_extended_id=False)
        t0 = time.perf_counter()
        bus.send(sync)
        assert bus.recv(5.0) is not None
        assert time.perf_counter() - t0 >= latency
    finally:
        stop.set()
        bus.shutdown()
        rig_bus.shutdown()


# ----------------------------------------------------------------- end to end
def test_a_lockstep_run_on_the_as_built_rig_shows_the_wheels_friction(tmp_path: Path):
    """A wheel torque pulse through the whole harness in lockstep on sgsrt-as-built: after
    the pulse the wheel's reported speed decays at about (Coulomb + viscous x speed) / rotor
    inertia."""
    raw = {"name": "pulse", "description": "a wheel pulse, then coasting",
           "rig": "sgsrt-as-built", "clock": "lockstep", "rate_hz": 100.0, "duration_s": 4.0,
           "actuators": ["reaction_wheel"],
           "controller": {"type": "wheel_pulse", "torque_n_m": 0.02, "start_s": 0.2,
                          "width_s": 0.5}}
    path = tmp_path / "pulse.yaml"
    path.write_text(yaml.safe_dump(raw))
    res = execute_run(load_run(str(path)), out_dir=tmp_path / "logs",
                      bus=private_channel("sgsrt-as-built"), show_progress=False)
    assert res.summary["stopped_by"] == "completed"
    cols = RecordedColumns(res.run_dir / "run.rrd")
    t, w = cols.time_s, cols.column("/wheel/speed_rad_s")
    coast = (t > 1.0) & (t < 3.9)
    # the pulse spun the rotor negative (+0.02 N m on the hub): slowing is a positive slope
    slowing = np.polyfit(t[coast], w[coast], 1)[0]
    rw = load_rig("sgsrt-as-built").data["as_built"]["reaction_wheel"]
    mean_w = float(np.mean(np.abs(w[coast])))
    expected = (rw["friction_coulomb_n_m"] + rw["friction_viscous_n_m_s"] * mean_w) / 0.0016
    assert w[coast][0] < -5.0
    assert slowing == pytest.approx(expected, rel=0.05)
