"""``scalar_values``: a recorded channel's list-per-row column as one float a row, the flat
fast path and the row-by-row form giving the same values."""

from __future__ import annotations

import numpy as np
import pyarrow as pa
import pytest

from harness.record.reader import scalar_values


def _row_by_row(column: pa.Array) -> np.ndarray:
    return np.array([np.nan if not x else x[0] for x in column.to_pylist()], dtype=float)


@pytest.mark.parametrize("rows", [
    [[1.0], [2.5], [-3.0]],            # the usual chunk: the flat path
    [[1.0], None, [3.0]],              # a null row
    [[1.0], [], [3.0]],                # an empty row
    [[1.0, 9.0], [], [3.0]],           # as many values as rows, not one per row
    [[1.0, 9.0], [2.0]],               # more values than rows
    [],
])
def test_scalar_values_is_each_rows_first_value(rows) -> None:
    column = pa.array(rows, type=pa.list_(pa.float64()))
    got = scalar_values(column)
    assert got.dtype == float and len(got) == len(rows)
    np.testing.assert_array_equal(got, _row_by_row(column))


def test_a_recorded_channel_reads_back_through_the_flat_path(tmp_path, monkeypatch) -> None:
    from harness.record.reader import read_scalar_channels
    from harness.record.recording import Recorder

    rec = Recorder(tmp_path / "r.rrd", ["/a", "/b"], 0, "t", block_rows=7)
    for i in range(20):
        row = rec.row(i * 0.01)
        row[:] = (i, -i)
        rec.commit()
    rec.close()
    import harness.record.reader as reader

    seen = []
    real = reader._first_of_each_row
    monkeypatch.setattr(reader, "_first_of_each_row", lambda c: seen.append(1) or real(c))
    out = read_scalar_channels(tmp_path / "r.rrd")
    np.testing.assert_array_equal(out["/a"][1], np.arange(20.0))
    np.testing.assert_array_equal(out["/b"][1], -np.arange(20.0))
    assert not seen, "the usual channel went row by row"
