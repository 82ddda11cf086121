"""Reading a run's recording back (Rerun 0.41 ``rerun.chunk.RrdReader``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from rerun.chunk import RrdReader


def read_scalar_channel(rrd: Path, entity: str) -> tuple[np.ndarray, np.ndarray]:
    """(time s, values) of a scalar channel recorded on the ``time`` timeline."""
    times: list[np.ndarray] = []
    values: list[np.ndarray] = []
    for chunk in RrdReader(rrd).stream().to_chunks():
        if chunk.entity_path != entity or chunk.is_static or "time" not in chunk.timeline_names:
            continue
        batch = chunk.to_record_batch()
        t = batch.column("time").cast("int64").to_numpy(zero_copy_only=False) * 1e-9
        v = np.array([x[0] if isinstance(x, list) else x
                      for x in batch.column("Scalars:scalars").to_pylist()], dtype=float)
        times.append(t)
        values.append(v)
    if not times:
        raise ValueError(f"{rrd}: no scalar channel {entity!r} on the 'time' timeline")
    t = np.concatenate(times)
    v = np.concatenate(values)
    order = np.argsort(t, kind="stable")
    return t[order], v[order]
