"""Legend names (harness/review/names.py): every plotted series of run.rrd, the decoded bus,
sweep.rrd and the studies' recordings carries a short readable name in the legend (a static
``SeriesLines:names``) while its entity path stays what tests and docs use."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from harness.core.loop import CHANNELS
from harness.record.reader import read_scalar_channel
from harness.review import layouts as L
from harness.review.names import SERIES_NAMES, series_name, strip_unit
from harness.review.reader import read_series_names


def test_every_plotted_series_has_a_short_distinct_name():
    for plot in (*L.PLOTS.values(), *L.BUS_PLOTS):
        names = [series_name(c) for c in plot.channels]
        assert len(set(names)) == len(names), plot.key  # which curve is which
        for n in names:
            assert "/" not in n and len(n) <= 24, (plot.key, n)
    assert set(CHANNELS) <= set(SERIES_NAMES)
    assert series_name("/bus/hub_sensor/rx_after_sync_ms") == "hub sensor"
    assert series_name("/sweep/curves/tip_accel_m_s2/beta_0.60") == "beta 0.60"
    assert strip_unit("torque_cmd_n_m") == "torque_cmd" and strip_unit("rate_deg_s") == "rate"


def test_run_rrd_legends_name_each_series(slew_result):
    rrd = slew_result.run_dir / "run.rrd"
    names = read_series_names(rrd)
    for c in CHANNELS:
        assert names[c] == [SERIES_NAMES[c]], c
    assert names["/bus/reaction_wheel/cmd/torque_cmd_n_m"] == ["WHEEL_CMD torque_cmd"]
    assert names["/bus/reaction_wheel/tlm/torque_n_m"] == ["WHEEL_TLM torque"]
    assert names["/bus/hub_sensor/rx_after_sync_ms"] == ["hub sensor"]
    assert names["/bus/late_or_missing"] == ["late or missing"]
    # the paths themselves are unchanged and still read back as the loop's rows
    t, angle = read_scalar_channel(rrd, "/attitude/angle_deg")
    assert len(t) == slew_result.summary["ticks"] and np.isfinite(angle).all()
    assert slew_result.columns().rows == slew_result.summary["ticks"]


def test_sweep_rrd_legends_are_the_betas(tmp_path):
    from harness.studies.sweep_report import save_rrd

    path = tmp_path / "sweep.rrd"
    save_rrd(path, "sweep-test", np.linspace(0.5, 1.5, 3), np.array([0.6, 1.0]),
             np.ones((3, 2, 2)))
    names = read_series_names(path)
    assert names["/sweep/curves/tip_accel_m_s2/beta_0.60"] == ["beta 0.60"]
    assert names["/sweep/log10/tip_deflection_m/beta_1.00"] == ["beta 1.00"]


def test_wang2022_recording_names_its_columns(tmp_path):
    from harness.studies.wang2022 import write_recording

    n = 5
    hist = SimpleNamespace(t=np.linspace(0, 1, n), eta=np.zeros((n, 6)), omega=np.zeros((n, 3)),
                           torque=np.zeros((n, 3)), q=np.tile([1.0, 0, 0, 0], (n, 1)))
    model = SimpleNamespace(tip_gain=np.ones(6))
    path = tmp_path / "wang.rrd"
    write_recording(str(path), {"tracked/zv/a": hist}, model, np.array([1.0, 0, 0, 0]))
    names = read_series_names(path)
    assert names["/wang2022/tracked/zv/a/eta"] == [f"mode {i}" for i in range(1, 7)]
    assert names["/wang2022/tracked/zv/a/body_rate_rad_s"] == ["x", "y", "z"]
    assert names["/wang2022/tracked/zv/a/quaternion"][0] == "q0 (scalar)"
