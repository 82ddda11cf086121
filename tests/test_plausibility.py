"""The stuck rule from a sensor's resolution and noise: a coarse sensor at rest repeats its
reading and is not stuck; a frozen one is, by its noise or by the motion its rate says."""

from __future__ import annotations

import math

import numpy as np
import pytest
import yaml

from harness.core.plausibility import (
    ChannelQuality,
    healthy_repeats,
    hub_is_stuck,
    repeated_reading_is_stuck,
    sensor_quality,
    stay_probability,
)
from rig_models.rig_file import RIGS_DIR, load_rig, rig_from_dict

DEG = math.pi / 180
DT = 0.002
COARSE = ChannelQuality(resolution=0.01 * DEG, noise_rms=0.0005 * DEG)  # 0.01 deg steps
COARSE_RATE = ChannelQuality(resolution=0.01 * DEG, noise_rms=0.0005 * DEG)


def _longest_run(readings: np.ndarray) -> int:
    best = run = 1
    for a, b in zip(readings[:-1], readings[1:], strict=True):
        run = run + 1 if a == b else 1
        best = max(best, run)
    return best


def test_a_coarse_sensor_at_rest_is_not_stuck():
    """0.01 deg steps, noise a twentieth of a step: its simulated readings at rest repeat
    for the whole 10 s, and the rule says that is what such a sensor does."""
    rng = np.random.default_rng(1)
    n = 5000  # 10 s at 500 Hz
    true = 0.123456 * DEG + np.zeros(n)
    angle = np.round((true + rng.normal(0, COARSE.noise_rms, n)) / COARSE.resolution)
    rate = np.round(rng.normal(0, COARSE_RATE.noise_rms, n) / COARSE_RATE.resolution)
    same = min(_longest_run(angle), _longest_run(rate))
    assert same > 1000  # the old rule (50 equal samples) called this stuck
    assert not hub_is_stuck(same, 0.0, DT, COARSE, COARSE_RATE, stuck_ticks=50)


def test_a_noisy_sensor_frozen_is_stuck_and_its_healthy_self_is_not():
    """Noise of half a step: a healthy sensor at rest changes its reading often, so a long
    run of equal samples is a fault; its own longest healthy run is not."""
    q = ChannelQuality(resolution=1e-4, noise_rms=5e-5)
    rng = np.random.default_rng(2)
    readings = np.round((3.3e-4 + rng.normal(0, q.noise_rms, 100_000)) / q.resolution)
    healthy = _longest_run(readings)
    assert not repeated_reading_is_stuck(healthy, (q,), stuck_ticks=5)
    limit = healthy_repeats((q,))
    assert healthy < limit < 100
    assert repeated_reading_is_stuck(math.ceil(limit) + 1, (q,), stuck_ticks=5)
    assert repeated_reading_is_stuck(60, (q, q), stuck_ticks=50)


def test_the_rate_says_it_moves_but_the_angle_is_frozen():
    # 0.5 deg/s over 50 samples is 0.5 deg: 50 steps of 0.01 deg, the angle never changed
    assert hub_is_stuck(50, 0.5 * DEG, DT, COARSE, COARSE_RATE, stuck_ticks=50)
    # a rate of a tenth of a step's worth over the window: it may well be at rest
    slow = 0.1 * COARSE.resolution / (49 * DT)
    assert not hub_is_stuck(50, slow, DT, COARSE, COARSE_RATE, stuck_ticks=50)
    # never before the monitor's own floor
    assert not hub_is_stuck(49, 0.5 * DEG, DT, COARSE, COARSE_RATE, stuck_ticks=50)


def test_stay_probability_bounds():
    assert stay_probability(ChannelQuality(1e-3, 0.0)) == 1.0
    assert stay_probability(ChannelQuality(0.0, 1e-3)) == 0.0
    # noise of one step: the reading stays in its step about 38 % of the time at best
    assert stay_probability(ChannelQuality(1.0, 1.0)) == pytest.approx(0.3829, abs=1e-3)
    assert healthy_repeats((ChannelQuality(1e-3, 0.0),)) == math.inf


def test_sensor_quality_takes_the_rig_file_and_the_binding():
    q = sensor_quality(load_rig("sgsrt"))
    assert set(q) == {"hub_sensor.angle", "hub_sensor.rate", "accelerometer.accel",
                      "piezo_amplifier.sensor_ch1", "piezo_amplifier.sensor_ch2"}
    assert q["piezo_amplifier.sensor_ch1"] == ChannelQuality(0.001, 0.001)
    # a coarse hub encoder in a rig file: 0.01 deg steps, the binding's 1e-7 rad finer
    data = yaml.safe_load(yaml.safe_dump(load_rig("sgsrt-canopen").data))
    data["hub_sensor"]["angle_lsb_rad"] = 0.01 * DEG
    data["hub_sensor"]["angle_noise_rms_rad"] = 0.0005 * DEG
    rig = rig_from_dict(data, "rig file x.yaml", base_dir=RIGS_DIR)
    assert sensor_quality(rig)["hub_sensor.angle"] == ChannelQuality(0.01 * DEG,
                                                                     0.0005 * DEG)
    # the binding coarser than the rig file: the accelerometer's analog input counts
    assert sensor_quality(rig)["accelerometer.accel"].resolution == pytest.approx(
        1.52587890625e-3)
