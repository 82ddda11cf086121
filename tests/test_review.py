"""What a reviewer sees in the Rerun viewer (harness/review, docs/review.md): the layout of
each kind of run, events and markers, the summary, the decoded bus, the identification's
spectrum, and one layout for run.rrd, identify.rrd and verdict.rrd together."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import rerun as rr
import rerun.blueprint as rrb

from harness.core.loop import CHANNELS
from harness.core.runs import load_run
from harness.core.session import execute_run
from harness.record.recording import APPLICATION_ID
from harness.review import layouts as L
from harness.review.reader import entities, read_blueprints, read_events, read_text
from rig_models.faults import parse_fault

RUN_KINDS = {
    "slew-rw": "slew", "slew-rw-zv": "slew", "case-a": "periodic", "free-decay": "free_decay",
    "slew-thruster-bangbang": "thruster", "thruster-pd-pwpf": "thruster",
    "thruster-oppf": "piezo",
}
TEXT_VIEWS = {L.EVENTS_VIEW, L.SUMMARY_VIEW, L.VERDICT_VIEW, L.CONFIG_VIEW}


def views_by_name(bp: rrb.Blueprint) -> dict[str, rrb.View]:
    return {str(v.name): v for v in L.blueprint_views(bp)}


@pytest.mark.parametrize(("name", "kind"), sorted(RUN_KINDS.items()))
def test_kind_of_each_built_in_run(name, kind):
    assert L.run_kind(load_run(name).resolved()) == kind


@pytest.mark.parametrize("kind", L.KINDS)
def test_layout_holds_the_views_the_docs_describe(kind):
    run = {"run": {"duration_s": 60.0, "controller": {"type": {
        "slew": "pd_wheel", "periodic": "square_wave", "free_decay": "wheel_bursts",
        "thruster": "thruster_two_level", "piezo": "thruster_pd_pwpf"}[kind]}
        | ({"piezo": {"channels": [1]}} if kind == "piezo" else {}),
        "actuators": ["piezo_amplifier", "thruster_valves"] if kind == "piezo" else []}}
    assert L.run_kind(run) == kind
    views = views_by_name(L.layout_for_run(run, CHANNELS))
    assert TEXT_VIEWS <= set(views)
    assert isinstance(views[L.EVENTS_VIEW], rrb.TextLogView)
    assert views[L.EVENTS_VIEW].origin == "/events"  # faults, interrupts, verdict alike
    assert views[L.VERDICT_VIEW].origin == "/run/verdict"
    assert views[L.SUMMARY_VIEW].origin == "/run/summary"
    # every plot of the run's kind, each with its unit in the title and its markers
    for key in L.MAIN_PLOTS[kind]:
        plot = L.PLOTS[key]
        assert "(" in plot.title and plot.title.endswith(")")
        contents = views[plot.title].contents
        assert list(plot.channels) + [f"/markers/{key}/**"] == list(contents) or \
            set(contents) >= {f"/markers/{key}/**"}
    assert {L.SPECTRUM_VIEW, L.WINDOWS_VIEW} <= set(views)  # identify.rrd has a place
    for p in L.BUS_PLOTS:
        assert p.title in views


def _tab(bp: rrb.Blueprint, name: str) -> set[str]:
    """The titles of the views on one tab of a run's layout."""
    found: list[rrb.Container] = []

    def walk(node) -> None:
        if isinstance(node, rrb.Container):
            if str(node.name) == name:
                found.append(node)
            for c in node.contents:
                walk(c)

    walk(bp.root_container)
    (tab,) = found
    return {str(v.name) for v in L.blueprint_views(rrb.Blueprint(tab))}


def test_timing_on_the_wire_is_on_the_run_page_when_it_was_measured():
    run = load_run("slew-rw").resolved()
    wire, loop = L.PLOTS["wire"].title, L.PLOTS["timing"].title
    ranges = {"/timing/lateness_ms": [0.0, 1.0]}
    bp = L.layout_for_run(run, CHANNELS, ranges)  # a lockstep run: nothing on the wire
    assert loop in _tab(bp, "Run") and wire not in _tab(bp, "Run")
    assert wire in _tab(bp, "Other signals")
    ranges["/timing/sync_jitter_ms"] = [0.1, 3.0]  # a real bus's kernel time stamps
    bp = L.layout_for_run(run, CHANNELS, ranges)
    assert {loop, wire} <= _tab(bp, "Run") and wire not in _tab(bp, "Other signals")


def test_every_built_in_run_gets_a_layout():
    from harness.core.runs import list_runs

    for name, _ in list_runs():
        run = load_run(name).resolved()
        views = views_by_name(L.layout_for_run(run, CHANNELS))
        assert TEXT_VIEWS <= set(views), name
    valve_decay = {"run": {"controller": {"type": "valve_bursts"}, "duration_s": 10,
                           "actuators": ["thruster_valves"]}}
    assert L.run_kind(valve_decay) == "free_decay"
    assert L.PLOTS["valves"].title in views_by_name(L.layout_for_run(valve_decay, CHANNELS))


def test_no_plot_mixes_units_or_scales():
    """One quantity a plot: error apart from the angle, torques apart from speeds,
    milliseconds apart from counts."""
    def unit(channel: str) -> str:
        units = ("_deg_s", "_deg", "_n_m", "_rad_s", "_rad", "_m_s2", "_v", "_ms", "_s")
        return next((u for u in units if channel.endswith(u)), "")

    by_channel = {c: p.key for p in L.PLOTS.values() for c in p.channels}
    assert by_channel["/attitude/error_deg"] != by_channel["/attitude/reference_deg"]
    assert by_channel["/wheel/torque_n_m"] != by_channel["/wheel/speed_rad_s"]
    assert by_channel["/timing/frames_rx"] != by_channel["/timing/work_ms"]
    assert by_channel["/attitude/angle_deg"] == by_channel["/attitude/reference_deg"]
    assert by_channel["/wheel/torque_cmd_n_m"] == by_channel["/wheel/torque_n_m"]
    for p in L.PLOTS.values():
        units = {unit(c) for c in p.channels if not c.startswith(("/bus/", "/timing/frames"))}
        assert len(units) <= 1, (p.key, units)
    assert set(CHANNELS) <= set(by_channel)  # every recorded channel has a plot


def test_y_axis_is_the_data_with_a_small_margin_and_the_judged_band():
    """A 5 deg slew is not drawn on +-10, nor a 0.02 deg error on +-100: the axis
    is the data's span plus a margin, widened only to a criterion's band on that channel."""
    angle = L.axis_range(L.PLOTS["angle"], {"/attitude/angle_deg": [0.0, 5.0],
                                            "/attitude/reference_deg": [0.0, 5.0]})
    assert angle[0] < 0.0 < 5.0 < angle[1] and angle[1] - angle[0] < 5.0 * 1.2
    error = L.axis_range(L.PLOTS["error"], {"/attitude/error_deg": [-0.02, 0.03]})
    assert error[1] - error[0] < 0.05 * 1.2
    # the settle band of +-0.1 deg judges the error: the axis shows it
    run = {"run": {"controller": {"type": "pd_wheel"}, "duration_s": 30.0,
                   "expect": {"s": {"settles": "/attitude/error_deg", "band_deg": 0.1},
                              "t": {"channel": "/tip/accel_m_s2", "max_abs_m_s2": 0.05},
                              "r": {"channel": "/tip/accel_m_s2", "reduce": "rms",
                                    "max_m_s2": 0.001}}}}
    bands = L.criterion_bands(run)
    assert bands == {"/attitude/error_deg": [-0.1, 0.1], "/tip/accel_m_s2": [-0.05, 0.05]}
    banded = L.axis_range(L.PLOTS["error"], {"/attitude/error_deg": [-0.02, 0.03]}, bands)
    assert banded[0] < -0.1 and 0.1 < banded[1] < 0.13
    # counts from zero, a flat signal still gets a span
    assert L.axis_range(L.PLOTS["firings"], {"/thrusters/firings": [3.0, 7.0]})[0] < 0.0
    flat = L.axis_range(L.PLOTS["rate"], {"/attitude/rate_deg_s": [2.0, 2.0]})
    assert flat[0] < 2.0 < flat[1]


@pytest.fixture(scope="module")
def faulted(tmp_path_factory):
    """A 3 s slew with the hub sensor silent from 1 s: stopped by the monitor."""
    out = tmp_path_factory.mktemp("review_fault")
    run = load_run("slew-rw", {"duration_s": 3.0})
    return execute_run(run, out_dir=out, show_progress=False,
                       faults=[parse_fault("silent_sensor@1:hub_sensor")])


def test_faulted_run_recording_holds_event_markers_summary_config_bus(faulted):
    rrd = faulted.run_dir / "run.rrd"
    assert faulted.summary["stopped_by"] == "fault"
    events = read_events(rrd)
    fault = [e for e in events if e.entity == "/events/hub_sensor"]
    assert len(fault) == 1 and fault[0].level == "ERROR" and "silent" in fault[0].text
    assert fault[0].time_s == pytest.approx(faulted.summary["faults"][0]["time_s"])
    # the bus pass saw the missing telemetry from the fault's start
    bus = [e for e in events if e.entity == "/events/can_log"]
    assert bus and 0.99 < bus[0].time_s <= fault[0].time_s and "hub_sensor" in bus[0].text
    have = entities(rrd)
    for key in L.MAIN_PLOTS["slew"]:
        if key != "frames":  # its channels have no value at the fault's tick in lockstep
            assert f"/markers/{key}/fault" in have, key
    summary = read_text(rrd, "/run/summary")
    assert summary.startswith("# slew-rw: fault") and "**FAULT**" in summary
    assert "| final angle (deg) |" in summary
    assert "controller:" in read_text(rrd, "/run/config")
    for e in ("/bus/hub_sensor/tlm/angle_rad", "/bus/reaction_wheel/cmd/torque_cmd_n_m",
              "/bus/harness/sync/tick", "/bus/late_or_missing",
              "/bus/accelerometer/rx_after_sync_ms"):
        assert e in have, e
    # the last layout in the file is the one with the plots' ranges; it holds the views
    saved = read_blueprints(rrd)
    assert len(saved) == 2
    names = {v.name for v in saved[-1]}
    assert TEXT_VIEWS <= names and L.PLOTS["error"].title in names
    assert (faulted.run_dir / L.LAYOUT_FILE).exists()


def test_time_plots_keep_peaks_and_draw_discrete_signals_whole(faulted):
    """Zoomed out, the viewer must not average a 44 ms work peak to 22 ms nor draw a
    -1/0/+1 valve at -0.5. Every continuous series is aggregated MinMax, every discrete one
    not at all (stepped), in the recording itself and as each plot's default in the layout
    run.rrd carries; the same quantity has one colour, distinct within each plot."""
    from harness.review.names import series_colour
    from harness.review.reader import read_series_styles

    rrd = faulted.run_dir / "run.rrd"
    min_max, off, step_after = 5, 1, 2  # Rerun 0.41's enum numbers
    styles = read_series_styles(rrd)
    for c in ("/timing/work_ms", "/tip/accel_m_s2", "/attitude/angle_deg",
              "/bus/accelerometer/tlm/accel_m_s2", "/bus/reaction_wheel/tlm/torque_n_m"):
        assert styles[c]["aggregation_policy"] == min_max, c
    for c in ("/thrusters/valve_cmd", "/thrusters/valve_state", "/thrusters/firings",
              "/timing/frames_rx", "/bus/late_or_missing"):
        assert styles[c]["aggregation_policy"] == off, c
        assert styles[c]["interpolation_mode"] == step_after, c
    final = read_blueprints(rrd)[-1]
    by_name = {v.name: dict(v.defaults) for v in final}
    agg = "SeriesLines:aggregation_policy"
    assert by_name[L.PLOTS["timing"].title][agg] == min_max
    assert by_name[L.PLOTS["tip"].title][agg] == min_max
    assert by_name[L.PLOTS["valves"].title][agg] == off
    assert by_name[L.PLOTS["firings"].title][agg] == off
    assert all(agg in by_name[p.title] for p in (*L.PLOTS.values(), *L.BUS_PLOTS))
    # colours: distinct within a plot, the bus's copy of a quantity in the loop's colour
    for plot in (*L.PLOTS.values(), *L.BUS_PLOTS):
        colours = [series_colour(c) for c in plot.channels]
        assert None not in colours and len(set(colours)) == len(colours), plot.key
    assert styles["/bus/reaction_wheel/cmd/torque_cmd_n_m"]["colors"] == \
        styles["/wheel/torque_cmd_n_m"]["colors"]
    assert styles["/piezo/cmd_ch1_v"]["colors"] != styles["/piezo/cmd_ch2_v"]["colors"]


def test_time_axes_end_where_the_run_ended(faulted):
    """A faulted run's plots end at the fault, not half empty to the configured end."""
    import json

    saved = json.loads((faulted.run_dir / L.LAYOUT_FILE).read_text())
    assert saved["end_s"] == pytest.approx(faulted.summary["simulated_time_s"], abs=0.01)
    assert saved["end_s"] < 2.0  # the 3 s run stopped at the fault near 1 s
    for view in L.blueprint_views(L.blueprint_for_run_dir(faulted.run_dir)):
        axis = getattr(view, "properties", {}).get("TimeAxis")
        if axis is not None:
            end_ns = axis.view_range.as_arrow_array().to_pylist()[0]["end"]
            assert saved["end_s"] < end_ns * 1e-9 < saved["end_s"] * 1.05, view.name


def test_bus_frames_sit_at_their_tick(faulted):
    from harness.record.reader import read_scalar_channel

    t, tick = read_scalar_channel(faulted.run_dir / "run.rrd", "/bus/harness/sync/tick")
    dt = faulted.summary["rate_hz"] ** -1
    assert np.allclose(t, tick * dt)
    t, angle = read_scalar_channel(faulted.run_dir / "run.rrd", "/bus/hub_sensor/tlm/angle_rad")
    k = np.floor(t / dt + 1e-9)
    assert np.all(t - k * dt < 0.9 * dt + 1e-12)  # lockstep: in its own tick
    assert t[-1] < 1.0 + 2 * dt  # silent from 1 s
    # decoded as the drivers decode them: the hub angle the loop recorded at that tick
    ta, angle_deg = read_scalar_channel(faulted.run_dir / "run.rrd", "/attitude/angle_deg")
    at_tick = np.interp(k * dt, ta, angle_deg)
    assert np.abs(np.degrees(angle) - at_tick).max() < 1e-5
    tw, torque = read_scalar_channel(faulted.run_dir / "run.rrd",
                                     "/bus/reaction_wheel/cmd/torque_cmd_n_m")
    assert torque.min() < 0 < torque.max()  # signed fields
    t2, missing = read_scalar_channel(faulted.run_dir / "run.rrd", "/bus/late_or_missing")
    assert missing[t2 < 0.99].max() == 0 and missing[t2 >= 1.0].min() >= 1


def _tiny_verdict_rrd(run_dir: Path) -> Path:
    """verdict.rrd as the verdict layer writes it (COMMON_BRIEF contract)."""
    path = run_dir / "verdict.rrd"
    rec = rr.RecordingStream(APPLICATION_ID, recording_id=run_dir.name)
    rec.save(str(path), default_blueprint=L.blueprint_for_run_dir(run_dir))
    rec.log("/run/verdict", rr.TextDocument("# FAIL\n\nsettle time", media_type="text/markdown"),
            static=True)
    rec.set_time("time", duration=0.5)
    rec.log("/events/verdict", rr.TextLog("settle_time_s 30 > 25", level="ERROR"))
    from harness.review.events import mark_events

    assert mark_events(rec, run_dir / "run.rrd", [(0.5, "verdict", "VERDICT settle")]) >= 8
    rec.flush()
    rec.disconnect()
    return path


def test_verdict_rrd_opens_with_the_runs_layout(faulted):
    verdict = _tiny_verdict_rrd(faulted.run_dir)
    ev = read_events(verdict)
    assert [(e.entity, e.level) for e in ev] == [("/events/verdict", "ERROR")]
    assert read_text(verdict, "/run/verdict").startswith("# FAIL")
    ours = read_blueprints(faulted.run_dir / "run.rrd")[-1]
    theirs = read_blueprints(verdict)[-1]
    key = sorted((v.name, v.kind, v.origin, v.contents) for v in ours)
    assert key == sorted((v.name, v.kind, v.origin, v.contents) for v in theirs)
    # its violation is marked on the plots at the run's values at 0.5 s
    from harness.record.reader import read_scalar_channel
    from harness.review.events import values_at

    # each criterion's markers in a series of their own (a legend names its series' last)
    t, angle = read_scalar_channel(verdict, "/markers/angle/verdict/settle")
    assert t == pytest.approx([0.5])
    t_run, a_run = read_scalar_channel(faulted.run_dir / "run.rrd", "/attitude/angle_deg")
    assert angle[0] == pytest.approx(a_run[np.searchsorted(t_run, 0.5 + 1e-9) - 1])
    assert values_at(faulted.run_dir / "run.rrd", [0.5])[0]["/attitude/angle_deg"] == angle[0]


def test_identify_rrd_spectrum_marks_every_mode_with_the_runs_layout(faulted, tmp_path):
    from harness.identification.windows import AnalysisWindow, identify_windows
    from harness.review.spectrum import write_identify_rrd

    fs = 500.0
    t = np.arange(0, 30, 1 / fs)
    modes = [(2.88, 0.05, 0.02), (13.3, 0.03, 0.01), (36.9, 0.02, 0.006)]
    a = sum(amp * np.exp(-z * w * t) * np.sin(w * np.sqrt(1 - z * z) * t)
            for w, z, amp in modes)
    a = a + np.random.default_rng(1).normal(0, 1e-4, len(t))
    result = identify_windows(t, a, [AnalysisWindow(0.0)])
    assert len(result.modes) == 3
    path = write_identify_rrd(faulted.run_dir / "identify.rrd", faulted.run_dir, result,
                              cfg={"run": {}})
    have = entities(path)
    # short legend names (the entity path is the legend), one per mode
    marks = sorted(e for e in have if e.startswith("/final/mode_"))
    assert marks == [f"/final/mode_{i}" for i in (1, 2, 3)]
    assert "/final/spectrum" in have and "/final/fft_peaks" in have
    assert max(len(e) for e in have if e.startswith("/final/")) <= 16
    # the modes view: undamped and damped frequency labelled, damping, 1 sigma
    text = read_text(path, "/identify/modes")
    assert "f: undamped natural frequency" in text and "fd: damped frequency" in text
    for i, (w, z, _) in enumerate(modes):
        block = text.split(f"**Mode {i + 1}** ")[1].split("**Mode")[0]
        f_hz = float(block.split("f = ")[1].split()[0])
        fd_hz = float(block.split("fd = ")[1].split()[0])
        assert f_hz == pytest.approx(w / (2 * np.pi), rel=0.01)
        assert fd_hz == pytest.approx(w * np.sqrt(1 - z * z) / (2 * np.pi), rel=0.01)
        assert fd_hz < f_hz and "+-" in block.split("f = ")[1].splitlines()[0]
        assert float(block.split("zeta = ")[1].split()[0].rstrip(",")) == \
            pytest.approx(z, rel=0.1)
    # every mode's marker its own colour, none the spectrum's
    from harness.review.spectrum import MODE_COLOURS, SPECTRUM_COLOUR

    assert len(set(MODE_COLOURS)) == len(MODE_COLOURS) and SPECTRUM_COLOUR not in MODE_COLOURS
    ours = read_blueprints(faulted.run_dir / "run.rrd")[-1]
    theirs = read_blueprints(path)[-1]
    assert sorted(v.name for v in ours) == sorted(v.name for v in theirs)


def test_modes_view_compares_with_the_model():
    from harness.review.spectrum import modes_markdown

    m = {"freq_hz": 1.0, "omega_rad_s": 2 * np.pi, "sigma_omega_rad_s": 0.01,
         "damping_ratio": 0.02, "sigma_damping": 0.001, "fft_peak_omega_rad_s": 6.28,
         "model_mode": 1, "model_omega_rad_s": 2 * np.pi * 1.02, "model_damping_ratio": 0.01,
         "source": {"experiment": "final free decay"}}
    text = modes_markdown([m, m, m], ["a note"])
    assert "(model mode 1: f = 1.0200 Hz, zeta = 0.0100)" in text
    assert "identified - model: f -1.96 %, zeta +100.00 %" in text
    assert "from: final free decay" in text and "- a note" in text
    # two lines a mode, the model and the difference among them, before the legend: three
    # modes fit the panel (a heading, seven lines a mode and the legend first needed a scroll)
    head = text.split("f: undamped natural frequency")[0].strip().splitlines()
    assert len(head) <= 2 + 2 * 3, head
    assert sum("identified - model" in line for line in head) == 3


def test_sweep_rrd_has_its_layout(tmp_path):
    from harness.studies.sweep_report import save_rrd

    lambdas = np.linspace(0.5, 1.5, 4)
    betas = np.array([0.6, 1.0])
    amps = np.random.default_rng(0).uniform(0.01, 1.0, (4, 2, 2))
    path = tmp_path / "sweep.rrd"
    save_rrd(path, "sweep-test", lambdas, betas, amps)
    have = entities(path)
    assert {"/sweep/curves/tip_accel_m_s2/beta_0.60", "/sweep/log10/tip_deflection_m/beta_1.00",
            "/sweep/map/tip_accel_m_s2", "/sweep/about"} <= have
    views = {v.name: v for v in read_blueprints(path)[-1]}
    curves = [v for v in views.values() if v.kind == "TimeSeries"]
    assert len(curves) == 4 and all("(" in v.name for v in curves)
    assert sum(v.kind == "Tensor" for v in views.values()) == 2
    assert "Sweep" in views


def test_sweep_rrd_shows_the_whole_range_one_colour_per_beta_and_scaled_maps(tmp_path):
    """The whole lambda range on screen (the resonance included), the maps with a colour
    scale, and each beta's colour the same in every plot."""
    from harness.review.reader import read_series_styles
    from harness.studies.sweep_report import save_plots, save_rrd, sweep_blueprint

    lambdas = np.linspace(0.3, 3.2, 30)
    betas = np.array([0.3, 0.6, 1.0])
    amps = np.random.default_rng(0).uniform(0.01, 1.0, (30, 3, 2))
    save_plots(tmp_path / "maps.png", tmp_path / "curves.png", lambdas, betas, amps, "hub_free")
    path = tmp_path / "sweep.rrd"
    save_rrd(path, "sweep-test", lambdas, betas, amps, maps_png=tmp_path / "maps.png")
    styles = read_series_styles(path)
    for b in ("0.30", "0.60", "1.00"):
        colours = {str(styles[f"/sweep/{k}/{o}/beta_{b}"]["colors"])
                   for k in ("curves", "log10") for o in ("tip_accel_m_s2", "tip_deflection_m")}
        assert len(colours) == 1, b  # one colour for a beta everywhere
    assert len({str(styles[f"/sweep/curves/tip_accel_m_s2/beta_{b}"]["colors"])
                for b in ("0.30", "0.60", "1.00")}) == 3
    assert "/sweep/maps" in entities(path)  # the maps with their colour bars
    views = {v.name: v for v in read_blueprints(path)[-1]}
    assert any(v.kind == "2D" and v.origin == "/sweep/maps" for v in views.values())
    for view in L.blueprint_views(sweep_blueprint(lambdas, True)):
        axis = getattr(view, "properties", {}).get("TimeAxis")
        if isinstance(view, rrb.TimeSeriesView):
            rng = axis.view_range.as_arrow_array().to_pylist()[0]
            assert rng["start"] <= 300 and rng["end"] >= 3200, view.name


def test_legend_goes_where_it_hides_no_curve():
    """A slew stopped at 12 s of 50: its angle rises in the left of the plot, so the legend
    must not sit at the left top (where it hid the curve in the viewer)."""
    t = np.arange(0, 12, 0.002)
    angle = 7.5 * (t / 12) ** 2
    cols = {"/attitude/angle_deg": angle, "/attitude/reference_deg": angle}
    ranges = L.channel_ranges(cols)
    corners = L.legend_corners(t, cols, 50.0, ranges)
    assert corners["angle"] in ("RightTop", "RightBottom")
    # a full-length slew to 20 deg holds at the top right: the bottom right is free
    t = np.arange(0, 50, 0.002)
    angle = 20 * np.clip(t / 25, 0, 1)
    cols = {"/attitude/angle_deg": angle}
    assert L.legend_corners(t, cols, 50.0, L.channel_ranges(cols))["angle"] == "RightBottom"


def test_plot_stats_in_blocks_match_the_whole_run():
    """Fed block by block (as a streaming recorder would) with bounded memory, the same
    ranges as the whole columns and a decimated copy that still spans the run."""
    rng = np.random.default_rng(2)
    t = np.arange(0, 100, 0.002)
    data = np.column_stack([np.sin(t), 1e-3 * rng.normal(size=len(t)), np.full(len(t), np.nan)])
    stats = L.PlotStats(["/attitude/angle_deg", "/attitude/error_deg", "/piezo/cmd_ch1_v"],
                        max_rows=1000)
    for k in range(0, len(t), 500):
        stats.add(t[k:k + 500], data[k:k + 500])
    whole = L.channel_ranges({"/attitude/angle_deg": data[:, 0],
                              "/attitude/error_deg": data[:, 1]})
    assert stats.ranges() == whole
    assert len(stats.t) <= 1000 and stats.t[0] == 0.0 and stats.t[-1] > 99.0
    assert np.all(np.diff(stats.t) > 0)
    assert set(stats.legends(100.0)) >= {"angle", "error"}


def test_judged_run_verdict_rrd_has_layout_events_and_markers(faulted, tmp_path):
    """harness judge's verdict.rrd (the verdict layer) carries run.rrd's layout, the
    verdict text, its violation as an event and a marker on the plots at its time."""
    import shutil

    from harness.testing import judge_run
    from harness.testing.judge import write_verdict

    run_dir = tmp_path / faulted.run_dir.name  # a copy: the fixture's verdict.rrd is ours
    shutil.copytree(faulted.run_dir, run_dir)
    (run_dir / "verdict.rrd").unlink(missing_ok=True)
    v = judge_run(run_dir)
    assert v.verdict == "ERROR"  # a fault the run did not expect
    write_verdict(v, run_dir)
    path = run_dir / "verdict.rrd"
    ev = [e for e in read_events(path) if e.entity == "/events/verdict"]
    fault_t = faulted.summary["faults"][0]["time_s"]
    assert ev and ev[0].time_s == pytest.approx(fault_t)
    assert read_text(path, "/run/verdict")
    assert {"/markers/angle/verdict/unexpected_fault",
            "/markers/tip/verdict/unexpected_fault"} <= entities(path)
    ours = read_blueprints(faulted.run_dir / "run.rrd")[-1]
    theirs = read_blueprints(path)[-1]
    assert sorted(v.name for v in ours) == sorted(v.name for v in theirs)


def test_verdict_lives_in_run_rrd_and_rejudging_replaces_it(faulted, tmp_path):
    """The verdict panel filled from run.rrd alone (without verdict.rrd), and a run stopped
    by an unexpected fault headlined by its cause, not a consequence. Judged, run.rrd holds the
    verdict (root cause first, failing criteria first, each with value, limit, margin and
    worst time), its violation as an event and marker, and the run's layout; re-judging
    replaces it, and every recorded sample stays."""
    import shutil

    from harness.record.reader import read_scalar_channel
    from harness.testing import judge_run
    from harness.testing.judge import write_verdict

    run_dir = tmp_path / faulted.run_dir.name
    shutil.copytree(faulted.run_dir, run_dir)
    rrd = run_dir / "run.rrd"
    before = read_scalar_channel(rrd, "/attitude/angle_deg")
    bus_before = read_scalar_channel(rrd, "/bus/hub_sensor/tlm/angle_rad")
    assert read_text(rrd, "/run/verdict") is None
    for _ in range(2):  # judged, then re-judged
        write_verdict(judge_run(run_dir), run_dir)
        text = read_text(rrd, "/run/verdict")
        assert text is not None
        head = text.splitlines()[0]
        fault = faulted.summary["faults"][0]
        assert head.startswith("# ERROR: unexpected fault hub_sensor: silent"), head
        assert f"{fault['time_s']:.3f} s" in head
        items = [ln for ln in text.splitlines() if ln.startswith("- **")]
        verdicts = [ln.split("**")[1] for ln in items]
        assert verdicts == sorted(verdicts, key=["ERROR", "FAIL", "MARGINAL", "NOT JUDGED",
                                                 "PASS"].index)
        assert "unexpected_fault" in items[0]  # the cause before its consequences
        final = next(ln for ln in items if " final_error:" in ln)
        # measured against where the run stopped, not where it was going: not judged
        assert final.startswith("- **NOT JUDGED** final_error") and "margin" not in final
        assert "limit |x| ≤ 0.1 deg" in final
        assert "not judged: a fault (hub_sensor: silent)" in text
        ev = [e for e in read_events(rrd) if e.entity == "/events/verdict"]
        assert len(ev) == 1 and ev[0].time_s == pytest.approx(fault["time_s"])
        # the unexpected fault is marked once, by the run's own fault marker
        assert "/markers/tip/fault" in entities(rrd)
        assert "/markers/tip/verdict" not in entities(rrd)
        names = {v.name for v in read_blueprints(rrd)[-1]}
        assert L.VERDICT_VIEW in names and L.PLOTS["tip"].title in names
        for (t0, v0), (t1, v1) in ((before, read_scalar_channel(rrd, "/attitude/angle_deg")),
                                   (bus_before,
                                    read_scalar_channel(rrd, "/bus/hub_sensor/tlm/angle_rad"))):
            assert np.array_equal(t0, t1) and np.array_equal(v0, v1)
    # a criterion's violation is marked on the plots at its worst sample
    from harness.review.verdict import write_into_run

    fail = {"name": "tip_quiet", "kind": "channel", "value": 0.03, "unit": "m_s2",
            "limit": {"max_abs_m_s2": 0.01}, "margin": -0.02, "verdict": "FAIL",
            "worst_time_s": 0.5, "message": "too much"}
    assert write_into_run(run_dir, {"verdict": "FAIL", "reason": "x", "criteria": [fail]})
    assert "/markers/tip/verdict/tip_quiet" in entities(rrd)
    assert [e.time_s for e in read_events(rrd) if e.entity == "/events/verdict"] == [0.5]


def test_baseline_comparison_draws_the_baseline_on_the_same_plot(faulted, tmp_path):
    """A baseline criterion's baseline channel is drawn on the judged channel's
    plot, on the run's time axis shifted as judged."""
    import shutil

    import yaml

    from harness.record.reader import read_scalar_channel
    from harness.testing import judge_run
    from harness.testing.judge import write_verdict

    run_dir = tmp_path / faulted.run_dir.name
    shutil.copytree(faulted.run_dir, run_dir)
    cfg_path = run_dir / "config.yaml"
    cfg = yaml.safe_load(cfg_path.read_text())
    cfg["run"]["expect"] = {"same_as_before": {
        "baseline": str(faulted.run_dir), "channel": "/attitude/error_deg",
        "tol_deg": 1e-6, "max_shift_s": 0.01, "applies_to_stopped": True}}
    cfg_path.write_text(yaml.safe_dump(cfg))
    v = judge_run(run_dir)
    [same] = [c for c in v.criteria if c.name == "same_as_before"]
    assert "time shift +0.000 s" in same.message
    write_verdict(v, run_dir)
    t0, x0 = read_scalar_channel(faulted.run_dir / "run.rrd", "/attitude/error_deg")
    t1, x1 = read_scalar_channel(run_dir / "run.rrd", "/baseline/attitude/error_deg")
    assert np.allclose(t0, t1) and np.array_equal(x0, x1)
    error_plot = next(w for w in read_blueprints(run_dir / "run.rrd")[-1]
                      if w.name == L.PLOTS["error"].title)
    assert "/baseline/attitude/error_deg" in error_plot.contents
    # a judged shift moves the baseline: its sample at t + shift sits at the run's t
    from harness.review.verdict import log_baselines

    shifted = tmp_path / "shifted.rrd"
    rec = rr.RecordingStream(APPLICATION_ID, recording_id="shifted")
    rec.save(str(shifted))
    assert log_baselines(rec, run_dir, {"criteria": [
        {"name": "same_as_before", "kind": "baseline",
         "message": "... time shift +0.010 s) within tolerance"}]}) == 1
    rec.flush()
    rec.disconnect()
    t2, x2 = read_scalar_channel(shifted, "/baseline/attitude/error_deg")
    assert np.allclose(t2, t0 - 0.010) and np.array_equal(x2, x0)


def test_verdict_is_not_appended_to_a_cut_recording(faulted, tmp_path):
    """A run.rrd cut short mid-message (SIGKILL) is left as it is; the verdict stays in
    verdict.json and verdict.rrd."""
    import shutil

    from harness.record.append import stream_end
    from harness.review.verdict import write_into_run
    from harness.testing import judge_run

    run_dir = tmp_path / faulted.run_dir.name
    shutil.copytree(faulted.run_dir, run_dir)
    rrd = run_dir / "run.rrd"
    verdict = judge_run(run_dir).to_dict()
    data = rrd.read_bytes()
    rrd.write_bytes(data[: len(data) - 100])
    assert stream_end(rrd) == "cut"
    assert not write_into_run(run_dir, verdict)
    assert rrd.read_bytes() == data[: len(data) - 100]


def test_realtime_bus_frames_at_their_receive_time(tmp_path):
    """On the real-time clock a frame sits at its own timestamp after the first SYNC: the
    SYNCs near their ticks (the clock's lateness), telemetry just after its SYNC."""
    from harness.record.reader import read_scalar_channel

    run = load_run("slew-rw", {"duration_s": 1.0})
    res = execute_run(run, out_dir=tmp_path, clock="realtime", show_progress=False)
    rrd = res.run_dir / "run.rrd"
    t, tick = read_scalar_channel(rrd, "/bus/harness/sync/tick")
    late = t - tick * run.dt_s
    assert late.min() == pytest.approx(0.0, abs=1e-6)  # against the clock's schedule
    assert np.all(np.diff(t) > 0)
    th, _ = read_scalar_channel(rrd, "/bus/hub_sensor/tlm/angle_rad")
    tr, rx_ms = read_scalar_channel(rrd, "/bus/hub_sensor/rx_after_sync_ms")
    assert len(th) == len(tr) > 0.5 * len(t)  # every frame has its receive offset
    assert np.all(rx_ms >= 0)  # a frame read after a later SYNC counts for its own tick
    assert np.median(rx_ms) < run.dt_s * 1e3  # telemetry comes within its tick
