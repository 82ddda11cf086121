"""The bench's own health in a real-time run's verdict: timing criteria and whose the lost
time was.

Every run on the real-time clock is judged, beside its own criteria, by three budget
criteria on the loop's timing (``timing_criteria``), with limits from the run file's
``realtime:`` section (``max_overruns_percent``, ``max_lateness_p99_period_percent``,
``max_missing_held_percent``; docs/criteria.md says why the defaults are what they are). A
run beyond one of them is INCONCLUSIVE: the bench did not hold its time, so neither a pass
nor a FAIL of what was tested can be trusted. Lockstep runs have nothing to hold and get
none.

``attribute`` says whose the lost time was, with the rules the harness already applies:

- an overrun episode (consecutive overrun ticks) is the **host**'s when its first tick
  started at least half a period late (``harness.core.loop.HELD_FRACTION``: the loop slept
  until its deadline and the host woke it late), else the **harness**'s (that tick's own
  work ran past the next deadline); the ticks after the first only catch up;
- telemetry frames missing in ticks the loop held, by the rig process's SYNC timing
  (``harness.core.session.attribute_missing``, in summary.json's ``frames``): the **host**'s
  when it delayed or preempted the rig's answer, the **device**'s when the rig answered after
  the loop stopped waiting, the **harness**'s when the answer was sent in time and not read
  (transport or loop). Without the rig's timing (a rig as a thread, the lab's rig) those
  frames cannot be split: "device or harness".

Reads run.rrd's ``/timing/lateness_ms`` and ``/timing/work_ms`` block by block (memory
bounded by a block, whatever the run's length).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from harness.testing.criteria import Criterion, parse_criterion
from harness.testing.measures import BENCH_MEASURES

LATENESS, WORK = "/timing/lateness_ms", "/timing/work_ms"

DEFAULT_LIMITS = {"max_overruns_percent": 1.0, "max_lateness_p99_period_percent": 50.0,
                  "max_missing_held_percent": 1.0}
"""The run file's defaults (``harness.core.runs.RUN_SCHEMA`` realtime), for a config.yaml
written before these keys existed."""

CRITERIA = (
    ("bench_overruns", "timing.overruns_percent", "max_overruns_percent",
     "overruns (ticks whose work ended after the next tick's deadline) as a share of the "
     "ticks; beyond {limit:g} % the loop did not keep its rate ('harness rt-check' calls a "
     "host beyond 1 % CANNOT HOLD)"),
    ("bench_lateness", "timing.lateness_p99_period_percent", "max_lateness_p99_period_percent",
     "the loop's lateness p99 (how late a tick started after its deadline) as a share of the "
     "period; beyond {limit:g} % one tick in a hundred was not held (a tick half a period late "
     "is not held: the loop's own rule, and 'harness rt-check''s CANNOT HOLD line)"),
    ("bench_telemetry", "timing.missing_held_percent", "max_missing_held_percent",
     "telemetry frames missing in ticks the loop held, as a share of the frames due; beyond "
     "{limit:g} % the controller ran on stale inputs more often than the overrun limit allows "
     "its outputs to be late"),
)
"""(criterion name, measure, run-file limit key, why)."""


def timing_criteria(run_cfg: Mapping[str, Any], taken: set[str]) -> list[Criterion]:
    """The bench's timing criteria with the run file's limits (``run_cfg``: config.yaml's
    ``run``); a name the run's own criteria already use is left to them."""
    rt = run_cfg.get("realtime") if isinstance(run_cfg.get("realtime"), Mapping) else {}
    out = []
    for name, measure, key, why in CRITERIA:
        if name in taken:
            continue
        limit = rt.get(key, DEFAULT_LIMITS[key])
        if isinstance(limit, bool) or not isinstance(limit, int | float):
            limit = DEFAULT_LIMITS[key]
        out.append(parse_criterion(
            name, {"measure": measure, "max_percent": float(limit), "budget": True,
                   "why": why.format(limit=float(limit))},
            "the run's realtime limits", f"realtime.{key}", known_measures=BENCH_MEASURES,
            channels=()))
    return out


def is_realtime(summary: Mapping[str, Any]) -> bool:
    return summary.get("clock") == "realtime" and not summary.get("dry_run")


# ----------------------------------------------------------------------------- attribution
@dataclass
class Episodes:
    """Overrun episodes found tick by tick: who began each, and the worst of each side."""

    dt_ms: float
    held_ms: float
    prev_overrun: bool = False
    episodes: dict[str, int] = field(default_factory=lambda: {"host": 0, "harness": 0})
    overruns: dict[str, int] = field(default_factory=lambda: {"host": 0, "harness": 0})
    current: str = ""
    # the largest first tick of each side: (lateness or work ms, time s)
    worst: dict[str, tuple[float, float]] = field(default_factory=dict)

    def feed(self, t: np.ndarray, late: np.ndarray, work: np.ndarray) -> None:
        over = (late + work) > self.dt_ms
        if not over.any():
            self.prev_overrun = False
            return
        before = np.concatenate(([self.prev_overrun], over[:-1]))
        starts = np.flatnonzero(over & ~before)
        idx = np.flatnonzero(over)
        # each overrun tick belongs to the episode that began at the last start before it
        if self.prev_overrun:
            first = idx[idx < (starts[0] if len(starts) else len(over))]
            self.overruns[self.current] += len(first) if self.current else 0
        for k, s in enumerate(starts):
            who = "host" if late[s] >= self.held_ms else "harness"
            self.current = who
            self.episodes[who] += 1
            end = starts[k + 1] if k + 1 < len(starts) else len(over)
            self.overruns[who] += int(np.count_nonzero(over[s:end]))
            size = float(late[s] if who == "host" else work[s])
            if size > self.worst.get(who, (-1.0, 0.0))[0]:
                self.worst[who] = (size, float(t[s]))
        self.prev_overrun = bool(over[-1])


def _aligned(blocks: Iterator[tuple[str, np.ndarray, np.ndarray]]
             ) -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """(time, lateness, work) of the ticks both channels recorded, in time order, from
    their blocks (each channel's in time order; one channel may run a few blocks ahead)."""
    pend: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for entity, t, x in blocks:
        if entity not in (LATENESS, WORK) or not len(t):
            continue
        old = pend.get(entity)
        pend[entity] = (t, x) if old is None else (np.concatenate((old[0], t)),
                                                   np.concatenate((old[1], x)))
        if not all(len(pend.get(e, ((),))[0]) for e in (LATENESS, WORK)):
            continue
        (tl, xl), (tw, xw) = pend[LATENESS], pend[WORK]
        common, il, iw = np.intersect1d(tl, tw, assume_unique=True, return_indices=True)
        if len(common):
            yield common, xl[il], xw[iw]
        # what one channel has beyond the other's last time waits for the other's next block
        upto = min(float(tl[-1]), float(tw[-1]))
        pend[LATENESS] = (tl[tl > upto], xl[tl > upto])
        pend[WORK] = (tw[tw > upto], xw[tw > upto])


def attribute(summary: Mapping[str, Any],
              blocks: Callable[[list[str]], Iterator[tuple[str, np.ndarray, np.ndarray]]] | None
              ) -> dict[str, Any]:
    """Whose the lost time was (module docstring): overrun episodes and overruns by who began
    them (from the recording's per-tick lateness and work, when ``blocks`` can read it), and
    the telemetry frames missing in ticks the loop held by summary.json's split."""
    from harness.core.loop import HELD_FRACTION  # lazy: the verdict layer sits above core

    out: dict[str, Any] = {}
    rate = summary.get("rate_hz")
    if blocks is not None and isinstance(rate, int | float) and rate > 0 \
            and summary.get("overruns"):
        dt_ms = 1e3 / float(rate)
        ep = Episodes(dt_ms, HELD_FRACTION * dt_ms)
        try:
            for t, late, work in _aligned(blocks([LATENESS, WORK])):
                ep.feed(t, late, work)
            out["overruns"] = {"episodes": ep.episodes, "ticks": ep.overruns,
                               "worst_first_tick": {k: {"ms": v[0], "time_s": v[1]}
                                                    for k, v in ep.worst.items()}}
        except Exception as exc:  # noqa: BLE001 - the recording unreadable: said, not raised
            out["overruns"] = {"unreadable": f"{type(exc).__name__}: {exc}"}
    f = summary.get("frames") if isinstance(summary.get("frames"), Mapping) else {}
    held = int(f.get("missing_in_ticks_on_time") or 0)
    if held:
        host = int(f.get("missing_in_ticks_host_delayed") or 0)
        if summary.get("virtual_rig_timing"):
            device = int(f.get("missing_rig_answered_after_window") or 0)
            out["frames"] = {"host": host, "device": device,
                             "harness": max(0, held - host - device)}
        else:
            out["frames"] = {"host": host, "device or harness": max(0, held - host)}
    return out


def describe(attr: Mapping[str, Any]) -> str:
    """One sentence: whose the lost time was, largest share first."""
    parts: list[tuple[int, str]] = []
    ov = attr.get("overruns") or {}
    if "unreadable" in ov:
        parts.append((0, f"overruns not attributed (run.rrd: {ov['unreadable']})"))
    for who in ("host", "harness"):
        n = (ov.get("ticks") or {}).get(who, 0)
        if not n:
            continue
        eps = ov["episodes"][who]
        w = ov["worst_first_tick"].get(who)
        how = (f"the loop woke {w['ms']:.1f} ms late at t = {w['time_s']:.3f} s" if who == "host"
               else f"a tick's work took {w['ms']:.1f} ms at t = {w['time_s']:.3f} s") if w else ""
        parts.append((n, f"{who}: {n} overruns in {eps} episode{'s' if eps != 1 else ''}"
                      + (f" (worst: {how})" if how else "")))
    for who, n in (attr.get("frames") or {}).items():
        if n:
            what = {"host": "delayed or preempted the rig's answer",
                    "device": "the rig answered after the loop stopped waiting",
                    "harness": "sent in time, not read in the tick",
                    "device or harness": "no rig timing to split them"}[who]
            parts.append((n, f"{who}: {n} telemetry frames missing in held ticks ({what})"))
    if not parts:
        return "time lost by: nobody the harness can name (no overrun episode, no frame " \
               "missing in a held tick)"
    parts.sort(key=lambda p: -p[0])
    return "time lost by " + "; ".join(p[1] for p in parts)
