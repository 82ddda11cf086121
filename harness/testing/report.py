"""A suite's report: ``results.json`` (machine-readable), ``report.md`` and ``report.html``
(one self-contained page) in the suite's output folder.

Per test: the verdict and its reason, every criterion's value against its limit and margin,
for a run a plot of each checked channel (read back from its run.rrd) with the criterion's
band shaded over its window, and relative links to run.rrd, can.blf, verdict.json and the
run's folder. Plots are PNGs drawn by matplotlib and embedded as base64, so the page needs
nothing beside it (the links need the run folders next to it).
"""

from __future__ import annotations

import base64
import datetime as dt
import html
import io
import json
import math
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np

from harness.testing.checks import worst
from harness.testing.outcome import exit_code

OVERVIEW = ("/attitude/angle_deg", "/tip/accel_m_s2")
COLORS = {"PASS": "#1a7f37", "MARGINAL": "#9a6700", "INCONCLUSIVE": "#0550ae",
          "FAIL": "#cf222e", "ERROR": "#8250df",
          "SKIPPED": "#6e7781", "NO CRITERIA": "#bc4c00", "NOT JUDGED": "#6e7781"}


def _fmt(v: Any) -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        return "nan" if math.isnan(v) else f"{v:.5g}"
    if isinstance(v, dict):
        return ", ".join(f"{k} {_fmt(x)}" for k, x in v.items())
    return str(v)


def channel_specs(run_dir: Path, criteria_results: list[dict[str, Any]]
                  ) -> list[dict[str, Any]]:
    """The run's channel criteria (verdict layer): channel, band (lo, hi) and window."""
    from harness.record.run_folder import load_run_folder
    from harness.record.summary_file import read_summary
    from harness.testing.evaluate import window_mask
    from harness.testing.judge import criteria_of

    # read as every reader of a run folder reads it: a damaged file is named (ValueError)
    cfg = load_run_folder(run_dir).config
    summary, _ = read_summary(run_dir / "summary.json")
    verdicts = {c["name"]: c for c in criteria_results}
    out = []
    for c in criteria_of(run_dir, cfg)[0]:
        if c.kind not in ("channel", "settles", "baseline"):
            continue
        if criteria_results and (c.name not in verdicts
                                 or verdicts[c.name].get("verdict") == "NOT JUDGED"):
            continue  # not judged (a fault test judges only its fault expectations)
        lim = c.limit
        if c.kind == "channel":
            lo = -lim["max_abs"] if "max_abs" in lim else lim.get("min")
            hi = lim["max_abs"] if "max_abs" in lim else lim.get("max")
        elif c.kind == "settles":
            lo = c.params["center"] - c.params["band"]
            hi = c.params["center"] + c.params["band"]
        else:
            lo = hi = None
        spec = {"name": c.name, "channel": c.target, "unit": c.unit if c.kind != "settles"
                else c.params["channel_unit"], "lo": lo, "hi": hi, "reduce": c.reduce,
                "kind": c.kind, "window": c.window.describe(),
                "verdict": verdicts.get(c.name, {}).get("verdict"),
                "worst_time_s": verdicts.get(c.name, {}).get("worst_time_s"),
                "value": verdicts.get(c.name, {}).get("value"),
                "window_fn": (lambda t, w=c.window: window_mask(t, w, summary))}
        if c.kind == "baseline":
            spec["baseline"] = c.params["baseline"]
        out.append(spec)
    return out


FIGSIZE = (11.0, 3.4)  # inches at DPI: 1100 px wide, shown at the page's full width
DPI = 100
LABEL_PT = 10


def _png(fig: Any) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI)
    import matplotlib.pyplot as plt

    plt.close(fig)
    return base64.b64encode(buf.getvalue()).decode("ascii")


def _shade_band(ax: Any, s: dict[str, Any], t0: float, t1: float, v: np.ndarray) -> None:
    """The criterion's band over its window. For ``reduce: each`` the band bounds every
    sample; for rms / mean / final it bounds that one number, drawn as a thick line."""
    lo, hi = s["lo"], s["hi"]
    if lo is None and hi is None:
        return
    reduce = s.get("reduce") or "each"
    # the criterion's own value (judged on every sample) when the verdict has it: the plot's
    # samples may be a long run's envelope (read_envelopes)
    known = s.get("value") if isinstance(s.get("value"), (int, float)) else None
    if reduce == "rms":
        value = known if known is not None else float(np.sqrt(np.nanmean(v ** 2)))
        lo = 0.0 if lo is None else lo
    elif reduce == "std":
        value = known if known is not None else float(np.nanstd(v))
        lo = 0.0 if lo is None else lo
    elif reduce == "mean":
        value = known if known is not None else float(np.nanmean(v))
    elif reduce == "final":
        value = known if known is not None else float(v[-1])
    else:
        value = None
    # the axis stays on the data (a settling error of 0.006 deg drawn on a +-0.1 deg band
    # was a flat line); a band edge beyond it is named in the legend
    y_lo, y_hi = ax.get_ylim()
    draw_lo = max(lo, y_lo) if lo is not None else y_lo
    draw_hi = min(hi, y_hi) if hi is not None else y_hi
    what = "band" if reduce == "each" else f"band of the {reduce}"
    off = [f"{y:.4g}" for y in (lo, hi) if y is not None and not y_lo <= y <= y_hi]
    label = f"{what} ({s['window']})" + (f"; edge {', '.join(off)} off the axis" if off else "")
    if draw_hi > draw_lo:
        ax.fill_between([t0, t1], [draw_lo, draw_lo], [draw_hi, draw_hi], color="#2da44e",
                        alpha=0.25, zorder=3, label=label)
    else:
        ax.plot([], [], color="#2da44e", lw=6, alpha=0.25, label=label)
    for y in (lo, hi):
        if y is not None and y_lo <= y <= y_hi:
            ax.hlines(y, t0, t1, colors="#2da44e", lw=0.8)
    if value is not None:
        ax.hlines(value, t0, t1, colors="#cf222e" if s["verdict"] in ("FAIL", "ERROR")
                  else "#1f2328", lw=2.0, label=f"{reduce} {value:.4g}")
    ax.set_ylim(y_lo, y_hi)


def run_plots(run_dir: Path, criteria_results: list[dict[str, Any]]) -> list[dict[str, str]]:
    """[{title, png (base64)}]: each checked channel with its band over its window; the
    angle and tip acceleration when no channel is checked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from harness.testing.judge import read_envelopes

    rrd = run_dir / "run.rrd"
    if not rrd.is_file():
        return []
    try:
        specs = channel_specs(run_dir, criteria_results)
    except (OSError, ValueError, KeyError) as exc:
        specs = []
        note = f"criteria not readable: {exc}"
    else:
        note = ""
    # each channel whole for a short run, its min/max envelope for a long one: memory
    # bounded whatever the run's length (a 24-hour soak run has 43 million rows a channel)
    t_end = _run_end_s(run_dir)
    data = read_envelopes(rrd, {s["channel"] for s in specs} | set(OVERVIEW), t_end)
    plots = []
    for s in specs:
        if s["channel"] not in data:
            continue
        t, v = data[s["channel"]]
        fig, ax = plt.subplots(figsize=FIGSIZE)
        ax.plot(t, v, lw=0.7, color="#0969da", label=channel_label(s["channel"]))
        _data_ylim(ax, v)
        try:
            mask, _ = s["window_fn"](t)
        except Exception:  # noqa: BLE001 - e.g. the window's event never happened
            mask = np.zeros_like(t, dtype=bool)
        if mask.any():
            t0, t1 = float(t[mask][0]), float(t[mask][-1])
            ax.axvspan(t0, t1, color="#eaeef2", alpha=0.35, zorder=0)
            _shade_band(ax, s, t0, t1, v[mask])
        if s["kind"] == "baseline":
            try:
                bt, bv = read_envelopes(Path(s["baseline"]) / "run.rrd" if Path(
                    s["baseline"]).is_dir() else Path(s["baseline"]), {s["channel"]},
                    t_end)[s["channel"]]
                ax.plot(bt, bv, lw=0.8, color="#8c959f", label="baseline")
            except Exception:  # noqa: BLE001 - the baseline may be on another machine
                pass
        if s["worst_time_s"] is not None:
            ax.axvline(s["worst_time_s"], color=COLORS.get(s["verdict"] or "", "k"), lw=0.8,
                       ls="--", label="worst")
        ax.set_xlabel("time (s)", fontsize=LABEL_PT)
        ax.set_ylabel(channel_label(s["channel"], unit=True), fontsize=LABEL_PT)
        ax.set_title(f"{s['name']}: {channel_label(s['channel'])} ({s['verdict']})",
                     fontsize=LABEL_PT + 1)
        _fault_marks(ax, run_dir)
        ax.legend(fontsize=LABEL_PT - 1, loc="best")
        ax.grid(alpha=0.3)
        fig.tight_layout()
        plots.append({"title": f"{s['name']}: {s['channel']}", "png": _png(fig)})
    if not plots:
        chans = [c for c in OVERVIEW if c in data]
        if chans:
            fig, axes = plt.subplots(len(chans), 1, figsize=(FIGSIZE[0], 2.6 * len(chans)),
                                     sharex=True, squeeze=False)
            marked = False
            for ax, c in zip(axes[:, 0], chans, strict=True):
                ax.plot(*data[c], lw=0.8, color="#0969da", label=channel_label(c))
                _data_ylim(ax, data[c][1])
                ax.set_ylabel(channel_label(c, unit=True), fontsize=LABEL_PT)
                marked = _fault_marks(ax, run_dir) or marked
                ax.legend(fontsize=LABEL_PT - 1, loc="best")
                ax.grid(alpha=0.3)
            axes[-1, 0].set_xlabel("time (s)", fontsize=LABEL_PT)
            title = ("fault test: the injection and its detection" if marked
                     else "no channel criterion: overview")
            axes[0, 0].set_title(title + (f" ({note})" if note else ""),
                                 fontsize=LABEL_PT + 1)
            fig.tight_layout()
            plots.append({"title": title, "png": _png(fig)})
    return plots


def frf_figure(run_dir: Path) -> str | None:
    """The run's Bode plot (frf.png, written by ``harness frf`` or by an ``frf:``
    criterion) as an embedded figure with its caption, else None."""
    png = run_dir / "frf.png"
    if not png.is_file():
        return None
    data = base64.b64encode(png.read_bytes()).decode("ascii")
    caption = ("frequency response (harness frf): |H| with its 1-sigma band, the rig "
               "model dashed, the modal fit; phase; coherence with 0.9 marked. frf.rrd "
               "holds the same for the Rerun viewer")
    return (f"<figure><img alt='{html.escape(caption)}' src='data:image/png;base64,{data}'>"
            f"<figcaption>{html.escape(caption)}</figcaption></figure>")


def scalar_bounds(limit: Any) -> tuple[float | None, float | None]:
    """A scalar criterion's pass band (lo, hi) from its limit as written (``max_abs_deg``,
    ``max_n_m``, ``min_s``, ``equals_count``); (None, None) without a numeric one."""
    lo = hi = None
    if not isinstance(limit, dict):
        return lo, hi
    for k, v in limit.items():
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
            continue
        if k.startswith("max_abs_"):
            lo, hi = -float(v), float(v)
        elif k.startswith("equals_"):
            lo = hi = float(v)
        elif k.startswith("max_"):
            hi = float(v)
        elif k.startswith("min_"):
            lo = float(v)
    return lo, hi


def scalar_plot(criteria: list[dict[str, Any]]) -> dict[str, str] | None:
    """{title, png}: each scalar criterion with a number and a numeric limit, one row each
    in its own unit: the pass band (green), its edges and the value (coloured by verdict);
    failing first. None when no criterion has both."""
    from harness.review.units import unit_text
    from harness.review.verdict import ordered

    rows = []
    for c in ordered(criteria):
        v = c.get("value")
        if c.get("kind") != "scalar" or isinstance(v, bool) or not isinstance(v, int | float) \
                or not math.isfinite(v):
            continue
        lo, hi = scalar_bounds(c.get("limit"))
        if lo is None and hi is None:
            continue
        rows.append((c, float(v), lo, hi))
    if not rows:
        return None
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(rows), 1, figsize=(FIGSIZE[0], 0.55 + 0.75 * len(rows)),
                             squeeze=False)
    for ax, (c, v, lo, hi) in zip(axes[:, 0], rows, strict=True):
        ends = [x for x in (v, lo, hi) if x is not None]
        a, b = min(ends), max(ends)
        span = (b - a) or (abs(b) or 1.0)
        left, right = a - 0.15 * span, b + 0.15 * span
        ax.axvspan(left if lo is None else lo, right if hi is None else hi,
                   color="#2da44e", alpha=0.25)
        for edge in (lo, hi):
            if edge is not None:
                ax.axvline(edge, color="#2da44e", lw=1.0)
        ax.plot([v], [0], "o", ms=9, color=COLORS.get(str(c.get("verdict")), "#1f2328"))
        ax.set_xlim(left, right)
        ax.set_yticks([])
        unit = unit_text(str(c.get("unit") or ""))
        ax.set_ylabel(f"{c.get('name')}\n{c.get('verdict')}", rotation=0, ha="right",
                      va="center", fontsize=LABEL_PT - 1)
        ax.set_xlabel(f"{c.get('target') or c.get('name')} ({unit or 'no unit'}): value "
                      f"{v:.4g}", fontsize=LABEL_PT - 1, labelpad=1)
        ax.tick_params(axis="x", labelsize=LABEL_PT - 2)
        ax.grid(axis="x", alpha=0.3)
    axes[0, 0].set_title("scalar criteria: value (dot) against its limit (green: passes)",
                         fontsize=LABEL_PT + 1)
    fig.tight_layout()
    return {"title": "scalar criteria: value against its limit", "png": _png(fig)}


def channel_label(channel: str, unit: bool = False) -> str:
    """``/tip/accel_m_s2`` -> ``tip acceleration`` (with ``unit``: ``... (m/s²)``)."""
    from harness.review.names import series_name, strip_unit
    from harness.review.units import split_unit, unit_text

    name = series_name(channel)
    if not unit:
        return name
    last = channel.rsplit("/", 1)[-1]
    u = unit_text(split_unit(last)[1]) if strip_unit(last) != last else ""
    return f"{name} ({u})" if u else name


def _data_ylim(ax: Any, v: Any) -> None:
    """The y axis on the data, with a small margin."""
    a = np.asarray(v, dtype=float)
    a = a[np.isfinite(a)]
    if not len(a):
        return
    lo, hi = float(a.min()), float(a.max())
    pad = 0.08 * (hi - lo) if hi > lo else (abs(hi) * 0.1 or 1.0)
    ax.set_ylim(lo - pad, hi + pad)


def _fault_marks(ax: Any, run_dir: Path) -> bool:
    """The run's injected faults and the faults it detected as vertical lines, named in
    the legend; whether there were any."""
    try:
        summary = json.loads((run_dir / "summary.json").read_text())
    except (OSError, ValueError):
        return False
    marked = False
    for f in summary.get("injected_faults") or []:
        if isinstance(f, dict) and isinstance(f.get("at_s"), int | float):
            ax.axvline(f["at_s"], color="#9a6700", lw=1.2, ls=":",
                       label=f"injected {f.get('kind')}"
                       + (f" on {f['device']}" if f.get("device") else "")
                       + f" at {f['at_s']:.3f} s")
            marked = True
    for f in summary.get("faults") or []:
        if isinstance(f, dict) and isinstance(f.get("time_s"), int | float):
            ax.axvline(f["time_s"], color="#cf222e", lw=1.2, ls="--",
                       label=f"detected {f.get('device')}: {f.get('kind')} at "
                       f"{f['time_s']:.3f} s")
            marked = True
    return marked


def _run_end_s(run_dir: Path) -> float:
    """The run's simulated length from its summary (its run file's duration otherwise)."""
    try:
        summary = json.loads((run_dir / "summary.json").read_text())
        return float(summary.get("simulated_time_s") or summary.get("duration_s") or 0.0)
    except (OSError, ValueError):
        return 0.0


RUN_FILES = ("run.rrd", "identify.rrd", "frf.rrd", "verdict.rrd", "can.blf", "verdict.json",
             "summary.json", "config.yaml", "layout.json", "frf.json", "frf.png")


def run_files(out_dir: Path, run_dir: str) -> list[str]:
    """The files of a run folder that exist (relative names), in ``RUN_FILES`` order."""
    return [f for f in RUN_FILES if (out_dir / run_dir / f).is_file()]


def open_command(out_dir: Path, run_dir: str) -> str:
    """The one command that opens a run's recordings together in the viewer (run.rrd holds
    the verdict once judged; verdict.rrd only when it could not be added there)."""
    folder = out_dir / run_dir
    files = [f for f in ("run.rrd", "identify.rrd") if (folder / f).is_file()]
    try:
        appended = "run_rrd_bytes" in json.loads((folder / "layout.json").read_text())
    except (OSError, ValueError, TypeError):
        appended = False
    if not appended and (folder / "verdict.rrd").is_file():
        files.append("verdict.rrd")
    return "rerun " + " ".join(f"{run_dir}/{f}" for f in files) if files else ""


def _pcts(p: Any) -> str:
    return "/".join(_fmt(p.get(k)) for k in ("p50", "p99", "max")) if isinstance(p, dict) \
        else "-"


def timing_line(out_dir: Path, run_dir: str) -> str | None:
    """A run's timing in one line: the loop's lateness beside what the frames' own time
    stamps say on the wire (SYNC period jitter, the slowest device's answer after SYNC, the
    command's margin before the next SYNC), or what the bus could not measure. None for a
    run without a readable summary."""
    try:
        s = json.loads((out_dir / run_dir / "summary.json").read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(s, dict):
        return None
    line = f"loop lateness p50/p99/max {_pcts(s.get('lateness_ms'))} ms"
    w = s.get("wire_timing")
    if not isinstance(w, dict):
        return line
    jitter, answers = w.get("sync_period_jitter_ms"), w.get("answer_latency_ms") or {}
    margin = w.get("command_margin_ms")
    if jitter is None and not answers and margin is None:
        return f"{line}; on the wire: not measured ({_fmt(w.get('note'))})"
    parts = [f"on the wire ({_fmt(w.get('source'))} time stamps, SYNC sent by "
             f"{_fmt(w.get('sync_sent_by'))}): SYNC jitter p50/p99/max {_pcts(jitter)} ms"]
    if answers:
        slowest = max(answers, key=lambda d: (answers[d] or {}).get("p99") or 0.0)
        parts.append(f"slowest answer after SYNC {slowest} p50/p99/max "
                     f"{_pcts(answers[slowest])} ms")
    if isinstance(margin, dict):
        parts.append(f"command margin before the next SYNC min {_fmt(margin.get('min'))} ms, "
                     f"{_fmt(margin.get('commands_after_next_sync'))} after it")
    return f"{line}; " + ", ".join(parts)


def _counts(records: list[dict[str, Any]]) -> dict[str, int]:
    return dict(Counter(r["verdict"] for r in records))


def write_reports(out_dir: Path, records: list[dict[str, Any]], *, not_run: list[str],
                  suites: list[Any], engine: str, bus: str | None,
                  preflight: dict[str, Any] | None, refused: str | None,
                  wall_s: float, interrupted: bool = False) -> dict[str, Any]:
    out_dir.mkdir(parents=True, exist_ok=True)
    verdicts = [r["verdict"] for r in records
                if r["verdict"] != "SKIPPED" and r.get("reported", True)]
    doc = {
        "suites": [{"name": s.name, "description": s.description, "source": str(s.source)}
                   for s in suites],
        "created_utc": dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
        "engine": engine, "bus": bus or "virtual (each run's own)",
        "wall_time_s": round(wall_s, 2),
        "verdict": worst(verdicts) if verdicts else ("ERROR" if refused else "PASS"),
        "exit_code": 130 if interrupted else (
            exit_code(records) if records else (2 if refused else 0)),
        "interrupted": interrupted,
        "counts": _counts(records), "refused": refused, "preflight": preflight,
        "rigs": rigs_of(records), "not_run": not_run, "tests": records,
    }
    from harness.history.record import record_suite  # the results database

    record_suite(out_dir, doc)  # adds each criterion's recent values ("trend") to doc
    (out_dir / "results.json").write_text(json.dumps(doc, indent=2, default=_json_default))
    (out_dir / "report.md").write_text(_markdown(doc, out_dir))
    (out_dir / "report.html").write_text(_html(doc, out_dir))
    return doc


def rigs_of(records: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Every rig the suite's tests ran on (``rig_models.rig_file.rig_identity`` without the
    bus: a suite's virtual runs each have their own), with its number of tests."""
    out: dict[tuple[Any, Any], dict[str, Any]] = {}
    for r in records:
        rig = r.get("rig")
        if not isinstance(rig, dict):
            continue
        key = (rig.get("rig"), rig.get("rig_sha256"))
        entry = out.setdefault(key, {"rig": rig.get("rig"), "rig_sha256": rig.get("rig_sha256"),
                                     "binding": rig.get("binding"), "tests": 0})
        entry["tests"] += 1
    return list(out.values())


def _on_rigs(doc: dict[str, Any]) -> str:
    """`` on sgsrt-canopen``: the title names the rig(s)."""
    names = [str(r["rig"]) for r in doc.get("rigs") or [] if r.get("rig")]
    return f" on {', '.join(dict.fromkeys(names))}" if names else ""


def _rig_lines(doc: dict[str, Any]) -> list[str]:
    from rig_models.rig_file import identity_text

    rigs = doc.get("rigs") or []
    return [identity_text(r) for r in rigs] or ["rig unknown (no test ran on a rig)"]


def _json_default(v: Any) -> Any:
    if isinstance(v, np.generic):
        return v.item()
    return str(v)


def _criteria_rows(criteria: list[dict[str, Any]]) -> list[list[str]]:
    """Value, limit and margin with their units as people write them (``N m``, ``m/s²``,
    ``|x| ≤ 0.1 deg``), the criterion's recent values (the results database), the time of
    the worst sample."""
    from harness.history.record import trend_text
    from harness.review.units import limit_text, quantity
    from harness.review.verdict import ordered

    rows = []
    for c in ordered(criteria):  # failing first, then in the run file's order
        unit = c.get("unit", "")
        limit = c.get("limit")
        value = quantity(c.get("value"), unit)
        if c.get("kind") == "settles" and c.get("value") is not None:
            value += " after its trigger"  # not summary.json's settle_time_s (from t = 0)
        if c.get("trend"):
            value += f" (recent: {trend_text(c['trend'])})"
        rows.append([c.get("name", ""), c.get("kind", ""), value,
                     limit_text({k: v for k, v in limit.items() if k != "over"})
                     if isinstance(limit, dict) else _fmt(limit),
                     quantity(c.get("margin"), unit), c.get("verdict", ""),
                     _fmt(c.get("worst_time_s")), c.get("message", "")])
    return rows


HEADER = ["criterion", "kind", "value", "limit", "margin", "verdict", "worst at (s)", "message"]
VERDICT_COL = 5


def _md_table(rows: list[list[str]], header: list[str]) -> str:
    def cell(x: str) -> str:
        return str(x).replace("|", "\\|").replace("\n", " ")
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(cell(x) for x in r) + " |" for r in rows]
    return "\n".join(lines)


def _markdown(doc: dict[str, Any], out_dir: Path) -> str:
    names = ", ".join(s["name"] for s in doc["suites"]) + _on_rigs(doc)
    out = [f"# Suite {names}: {doc['verdict']}", "",
           f"{doc['created_utc']}, {doc['engine']}, bus {doc['bus']}, "
           f"{doc['wall_time_s']:.1f} s; " + ", ".join(f"{v} {n}" for v, n in
                                                       doc["counts"].items()), ""]
    out += [f"- {line}" for line in _rig_lines(doc)] + [""]
    if doc["refused"]:
        out += [f"**Refused:** {doc['refused']}", ""]
    out += [_md_table([[r["item"], r["verdict"], _fmt(r["wall_s"]), r["reason"]]
                       for r in doc["tests"]], ["test", "verdict", "time (s)", "reason"]), ""]
    if doc["not_run"]:
        out += ["Not reported (the suite stopped early; finished ones are listed with "
                "reported false): " + ", ".join(doc["not_run"]), ""]
    for r in doc["tests"]:
        out += [f"## {r['item']}: {r['verdict']}", "", r["reason"], ""]
        if r.get("run_dir"):
            d = r["run_dir"]
            names = run_files(out_dir, d) or ["run.rrd", "can.blf", "verdict.json"]
            out += [" · ".join(f"[{f}]({d}/{f})" for f in names) + f" · [folder]({d}/)", ""]
            if cmd := open_command(out_dir, d):
                out += [f"`{cmd}`", ""]
            if r["kind"] == "run" and (timing := timing_line(out_dir, d)):
                out += [f"Timing: {timing}", ""]
        if r["criteria"]:
            out += [_md_table(_criteria_rows(r["criteria"]), HEADER), ""]
        if r.get("modes"):
            out += [_md_table([[str(i + 1), _fmt(m.get("omega_rad_s")),
                                _fmt(m.get("model_omega_rad_s")),
                                _fmt(m.get("omega_error_percent")),
                                _fmt(m.get("damping_ratio")), _fmt(m.get("model_damping_ratio")),
                                _fmt(m.get("damping_error_percent"))]
                               for i, m in enumerate(r["modes"])],
                              ["mode", "rad/s", "model rad/s", "error %", "zeta",
                               "model zeta", "error %"]), ""]
    return "\n".join(out) + "\n"


CSS = """
body{font-family:system-ui,sans-serif;margin:1.5em;max-width:90em;color:#1f2328}
table{border-collapse:collapse;margin:.5em 0;font-size:.85em}
td,th{border:1px solid #d0d7de;padding:.2em .5em;text-align:left;vertical-align:top}
th{background:#f6f8fa}.v{font-weight:bold;color:#fff;padding:.1em .5em;border-radius:.3em}
section{border-top:1px solid #d0d7de;margin-top:1.2em}
figure{margin:.5em 0}img{width:100%;height:auto}
code{background:#f6f8fa;padding:.1em .3em;border-radius:.2em;word-break:break-all}
@media (max-width:60em){body{margin:.5em}table{font-size:.8em}}
.reason{font-family:monospace;white-space:pre-wrap}
"""


def _badge(v: str) -> str:
    return f'<span class="v" style="background:{COLORS.get(v, "#000")}">{html.escape(v)}</span>'


def _html_table(rows: list[list[str]], header: list[str], verdict_col: int | None = None) -> str:
    h = "".join(f"<th>{html.escape(x)}</th>" for x in header)
    body = []
    for r in rows:
        cells = [(_badge(x) if i == verdict_col and x in COLORS else html.escape(str(x)))
                 for i, x in enumerate(r)]
        body.append("<tr>" + "".join(f"<td>{c}</td>" for c in cells) + "</tr>")
    return f"<table><tr>{h}</tr>{''.join(body)}</table>"


def _anchor(item: str) -> str:
    return "t-" + "".join(ch if ch.isalnum() else "-" for ch in item)


def _html(doc: dict[str, Any], out_dir: Path) -> str:
    names = ", ".join(s["name"] for s in doc["suites"]) + _on_rigs(doc)
    parts = [f"<!doctype html><html><head><meta charset='utf-8'><title>Suite "
             f"{html.escape(names)}</title><style>{CSS}</style></head><body>",
             f"<h1>Suite {html.escape(names)} {_badge(doc['verdict'])}</h1>",
             f"<p>{html.escape(doc['created_utc'])} &middot; {html.escape(doc['engine'])} "
             f"&middot; bus {html.escape(doc['bus'])} &middot; {doc['wall_time_s']:.1f} s "
             f"&middot; exit code {doc['exit_code']} &middot; "
             + ", ".join(f"{html.escape(v)} {n}" for v, n in doc["counts"].items()) + "</p>"]
    parts.append("<ul class='rigs'>" + "".join(f"<li>{html.escape(line)}</li>"
                                               for line in _rig_lines(doc)) + "</ul>")
    if doc["refused"]:
        parts.append(f"<p><b>Refused:</b> {html.escape(doc['refused'])}</p>")
    rows = [[f"<a href='#{_anchor(r['item'])}'>{html.escape(r['item'])}</a>",
             _badge(r["verdict"]), html.escape(_fmt(r["wall_s"])),
             html.escape(r.get("worker") or "-"), html.escape(r["reason"])]
            for r in doc["tests"]]
    parts.append("<table><tr><th>test</th><th>verdict</th><th>time (s)</th><th>worker</th>"
                 "<th>reason</th></tr>" + "".join(
                     "<tr>" + "".join(f"<td>{c}</td>" for c in r) + "</tr>" for r in rows)
                 + "</table>")
    if doc["not_run"]:
        parts.append("<p>Not reported (the suite stopped early): "
                     + html.escape(", ".join(doc["not_run"])) + "</p>")
    for r in doc["tests"]:
        parts.append(f"<section id='{_anchor(r['item'])}'><h2>{html.escape(r['item'])} "
                     f"{_badge(r['verdict'])}</h2>")
        if r.get("description"):
            parts.append(f"<p>{html.escape(r['description'])}</p>")
        parts.append(f"<p class='reason'>{html.escape(r['reason'])}</p>")
        if r.get("run_dir"):
            d = html.escape(r["run_dir"])
            names = run_files(out_dir, r["run_dir"]) or ["run.rrd", "can.blf", "verdict.json"]
            if r["kind"] == "identify" and (out_dir / r["run_dir"] / "identify.json").is_file():
                names.append("identify.json")
            links = " &middot; ".join(f"<a href='{d}/{html.escape(f)}'>{html.escape(f)}</a>"
                                      for f in names)
            parts.append(f"<p>{links} &middot; <a href='{d}/'>{d}/</a></p>")
            if cmd := open_command(out_dir, r["run_dir"]):
                parts.append("<p>open its recordings together (from this folder): "
                             f"<code>{html.escape(cmd)}</code></p>")
            if r["kind"] == "run" and (timing := timing_line(out_dir, r["run_dir"])):
                parts.append(f"<p>Timing: {html.escape(timing)}</p>")
        steps = [c for c in r["criteria"] or [] if c.get("kind") == "step"]
        if steps:  # a sequence: its steps in the order they ran, each with why
            parts.append("<p>Sequence, step by step:</p>")
            parts.append(_html_table([[c.get("name", ""), str(c.get("value", "")),
                                       c.get("verdict", ""), c.get("message", "")]
                                      for c in steps],
                                     ["step", "outcome", "verdict", "what decided it"],
                                     verdict_col=2))
        if r["criteria"]:
            parts.append(_html_table(_criteria_rows(r["criteria"]), HEADER,
                                     verdict_col=VERDICT_COL))
        if r.get("modes"):
            parts.append(_html_table([[str(i + 1), _fmt(m.get("omega_rad_s")),
                                       _fmt(m.get("model_omega_rad_s")),
                                       _fmt(m.get("omega_error_percent")),
                                       _fmt(m.get("damping_ratio")),
                                       _fmt(m.get("model_damping_ratio")),
                                       _fmt(m.get("damping_error_percent"))]
                                      for i, m in enumerate(r["modes"])],
                                     ["mode", "rad/s", "model rad/s", "error %", "zeta",
                                      "model zeta", "error %"]))
        if r["criteria"]:
            try:
                scalars = scalar_plot(r["criteria"])
            except Exception as exc:  # noqa: BLE001 - a report must not die on one plot
                scalars = None
                parts.append(f"<p>scalar plot not drawn: {html.escape(type(exc).__name__)}: "
                             f"{html.escape(str(exc))}</p>")
            if scalars:
                parts.append(f"<figure><img alt='{html.escape(scalars['title'])}' "
                             f"src='data:image/png;base64,{scalars['png']}'></figure>")
        if r.get("run_dir") and r["kind"] == "run":
            try:
                plots = run_plots(out_dir / r["run_dir"], r["criteria"])
            except Exception as exc:  # noqa: BLE001 - a report must not die on one plot
                plots = []
                parts.append(f"<p>plots not drawn: {html.escape(type(exc).__name__)}: "
                             f"{html.escape(str(exc))}</p>")
            for p in plots:
                parts.append(f"<figure><img alt='{html.escape(p['title'])}' "
                             f"src='data:image/png;base64,{p['png']}'></figure>")
            if (bode := frf_figure(out_dir / r["run_dir"])) is not None:
                parts.append(bode)
        parts.append("</section>")
    parts.append("</body></html>")
    return "\n".join(parts)
