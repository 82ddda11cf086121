"""Plots of a long run read in bounded memory: a channel's min/max envelope per time bucket,
equal to the brute-force minimum and maximum of every bucket; a short channel whole."""

from __future__ import annotations

import numpy as np
import rerun as rr

from harness.testing.judge import read_channels, read_envelopes


def _rrd(path, channels: dict[str, tuple[np.ndarray, np.ndarray]], block: int) -> None:
    rec = rr.RecordingStream("sgsrt-test", recording_id="envelope")
    rec.save(str(path))
    for name, (t, v) in channels.items():
        for i in range(0, len(t), block):  # several chunks, as the recorder's blocks
            rec.send_columns(name, indexes=[rr.TimeColumn("time", duration=t[i:i + block])],
                             columns=rr.Scalars.columns(scalars=v[i:i + block]))
    rec.flush()
    rec.disconnect()


def test_envelope_matches_every_buckets_extremes(tmp_path):
    rng = np.random.default_rng(3)
    t = np.arange(60_000) * 2e-3  # 120 s at 500 Hz
    v = np.sin(2 * np.pi * 0.3 * t) + 0.1 * rng.standard_normal(t.size)
    v[31_337] = 9.0  # one spike a plot must not lose
    v[40_000] = np.nan
    ts, vs = np.arange(500) * 0.01, rng.standard_normal(500)
    rrd = tmp_path / "run.rrd"
    _rrd(rrd, {"/long": (t, v), "/short": (ts, vs)}, block=777)
    buckets = 1000
    env = read_envelopes(rrd, {"/long", "/short", "/absent"}, t_end_s=120.0, buckets=buckets)
    assert set(env) == {"/long", "/short"}
    whole = read_channels(rrd, {"/short"})
    np.testing.assert_array_equal(env["/short"][1], whole["/short"][1])  # short: whole
    et, ev = env["/long"]
    assert len(et) == 2 * buckets and ev.max() == 9.0
    b = np.clip((t / (120.0 / buckets)).astype(int), 0, buckets - 1)
    for k in (0, 261, 500, 999):
        sel = v[b == k]
        assert ev[2 * k] == np.nanmin(sel) and ev[2 * k + 1] == np.nanmax(sel)
    # another chunking of the same samples gives the same envelope
    rrd2 = tmp_path / "run2.rrd"
    _rrd(rrd2, {"/long": (t, v)}, block=4096)
    np.testing.assert_array_equal(read_envelopes(rrd2, {"/long"}, 120.0, buckets)["/long"][1],
                                  ev)
