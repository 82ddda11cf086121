"""`harness export`: a run in MATLAB .mat, Parquet, ASAM MDF4 and CSV, read back with each
format's own reader (scipy.io, pyarrow, asammdf, the csv module) and compared with the
recording (run.rrd through the harness's reader, can.blf through python-can's layout);
bad input refused with exit 2, a missing library named with its pip command."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np
import pytest

from harness.cli import main
from harness.core.loop import CHANNELS
from harness.core.runs import load_run
from harness.core.session import execute_run
from harness.export.source import channel_blocks, channel_of, loop_channels
from harness.record.blf_frames import read_frames
from harness.record.reader import read_scalar_channels


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory) -> Path:
    """A 12 s lockstep slew with a few error frames on the bus (both CAN groups)."""
    out = tmp_path_factory.mktemp("export-run")
    run = load_run("slew-rw", {"duration_s": 12.0, "faults": [
        {"kind": "error_frames", "at_s": 1.0, "duration_s": 0.004, "value": 2}]})
    res = execute_run(run, out_dir=out, show_progress=False)
    from harness.testing import judge_run, write_verdict

    write_verdict(judge_run(res.run_dir), res.run_dir)
    return res.run_dir


@pytest.fixture(scope="module")
def recorded(run_dir):
    """The recording in SI as the export must give it: {exported name: values}, time, and
    can.blf's frames."""
    raw = read_scalar_channels(run_dir / "run.rrd", CHANNELS)
    t = raw[CHANNELS[0]][0]
    for e in CHANNELS:
        assert np.array_equal(raw[e][0], t)  # one row a tick for every channel
    values = dict(_si(e, raw[e][1]) for e in CHANNELS)
    frames = list(read_frames(run_dir / "can.blf"))
    return t, values, frames


def _si(entity: str, x: np.ndarray) -> tuple[str, np.ndarray]:
    """The exported name and SI values of a recorded channel, worked out here on their own
    (not with the export's table): degrees to radians, milliseconds to seconds."""
    name = entity.strip("/").replace("/", ".")
    for suffix, si, convert in (("_deg_s", "_rad_s", np.deg2rad), ("_deg", "_rad", np.deg2rad),
                                ("_ms", "_s", lambda v: v / 1000.0)):
        if name.endswith(suffix):
            return name[: -len(suffix)] + si, convert(x)
    return name, x


def _same(a, b) -> bool:
    """Equal, NaN where NaN, to the last bits of a float64 (a product by pi/180 may be
    rounded either way)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    return a.shape == b.shape and bool(np.allclose(a, b, rtol=4e-16, atol=0, equal_nan=True))


def _export(run_dir: Path, fmt: str, out: Path) -> list[Path]:
    assert main(["export", str(run_dir), "--to", fmt, "--out", str(out)]) == 0
    return sorted(out.iterdir())


def test_names_and_units_are_si():
    c = channel_of("/attitude/angle_deg")
    assert (c.name, c.unit, c.factor) == ("attitude.angle_rad", "rad", math.pi / 180)
    def of(e):
        c = channel_of(e)
        return c.name, c.unit, c.factor

    assert of("/attitude/rate_deg_s") == ("attitude.rate_rad_s", "rad/s", math.pi / 180)
    assert of("/timing/lateness_ms") == ("timing.lateness_s", "s", 1e-3)
    assert of("/tip/accel_m_s2") == ("tip.accel_m_s2", "m/s^2", 1.0)
    assert of("/thrusters/firings") == ("thrusters.firings", "", 1.0)
    assert channel_of("/wheel/torque_n_m").ident == "wheel_torque_n_m"


def test_channels_stream_block_by_block(run_dir):
    """The reader hands on the recorder's blocks (2500 rows in lockstep), never the whole
    run: what keeps memory flat (benchmarks/bench_export_memory.py measures it)."""
    sizes = [len(t) for t, _ in channel_blocks(run_dir / "run.rrd", loop_channels())]
    assert len(sizes) >= 3 and max(sizes) <= 2 * 2500 and sum(sizes) == 6001


def _frames_equal(recorded_frames, host_time_s, can_id, error, length, data, tx=None,
                  time_s=None, t=None):
    """The frames as can.blf has them (host time stamps, direction); ``time_s`` on the run's
    time: each SYNC at its tick's row time ``t``."""
    assert len(can_id) == len(recorded_frames)
    for k in (0, 1, len(can_id) // 2, len(can_id) - 1):
        fr = recorded_frames[k]
        assert int(can_id[k]) == fr[1] and bool(error[k]) == fr[4]
        assert int(length[k]) == len(fr[7])
        assert bytes(np.asarray(data[k], dtype=np.uint8)[: len(fr[7])]) == fr[7]
        assert host_time_s[k] == fr[0]
    ids = np.array([f[1] for f in recorded_frames])
    assert np.array_equal(np.asarray(can_id, dtype=np.int64), ids)
    assert int(np.sum(error)) == sum(f[4] for f in recorded_frames) > 0
    if tx is not None:
        assert np.array_equal(np.asarray(tx, dtype=bool), [not f[5] for f in recorded_frames])
    if time_s is not None:
        time_s = np.asarray(time_s, dtype=float)
        assert np.all(np.diff(time_s) >= 0) and time_s[0] >= 0
        sync = time_s[(ids == 128) & ~np.asarray(error, dtype=bool)]  # not an error frame
        assert np.array_equal(sync, t[: len(sync)]) and len(sync) == len(t)


def test_mat_reads_back_with_scipy(run_dir, recorded, tmp_path):
    from scipy.io import loadmat

    t, values, frames = recorded
    (path,) = _export(run_dir, "mat", tmp_path)
    m = loadmat(path, simplify_cells=True)
    assert np.array_equal(m["time_s"], t)
    for name, v in values.items():
        assert _same(m[name.replace(".", "_")], v), name
    meta = m["metadata"]
    assert meta["channels"]["attitude_angle_rad"]["unit"] == "rad"
    assert meta["channels"]["attitude_angle_rad"]["source"] == "/attitude/angle_deg"
    assert json.loads(meta["summary_json"]) == json.loads((run_dir / "summary.json").read_text())
    assert json.loads(meta["verdict_json"])["verdict"] == \
        json.loads((run_dir / "verdict.json").read_text())["verdict"]
    assert json.loads(meta["config_json"])["run"]["name"] == "slew-rw"
    assert m["can_data"].shape == (len(frames), 8)
    _frames_equal(frames, m["can_host_time_s"], m["can_id"], m["can_error_frame"],
                  m["can_length"], m["can_data"], m["can_tx"], m["can_time_s"], t)


def test_parquet_reads_back_with_pyarrow(run_dir, recorded, tmp_path):
    import pyarrow.parquet as pq

    t, values, frames = recorded
    paths = _export(run_dir, "parquet", tmp_path)
    assert [p.name.split(".", 2)[-1] for p in paths] == ["can.parquet", "parquet"]
    main_file = next(p for p in paths if not p.name.endswith(".can.parquet"))
    table = pq.read_table(main_file)
    assert np.array_equal(table["time_s"].to_numpy(), t)
    for name, v in values.items():
        assert _same(table[name].to_numpy(), v), name
    field = table.schema.field("timing.lateness_s")
    assert field.metadata == {b"unit": b"s", b"source": b"/timing/lateness_ms"}
    meta = json.loads(pq.ParquetFile(main_file).metadata.metadata[b"sgsrt"])
    assert meta["summary"] == json.loads((run_dir / "summary.json").read_text())
    assert meta["verdict"]["verdict"] in ("PASS", "MARGINAL", "FAIL", "ERROR")
    fr = pq.read_table(next(p for p in paths if p.name.endswith(".can.parquet")))
    data = np.frombuffer(fr["data"].combine_chunks().buffers()[1], np.uint8).reshape(-1, 8)
    _frames_equal(frames, fr["host_time_s"].to_numpy(), fr["can_id"].to_numpy(),
                  fr["error_frame"].to_numpy(), fr["length"].to_numpy(), data,
                  fr["tx"].to_numpy(), fr["time_s"].to_numpy(), t)


def test_mf4_reads_back_with_asammdf(run_dir, recorded, tmp_path):
    from asammdf import MDF

    t, values, frames = recorded
    (path,) = _export(run_dir, "mf4", tmp_path)
    with MDF(path) as mdf:
        for name, v in values.items():
            s = mdf.get(name)
            assert np.array_equal(s.timestamps, t) and _same(s.samples, v), name
        assert mdf.get("attitude.angle_rad").unit == "rad"
        assert mdf.get("wheel.torque_n_m").unit == "N m"
        atts = {mdf.extract_attachment(i)[1].name: mdf.extract_attachment(i)[0]
                for i in range(len(mdf.attachments))}
        assert json.loads(atts["summary.json"]) == json.loads(
            (run_dir / "summary.json").read_text())
        assert json.loads(atts["config.json"])["run"]["name"] == "slew-rw"
        data = mdf.get("CAN_DataFrame")
        err = mdf.get("CAN_ErrorFrame")
        host = mdf.get("can.data_frame.host_time_s")
        start = mdf.header.start_time.timestamp()
        assert data.attachment[1].name == "sgsrt.dbc"  # the rig's DBC, for decoding
        assert b"BO_ 128 SYNC" in data.attachment[0]
        groups = {g.channel_group.acq_name for g in mdf.groups}
        assert {"channels", "CAN"} <= groups
    # both groups together, in time order, are the log's frames
    ok = [f for f in frames if not f[4]]
    bad = [f for f in frames if f[4]]
    d = data.samples
    assert np.array_equal(d["CAN_DataFrame.ID"], [f[1] for f in ok])
    assert np.array_equal(d["CAN_DataFrame.DataLength"], [len(f[7]) for f in ok])
    for k in (0, len(ok) // 2, len(ok) - 1):
        n = len(ok[k][7])
        assert bytes(d["CAN_DataFrame.DataBytes"][k][:n]) == ok[k][7]
        assert host.samples[k] == ok[k][0]  # the host's time stamp, record for record
    # the run's time: each SYNC at its tick's row
    sync = data.timestamps[d["CAN_DataFrame.ID"] == 128]
    assert np.array_equal(sync, t) and np.array_equal(host.timestamps, data.timestamps)
    assert np.array_equal(d["CAN_DataFrame.Dir"], [0 if f[5] else 1 for f in ok])  # 1: Tx
    assert len(err.samples) == len(bad) > 0
    # a bus-logging reader that knows only the ASAM layout: python-can's own MF4 reader
    import can

    back = [(m.arbitration_id, bytes(m.data), m.timestamp, m.is_rx)
            for m in can.MF4Reader(str(path)) if not m.is_error_frame]
    assert [(i, d, rx) for i, d, _, rx in back] == [(f[1], f[7], f[5]) for f in ok]
    # absolute time: the header's start (the host time of run time 0) + the run time
    assert back[-1][2] == pytest.approx(start + data.timestamps[-1], abs=1e-5)


def test_csv_reads_back_with_the_csv_module(run_dir, recorded, tmp_path):
    t, values, frames = recorded
    paths = _export(run_dir, "csv", tmp_path)
    by_end = {p.name.split(".", 2)[-1]: p for p in paths}
    assert set(by_end) == {"csv", "can.csv", "metadata.json"}
    with by_end["csv"].open(newline="") as f:
        rows = list(csv.reader(f))
    header, body = rows[0], np.array(rows[1:], dtype=float)
    assert header[0] == "time_s" and np.array_equal(body[:, 0], t)
    for i, name in enumerate(header[1:], start=1):
        assert _same(body[:, i], values[name]), name
    meta = json.loads(by_end["metadata.json"].read_text())
    assert {c["name"]: c["unit"] for c in meta["channels"]}["attitude.rate_rad_s"] == "rad/s"
    assert meta["summary"]["run"] == "slew-rw" and meta["can_frames"] == len(frames)
    with by_end["can.csv"].open(newline="") as f:
        fr = list(csv.DictReader(f))
    data = np.array([[int(r[f"byte{i}"]) for i in range(8)] for r in fr])
    _frames_equal(frames, [float(r["host_time_s"]) for r in fr],
                  [int(r["can_id"]) for r in fr], [int(r["error_frame"]) for r in fr],
                  [int(r["length"]) for r in fr], data, [int(r["tx"]) for r in fr],
                  [float(r["time_s"]) for r in fr], t)


def test_bad_input_is_refused_naming_the_file(run_dir, tmp_path, capsys):
    import shutil

    assert main(["export", str(tmp_path / "nothing"), "--to", "csv"]) == 2
    assert "not a directory" in capsys.readouterr().err
    bad = Path(shutil.copytree(run_dir, tmp_path / "bad"))
    (bad / "summary.json").write_text("[1, 2")
    assert main(["export", str(bad), "--to", "csv", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "summary.json: not readable JSON" in err and "Traceback" not in err
    (bad / "summary.json").write_text(json.dumps({"rate_hz": 0}))
    assert main(["export", str(bad), "--to", "csv", "--out", str(tmp_path / "o")]) == 2
    assert "rate_hz" in capsys.readouterr().err
    (bad / "config.yaml").unlink()
    assert main(["export", str(bad), "--to", "csv"]) == 2
    assert "config.yaml: no such file" in capsys.readouterr().err
    afile = tmp_path / "afile"
    afile.write_text("x")
    assert main(["export", str(run_dir), "--to", "csv", "--out", str(afile)]) == 2
    assert "not a directory" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()  # refused before anything was written


def test_a_missing_library_names_the_pip_command(run_dir, tmp_path, monkeypatch, capsys):
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name == "asammdf" else real(name, *a))
    assert main(["export", str(run_dir), "--to", "mf4", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "needs asammdf" in err and "pip install 'sgsrt-harness[export]'" in err
    assert not list(tmp_path.iterdir())  # nothing written


def test_a_cut_recording_exports_what_it_holds_and_garbage_is_refused(run_dir, tmp_path,
                                                                      capsys):
    import shutil

    import pyarrow.parquet as pq

    cut = Path(shutil.copytree(run_dir, tmp_path / "cut"))
    rrd = cut / "run.rrd"
    with rrd.open("r+b") as f:  # a run killed mid-write: its recording ends mid-message
        f.truncate(rrd.stat().st_size // 2)
    assert main(["export", str(cut), "--to", "parquet", "--out", str(tmp_path / "a")]) == 0
    rows = pq.read_table(tmp_path / "a" / "cut.parquet").num_rows
    assert 0 < rows < 6001
    rrd.write_bytes(bytes(range(256)) * 12)
    assert main(["export", str(cut), "--to", "csv", "--out", str(tmp_path / "b")]) == 2
    err = capsys.readouterr().err
    assert "run.rrd: cannot read" in err and "Traceback" not in err
    assert not list((tmp_path / "b").iterdir())  # no partial file left
