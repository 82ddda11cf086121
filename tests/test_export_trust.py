"""`harness export` under a hostile tester: the frames on the channels' time axis (the
recording's own bus view placing them alike), the harness's frames as Tx in MDF4 with the
rig's DBC embedded, two exports into one folder at once, memory that does not grow with a
recording lacking a channel, and bad input ending in one line with exit 2."""

from __future__ import annotations

import csv
import json
import shutil
import threading
import tracemalloc
from pathlib import Path

import can
import numpy as np
import pytest
import rerun as rr

from harness.cli import main
from harness.core.loop import CHANNELS
from harness.export import export_run
from harness.export import source as export_source
from harness.export.source import channel_blocks, channel_of, loop_channels
from harness.export.writers import temporary_beside
from harness.record.blf_frames import read_frames
from harness.record.reader import iter_chunks, read_scalar_channel


def _run(out: Path, *args: str) -> Path:
    """A slew-rw run made through the command line (its verdict does not matter here: a
    6 s slew ends before it settles)."""
    assert main(["run", "slew-rw", "--out", str(out), "--quiet", *args]) != 2
    (run_dir,) = out.glob("*-slew-rw")
    assert (run_dir / "summary.json").is_file()
    return run_dir


@pytest.fixture(scope="module")
def lockstep_50s(tmp_path_factory) -> Path:
    """slew-rw as it ships, 50 s in lockstep (about 7 s of wall time)."""
    return _run(tmp_path_factory.mktemp("lockstep50"))


@pytest.fixture(scope="module")
def canopen_run(tmp_path_factory) -> Path:
    """CANopen: the SYNC's counter wraps at 240 (3000 ticks: it wraps 12 times)."""
    return _run(tmp_path_factory.mktemp("canopen"), "--rig", "sgsrt-canopen",
                "--duration-s", "6")


@pytest.fixture(scope="module")
def dbc_run(tmp_path_factory) -> Path:
    """A vendor DBC (drivers/sgsrt_dbc2.dbc): its own SYNC frame, 29-bit ids."""
    return _run(tmp_path_factory.mktemp("dbc2"), "--rig", "sgsrt-dbc2", "--duration-s", "6")


@pytest.fixture(scope="module")
def realtime_run(tmp_path_factory) -> Path:
    return _run(tmp_path_factory.mktemp("realtime"), "--clock", "realtime",
                "--duration-s", "2")


def _parquet(run_dir: Path, out: Path):
    import pyarrow.parquet as pq

    assert main(["export", str(run_dir), "--to", "parquet", "--out", str(out)]) == 0
    name = export_source.safe_name(run_dir.name)
    return pq.read_table(out / f"{name}.parquet"), pq.read_table(out / f"{name}.can.parquet")


def _bus_view_matches(run_dir: Path, frames) -> None:
    """The hub sensor's telemetry frames sit where run.rrd's bus view put them."""
    view = next(c.entity_path for c in iter_chunks(run_dir / "run.rrd", content="/bus/**")
                if c.entity_path.startswith("/bus/hub_sensor/tlm/"))
    t_view, _ = read_scalar_channel(run_dir / "run.rrd", view)
    t, ids = frames["time_s"].to_numpy(), frames["can_id"].to_numpy()
    matching = [i for i in np.unique(ids) if np.array_equal(np.sort(t[ids == i]), t_view)]
    assert len(matching) == 1, matching


def test_a_50s_lockstep_runs_frames_and_channels_share_one_time_axis(lockstep_50s, tmp_path):
    """Frames once carried the host's clock (channels 0-50 s, frames 0-3.9 s). Now each SYNC is at
    its tick's channel time, to the bit, and every frame within the run's 50 s."""
    channels, frames = _parquet(lockstep_50s, tmp_path)
    t = channels["time_s"].to_numpy()
    assert t[0] == 0.0 and t[-1] == 50.0 and len(t) == 25001
    ft, ids = frames["time_s"].to_numpy(), frames["can_id"].to_numpy()
    err = frames["error_frame"].to_numpy()
    assert ft.min() == 0.0 and 49.99 < ft.max() < 50.0 + 0.002  # the last tick's answers
    assert np.all(np.diff(ft) >= 0)
    host = frames["host_time_s"].to_numpy()
    assert host[-1] - host[0] < 45  # lockstep: the host's clock is not the run's
    sync = (ids == 128) & ~err
    data = np.frombuffer(frames["data"].combine_chunks().buffers()[1], np.uint8).reshape(-1, 8)
    ticks = data[sync, :4].copy().view("<u4").ravel()
    assert np.array_equal(ft[sync], t[ticks])  # a SYNC's time is its tick's channel time
    # the host time stamps are can.blf's, unchanged
    blf = [f[0] for f in read_frames(lockstep_50s / "can.blf")]
    assert np.array_equal(host, blf)
    meta = json.loads(__import__("pyarrow.parquet", fromlist=["x"]).ParquetFile(
        tmp_path / f"{lockstep_50s.name}.can.parquet").metadata.metadata[b"sgsrt"])
    assert meta["clock"] == "lockstep" and meta["host_time_origin_s"] == host[sync][0]
    _bus_view_matches(lockstep_50s, frames)


def test_canopen_syncs_unwrap_onto_the_ticks(canopen_run, tmp_path):
    channels, frames = _parquet(canopen_run, tmp_path)
    t = channels["time_s"].to_numpy()
    ft, ids = frames["time_s"].to_numpy(), frames["can_id"].to_numpy()
    sync = (ids == 0x80) & ~frames["error_frame"].to_numpy()
    assert sync.sum() == len(t) == 3001  # the counter wrapped 12 times: every tick found
    assert np.array_equal(ft[sync], t)
    _bus_view_matches(canopen_run, frames)


def test_a_real_time_run_keeps_the_host_clock_less_its_start(realtime_run, tmp_path):
    """Real time: a frame at its host time stamp minus when tick 0 was due (the bus view's
    rule), so a late SYNC shows late: never before its tick."""
    channels, frames = _parquet(realtime_run, tmp_path)
    t = channels["time_s"].to_numpy()
    ft, ids = frames["time_s"].to_numpy(), frames["can_id"].to_numpy()
    host = frames["host_time_s"].to_numpy()
    sync = (ids == 128) & ~frames["error_frame"].to_numpy()
    assert np.all(ft[sync] >= t[: sync.sum()] - 1e-6)  # a POSIX time stamp: 0.24 us steps
    keep = ft > 0
    assert np.allclose(host[keep] - ft[keep], (host - ft)[keep][0], atol=1e-6)
    _bus_view_matches(realtime_run, frames)


def test_mf4_marks_the_harness_frames_tx_and_embeds_the_rigs_dbc(dbc_run, tmp_path):
    from asammdf import MDF

    assert main(["export", str(dbc_run), "--to", "mf4", "--out", str(tmp_path)]) == 0
    (path,) = tmp_path.glob("*.mf4")
    recorded = list(read_frames(dbc_run / "can.blf"))
    ok = [f for f in recorded if not f[4]]
    dbc = Path(__file__).resolve().parents[1] / "drivers" / "sgsrt_dbc2.dbc"
    with MDF(path) as mdf:
        frames = mdf.get("CAN_DataFrame")
        d = frames.samples
        assert np.array_equal(d["CAN_DataFrame.Dir"], [0 if f[5] else 1 for f in ok])
        tx_ids = set(d["CAN_DataFrame.ID"][d["CAN_DataFrame.Dir"] == 1].tolist())
        rx_ids = set(d["CAN_DataFrame.ID"][d["CAN_DataFrame.Dir"] == 0].tolist())
        assert tx_ids and rx_ids and not tx_ids & rx_ids  # commands out, telemetry in
        # the DBC the bus-logging groups reference, and every file of the binding embedded
        assert frames.attachment[1].name == "sgsrt_dbc2.dbc"
        assert frames.attachment[0] == dbc.read_bytes()
        names = [mdf.extract_attachment(i)[1].name for i in range(len(mdf.attachments))]
        assert "sgsrt_dbc2.dbc" in names and "summary.json" in names
        # asammdf decodes the frames by it: the harness's sync counter counts the ticks
        decoded = mdf.extract_bus_logging({"CAN": [(dbc, 0)]})
        sync = decoded.get("MST_SyncCnt")
        channels = mdf.get("attitude.angle_rad")
        assert len(sync.samples) == len(channels.timestamps)
        assert np.array_equal(sync.timestamps, channels.timestamps)
    # python-can's reader of the ASAM layout: Tx as is_rx False
    back = [m.is_rx for m in can.MF4Reader(str(path)) if not m.is_error_frame]
    assert back == [f[5] for f in ok]


def test_an_eds_bound_rig_has_its_eds_files_embedded(canopen_run, tmp_path):
    from asammdf import MDF

    assert main(["export", str(canopen_run), "--to", "mf4", "--out", str(tmp_path)]) == 0
    (path,) = tmp_path.glob("*.mf4")
    with MDF(path) as mdf:
        names = [mdf.extract_attachment(i)[1].name for i in range(len(mdf.attachments))]
        d = mdf.get("CAN_DataFrame").samples
        assert set(np.unique(d["CAN_DataFrame.Dir"]).tolist()) == {0, 1}
    assert any(n.lower().endswith(".eds") for n in names), names


def test_a_rig_binding_two_dbcs_gets_one_merged_dbc_with_the_frames_it_uses():
    """Two DBCs defining one id (sgsrt's SYNC and the vendor's MST_Sync, both 0x80): the
    merged DBC keeps the message the binding uses."""
    import cantools

    from harness.export.writers import _bus_attachment

    drivers = Path(__file__).resolve().parents[1] / "drivers"
    got = _bus_attachment([drivers / "sgsrt.dbc", drivers / "sgsrt_dbc2.dbc"],
                          {((128, False), "SYNC")})
    assert got is not None and got[1] == "rig.dbc"
    db = cantools.database.load_string(got[0].decode(), database_format="dbc")
    names = {m.name for m in db.messages}
    assert db.get_message_by_frame_id(128).name == "SYNC" and "MST_Sync" not in names
    assert {"HUB_TLM", "HUB_Tlm"} <= names


# ------------------------------------------------------------------------ two at once
def test_temporary_files_are_each_exports_own(tmp_path):
    final = tmp_path / "run.mf4"
    a, b = temporary_beside(final), temporary_beside(final)
    assert a != b and a.is_file() and b.is_file() and a.suffix == ".mf4"
    assert a.name.startswith(".run.mf4.") and ".partial" in a.name


@pytest.mark.parametrize("fmt", ["parquet", "mf4", "mat", "csv"])
def test_two_exports_into_one_folder_at_once_both_complete(dbc_run, tmp_path, fmt):
    """Two exports of the run into one --out at the same moment (threads): each writes its
    own temporary files and renames them, so both succeed and what is left is complete."""
    out = tmp_path / "out"
    start = threading.Barrier(2)
    results: list[object] = []

    def one() -> None:
        start.wait()
        try:
            results.append(export_run(dbc_run, fmt, out))
        except BaseException as exc:  # noqa: BLE001 - reported below
            results.append(exc)

    threads = [threading.Thread(target=one) for _ in range(2)]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    assert all(isinstance(r, list) for r in results), results
    assert results[0] == results[1]
    left = sorted(p.name for p in out.iterdir())
    assert left == sorted(p.name for p in results[0])  # no temporary file left behind
    n = 3001
    if fmt == "parquet":
        import pyarrow.parquet as pq

        assert pq.read_table(out / f"{dbc_run.name}.parquet").num_rows == n
    elif fmt == "mf4":
        from asammdf import MDF

        with MDF(out / f"{dbc_run.name}.mf4") as mdf:
            assert len(mdf.get("attitude.angle_rad").samples) == n
    elif fmt == "mat":
        from scipy.io import loadmat

        assert loadmat(out / f"{dbc_run.name}.mat")["time_s"].size == n
    else:
        assert len((out / f"{dbc_run.name}.csv").read_text().splitlines()) == n + 1


# ------------------------------------------------------------------------ memory
def _recording(folder: Path, seconds: float, missing: tuple[str, ...] = (),
               late: tuple[str, ...] = (), stop: tuple[str, float] | None = None,
               rate: float = 500.0, block: int = 2500) -> Path:
    """A run folder with a generated run.rrd of the loop's channels (blocks of ``block``
    rows as the recorder writes them): ``missing`` never recorded (a run from before the
    channel existed), ``late`` written after all the others (a merged recording), ``stop``
    a channel recorded only up to a time. Values: sin(tick x 1e-3 + len(entity))."""
    folder.mkdir(parents=True)
    rec = rr.RecordingStream("sgsrt-test")
    rec.save(str(folder / "run.rrd"))
    n = int(seconds * rate) + 1

    def send(e: str, k0: int, k1: int) -> None:
        k = np.arange(k0, k1)
        rec.send_columns(e, indexes=[rr.TimeColumn("time", duration=k * (1.0 / rate))],
                         columns=rr.Scalars.columns(scalars=np.sin(k * 1e-3 + len(e))))

    for k0 in range(0, n, block):
        for e in CHANNELS:
            if e in missing or e in late or (stop and e == stop[0] and k0 >= stop[1] * rate):
                continue
            send(e, k0, min(n, k0 + block))
    for e in late:
        for k0 in range(0, n, block):
            send(e, k0, min(n, k0 + block))
    rec.flush()
    rec.disconnect()
    (folder / "config.yaml").write_text(json.dumps({"run": {
        "name": "generated", "rate_hz": rate, "duration_s": seconds, "clock": "lockstep"}}))
    with can.BLFWriter(str(folder / "can.blf")) as w:
        for k in range(3):
            w.on_message_received(can.Message(
                timestamp=1000.0 + k * 1e-4, arbitration_id=128, is_extended_id=False,
                data=k.to_bytes(4, "little"), is_rx=False))
    return folder


def _peak_mb(fn) -> float:
    tracemalloc.start()
    try:
        fn()
        return tracemalloc.get_traced_memory()[1] / 1e6
    finally:
        tracemalloc.stop()


def test_a_recording_without_a_channel_exports_in_bounded_memory(tmp_path):
    """A run recorded before a channel existed: the export held every row until the end
    (about 1.2 GB per recorded hour; the reader's peak on these recordings was 93 MB at
    60 s and 196 MB at 480 s). Now the export's peak is the same for 40 s and for 320 s
    (8 times the rows)."""
    lacking = CHANNELS[3]
    peaks = {}
    for seconds in (40, 320):
        run_dir = _recording(tmp_path / f"r{seconds}", seconds, missing=(lacking,))
        out = tmp_path / f"o{seconds}"
        peaks[seconds] = _peak_mb(lambda d=run_dir, o=out: export_run(d, "csv", o))
        with (out / f"r{seconds}.csv").open(newline="") as f:
            rows = list(csv.reader(f))
        col = rows[0].index(channel_of(lacking).name)
        assert len(rows) == seconds * 500 + 2
        assert all(r[col] == "nan" for r in rows[1:])  # not recorded
    assert peaks[320] < peaks[40] + 2.0 and peaks[320] < 20.0, peaks


@pytest.mark.parametrize("layout", ["stop", "late"])
def test_every_layout_streams_with_bounded_memory(tmp_path, monkeypatch, layout):
    """A channel that stops halfway, channels written after all the others (read ahead by
    a second reader once the rows held pass the bound): the rows are right and the peak
    does not grow with the length."""
    monkeypatch.setattr(export_source, "MAX_HELD_SAMPLES", 50_000)
    kw = ({"stop": (CHANNELS[2], 20.0)} if layout == "stop" else
          {"late": (CHANNELS[5], CHANNELS[7]), "missing": (CHANNELS[0],)})
    peaks = {}
    for seconds in (40, 320):
        run_dir = _recording(tmp_path / f"r{seconds}", seconds, **kw)
        counted: list[int] = []

        def read(run_dir: Path = run_dir, counted: list[int] = counted) -> None:
            rows, last = 0, -1.0
            for t, cols in channel_blocks(run_dir / "run.rrd", loop_channels()):
                assert np.all(np.diff(t) > 0) and t[0] > last  # in time order, no row twice
                last = t[-1]
                k = np.round(t * 500).astype(int)
                for e in CHANNELS:
                    x, want = cols[e], np.sin(k * 1e-3 + len(e)) * channel_of(e).factor
                    got = ~np.isnan(x)
                    assert np.allclose(x[got], want[got]), e
                    if e in kw.get("missing", ()):
                        assert not got.any()
                    elif layout == "stop" and e == CHANNELS[2]:
                        assert np.array_equal(got, t < 20.0)
                    else:
                        assert got.all(), e
                rows += len(t)
            counted.append(rows)

        peaks[seconds] = _peak_mb(read)
        assert counted == [seconds * 500 + 1]
    assert peaks[320] < peaks[40] + 2.0 and peaks[320] < 20.0, peaks


# ------------------------------------------------------------------------ bad input
def _one_line(capsys, *words: str) -> str:
    err = capsys.readouterr().err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    for w in words:
        assert w in err, err
    return err


@pytest.mark.parametrize("length", [236, 245, 255])
def test_a_run_folder_named_up_to_255_characters_exports_under_a_shortened_name(
        dbc_run, tmp_path, capsys, length):
    """Every file name (with a temporary file's ending) stays within 255 bytes: the name is
    cut and ends in a hash of the whole; the metadata keeps the folder's name."""
    long = Path(shutil.copytree(dbc_run, tmp_path / ("r" * length)))
    out = tmp_path / "out"
    assert main(["export", str(long), "--to", "csv", "--out", str(out)]) == 0
    names = sorted(p.name for p in out.iterdir())
    assert len(names) == 3 and all(len(n.encode()) <= 255 - 26 for n in names)
    meta = json.loads(next(out.glob("*.metadata.json")).read_text())
    assert meta["run_folder"] == long.name
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["out", long.name])


def test_a_summary_nested_987_levels_is_refused_in_one_line(dbc_run, tmp_path, capsys):
    bad = Path(shutil.copytree(dbc_run, tmp_path / "bad"))
    out = tmp_path / "out"
    (bad / "summary.json").write_text('{"a":' * 987 + "1" + "}" * 987)
    assert main(["export", str(bad), "--to", "mat", "--out", str(out)]) == 2
    _one_line(capsys, "summary.json", "nested")
    (bad / "summary.json").write_text((dbc_run / "summary.json").read_text())
    (bad / "verdict.json").write_text('{"a":' + "[" * 986 + "]" * 986 + "}")
    assert main(["export", str(bad), "--to", "csv", "--out", str(out)]) == 2
    _one_line(capsys, "verdict.json", "nested")
    (bad / "verdict.json").unlink()
    (bad / "config.yaml").write_text("run: {rate_hz: 500, duration_s: 6}\nx: "
                                     + "[" * 100 + "]" * 100 + "\n")
    assert main(["export", str(bad), "--to", "csv", "--out", str(out)]) == 2
    _one_line(capsys, "config.yaml", "nested")
    assert not out.exists()


def test_other_bad_input_ends_in_one_line_with_exit_2(dbc_run, tmp_path, capsys):
    bad = Path(shutil.copytree(dbc_run, tmp_path / "bad"))
    out = tmp_path / "out"
    # --out too long for the file system
    assert main(["export", str(bad), "--to", "csv", "--out", str(tmp_path / ("o" * 300))]) == 2
    _one_line(capsys, "too long")
    # a rig that is not a rig file's data
    cfg = (bad / "config.yaml").read_text()
    (bad / "config.yaml").write_text(cfg.replace("\nrig:\n", "\nrig: 5\nold_rig:\n", 1))
    assert main(["export", str(bad), "--to", "csv", "--out", str(out)]) == 2
    _one_line(capsys, "config.yaml", "rig")
    (bad / "config.yaml").write_text(cfg)
    # a clock that is neither
    summary = json.loads((bad / "summary.json").read_text())
    (bad / "summary.json").write_text(json.dumps({**summary, "clock": "sundial"}))
    assert main(["export", str(bad), "--to", "csv", "--out", str(out)]) == 2
    _one_line(capsys, "summary.json", "clock")
    (bad / "summary.json").write_text(json.dumps(summary))
    # the rig's DBC gone (its SYNC frame is what puts the frames on the run's time)
    cfg = (bad / "config.yaml").read_text().replace("sgsrt_dbc2.dbc", "gone.dbc")
    (bad / "config.yaml").write_text(cfg)
    assert main(["export", str(bad), "--to", "csv", "--out", str(out)]) == 2
    _one_line(capsys, "config.yaml", "gone.dbc")
    assert not out.exists()


@pytest.mark.parametrize("fmt", ["mat", "mf4"])
def test_a_folder_name_not_utf8_or_with_control_characters_exports(dbc_run, tmp_path, fmt):
    """Rerun opens only text paths (read through /proc/self/fd), MDF4's XML and MATLAB's
    UTF-8 take no such name (kept with escapes)."""
    import os

    odd = Path(os.fsdecode(bytes(tmp_path) + b"/run\xff\x01name"))
    shutil.copytree(dbc_run, odd)
    out = tmp_path / "out"
    assert main(["export", str(odd), "--to", fmt, "--out", str(out)]) == 0
    (path,) = out.iterdir()
    assert path.name == f"run__name.{fmt}"
    if fmt == "mat":
        from scipy.io import loadmat

        assert loadmat(path, simplify_cells=True)["metadata"]["run_folder"] == \
            "run\\xff\\x01name"
    else:
        from asammdf import MDF

        with MDF(path) as mdf:
            assert "run\\xff\\x01name" in mdf.header.comment


def test_a_cut_recording_writes_nothing_outside_the_output_folder(dbc_run, tmp_path,
                                                                 monkeypatch):
    """A run.rrd cut short is read from a copy of its complete part inside --out (the
    reader's own copy would go to the system's temporary folder), removed at the end."""
    import tempfile

    tmp = tmp_path / "system-tmp"
    tmp.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(tmp))
    cut = Path(shutil.copytree(dbc_run, tmp_path / "cut"))
    rrd = cut / "run.rrd"
    with rrd.open("r+b") as f:
        f.truncate(rrd.stat().st_size // 2)
    out = tmp_path / "out"
    paths = export_run(cut, "mf4", out)
    assert sorted(out.iterdir()) == sorted(paths) and not list(tmp.iterdir())
