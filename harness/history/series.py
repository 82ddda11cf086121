"""A series across runs from the database: a criterion (value, limits, margin, verdict) or an
identified mode (omega with its 1 sigma), with its alarms, as rows, JSON, a PNG and a page.
"""

from __future__ import annotations

import base64
import html
import io
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from harness.history import drift
from harness.history.db import Filters, HistoryDB
from harness.testing.measures import unit_text

LIMIT_KEYS = ("min", "max", "max_abs")


@dataclass
class Series:
    """One test's criterion or mode on one rig (its name, real or virtual) under one run
    configuration (``run_sha256``: the run file's data; "" for records from before it was
    kept), oldest first."""

    what: str  # "criterion" | "mode"
    test: str
    name: str  # the criterion's name, or "mode N"
    unit: str  # as verdicts print it (N m, m/s^2)
    rows: list[dict[str, Any]]
    alarms: list[drift.Alarm] = field(default_factory=list)
    flaky: list[dict[str, Any]] = field(default_factory=list)
    rig: str = ""
    real_rig: bool = False
    run_sha256: str = ""

    @property
    def where(self) -> str:
        """``on sgsrt-canopen (real), run configuration 0123abcd``."""
        rig = f"on {self.rig or 'an unnamed rig'}{' (real)' if self.real_rig else ''}"
        return rig + (f", run configuration {self.run_sha256[:8]}" if self.run_sha256 else "")

    @property
    def label(self) -> str:
        return f"{self.test} {self.name} {self.where}"

    def points(self) -> list[drift.Point]:
        return [drift.Point(r["time_utc"], float(r["value"]), r.get("sigma"), r.get("source")
                            or "") for r in self.rows if r.get("value") is not None]

    def to_dict(self) -> dict[str, Any]:
        return {"series": self.what, "test": self.test, "name": self.name, "unit": self.unit,
                "rig": self.rig, "real_rig": self.real_rig, "run_sha256": self.run_sha256,
                "label": self.label, "runs": self.rows,
                "alarms": [a.to_dict() for a in self.alarms], "flaky": self.flaky}


def _limits(raw: Any) -> dict[str, float]:
    """The numeric limits of a criterion's ``limit`` (keys as in verdict.json, unit
    suffix dropped: ``max_m_s2`` -> ``max``)."""
    try:
        lim = json.loads(raw) if isinstance(raw, str) else (raw or {})
    except ValueError:
        return {}
    out: dict[str, float] = {}
    for k, v in (lim or {}).items():
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            continue
        for base in ("marginal", "max_abs", "min", "max"):
            if k == base or k.startswith(base + "_"):
                out[base] = float(v)
                break
    return out


def _identity(r: dict[str, Any]) -> dict[str, Any]:
    return {"rig": r["rig"], "real_rig": bool(r["real_rig"]), "rig_sha256": r.get("rig_sha256"),
            "run_sha256": r.get("run_sha256"), "bus": r.get("bus"),
            "config_sha256": r["config_sha256"], "source": r["source"]}


def criterion_series(db: HistoryDB, test: str, name: str, filters: Filters | None = None
                     ) -> Series:
    """The criterion's rows the filters select, as one series (``split`` parts it by rig
    and run configuration)."""
    rows = db.criterion_series(test, name, filters)
    out = []
    for r in rows:
        out.append({"time_utc": r["time_utc"], "value": r["value"], "margin": r["margin"],
                    "verdict": r["verdict"], "limits": _limits(r["limits"]), **_identity(r)})
    unit = next((r["unit"] for r in rows if r.get("unit")), "")
    return Series("criterion", test, name, unit_text(unit or ""), out)


def mode_series(db: HistoryDB, test: str, mode: int, filters: Filters | None = None) -> Series:
    rows = db.mode_series(test, mode, filters)
    out = [{"time_utc": r["time_utc"], "value": r["omega_rad_s"],
            "sigma": r["sigma_omega_rad_s"], "damping_ratio": r["damping_ratio"],
            "sigma_damping": r["sigma_damping"], "model_omega_rad_s": r["model_omega_rad_s"],
            **_identity(r)} for r in rows]
    return Series("mode", test, f"mode {mode}", "rad/s", out)


def split(series: Series) -> list[Series]:
    """``series``' rows parted into one series per rig (name, real or virtual) and run
    configuration, in the order each first ran: one rig's alarms are never measured from
    another rig's runs, nor a suite item's from a plain run with other criteria."""
    parts: dict[tuple[str, bool, str], list[dict[str, Any]]] = {}
    for r in series.rows:
        key = (r.get("rig") or "", bool(r.get("real_rig")), r.get("run_sha256") or "")
        parts.setdefault(key, []).append(r)
    return [Series(series.what, series.test, series.name, series.unit, rows, rig=rig,
                   real_rig=real, run_sha256=run)
            for (rig, real, run), rows in parts.items()]


def flaky(series: Series) -> list[dict[str, Any]]:
    """Configurations (run and rig unchanged: the same config hash) under which the verdict
    flipped between PASS and FAIL: the test is flaky there."""
    by_cfg: dict[str, list[dict[str, Any]]] = {}
    for r in series.rows:
        if r.get("config_sha256") and r.get("verdict"):
            by_cfg.setdefault(r["config_sha256"], []).append(r)
    out = []
    for cfg, rows in by_cfg.items():
        verdicts = [r["verdict"] for r in rows]
        passed = sum(v in ("PASS", "MARGINAL") for v in verdicts)
        failed = sum(v == "FAIL" for v in verdicts)
        if passed and failed:
            flips = sum(1 for a, b in zip(verdicts, verdicts[1:], strict=False)
                        if (a == "FAIL") != (b == "FAIL"))
            out.append({"config_sha256": cfg, "runs": len(rows), "passed": passed,
                        "failed": failed, "flips": flips,
                        "message": f"{series.label}: flaky: {failed} FAIL and {passed} PASS in "
                                   f"{len(rows)} runs of one unchanged configuration "
                                   f"({cfg[:12]}), {flips} flips"})
    return out


def analyse(series: Series, k: float = drift.DEFAULT_K, n_ref: int = drift.DEFAULT_N_REF,
            n_trend: int = drift.DEFAULT_N_TREND, reference: int = 0,
            spread: float | None = None, bands: list[dict[str, float]] | None = None,
            designed_by: str = "") -> Series:
    """The series' alarms (and flaky configurations for a criterion)."""
    pts = series.points()
    alarms: list[drift.Alarm] = []
    if series.what == "mode":
        with_sigma = [p for p in pts if p.sigma is not None]
        if with_sigma and reference < len(pts) and pts[reference].sigma is not None:
            alarms += drift.change_alarms(pts, series.label, series.unit, k, reference)
        if bands:
            mode = int(series.name.split()[-1])
            if mode <= len(bands):
                for i, p in enumerate(pts):
                    a = drift.band_alarm(p, i, series.label, bands[mode - 1], designed_by)
                    if a is not None:
                        alarms.append(a)
        t = drift.trend_alarm(pts, series.label, series.unit, k, n_trend)
        if t is not None:
            alarms.append(t)
    else:
        # the chart is the margin's (the distance to the limit, whatever side it is on;
        # the value's own would repeat it while the limit stays)
        margins = [drift.Point(r["time_utc"], float(r["margin"]), None, r.get("source") or "")
                   for r in series.rows if r.get("margin") is not None]
        alarms += drift.control_alarms(margins, f"{series.label} margin", series.unit, k,
                                       n_ref, spread)
        t = drift.trend_alarm(margins, f"{series.label} margin", series.unit, k, n_trend)
        if t is not None and t.change < 0:  # only a shrinking margin is a warning
            alarms.append(t)
        series.flaky = flaky(series)
    series.alarms = sorted(alarms, key=lambda a: (a.index, a.kind))
    return series


# ------------------------------------------------------------------------ output
def table(series: Series) -> str:
    lines = [f"{series.label} ({series.unit or 'no unit'}), {len(series.rows)} runs"]
    if series.what == "mode":
        lines.append(f"{'#':>3} {'time (UTC)':<20} {'omega':>10} {'1 sigma':>9} "
                     f"{'model':>9} {'zeta':>7}  rig")
        for i, r in enumerate(series.rows):
            lines.append(f"{i:>3} {r['time_utc']:<20} {r['value']:>10.5f} "
                         f"{_f(r['sigma'], '9.5f')} {_f(r['model_omega_rad_s'], '9.4f')} "
                         f"{_f(r['damping_ratio'], '7.4f')}  {r['rig'] or '-'}"
                         f"{' (real)' if r['real_rig'] else ''}")
    else:
        lines.append(f"{'#':>3} {'time (UTC)':<20} {'value':>11} {'margin':>11} "
                     f"{'verdict':<8} limits")
        for i, r in enumerate(series.rows):
            lim = ", ".join(f"{k} {v:g}" for k, v in r["limits"].items())
            sc = f" ({r['scatter']} the predicted scatter)" if r.get("scatter") else ""
            lines.append(f"{i:>3} {r['time_utc']:<20} {_f(r['value'], '11.5g')} "
                         f"{_f(r['margin'], '11.4g')} {r['verdict'] or '-':<8} {lim}{sc}")
    for a in series.alarms:
        lines.append(f"ALARM ({a.kind}, run {a.index}): {a.message}")
    for f in series.flaky:
        lines.append(f"FLAKY: {f['message']}")
    if not series.alarms:
        lines.append("no alarm")
    return "\n".join(lines)


def _f(v: Any, fmt: str) -> str:
    width = int(fmt.split(".")[0] or 0)
    return f"{'-':>{width}}" if v is None else format(v, fmt)


def plot_png(series: Series | list[Series], path: Path | io.BytesIO) -> Path | io.BytesIO:
    """Values over the runs, one panel a series (a rig, a run configuration): a mode with
    its 1-sigma error bars (the model's value dashed); a criterion with its limits (red)
    and marginal band (shaded); alarms ringed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    many = series if isinstance(series, list) else [series]
    fig, axes = plt.subplots(len(many), 1, figsize=(8, 4 * len(many)), dpi=100,
                             squeeze=False)
    for ax, one in zip(axes[:, 0], many, strict=True):
        _draw(ax, one)
    fig.tight_layout()
    if not isinstance(path, io.BytesIO):
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, format="png")
    plt.close(fig)
    return path


def _draw(ax: Any, series: Series) -> None:
    idx = list(range(len(series.rows)))
    vals = [math.nan if r["value"] is None else r["value"] for r in series.rows]
    if series.what == "mode":
        sig = [r.get("sigma") or 0.0 for r in series.rows]
        ax.errorbar(idx, vals, yerr=sig, fmt="o", capsize=3, label="identified, 1 sigma")
        model = [r.get("model_omega_rad_s") for r in series.rows]
        if any(m is not None for m in model):
            ax.plot(idx, [math.nan if m is None else m for m in model], "k--", lw=1,
                    label="rig file's model")
    else:
        colors = ["#2da44e" if r["verdict"] == "PASS" else "#bf8700"
                  if r["verdict"] == "MARGINAL" else "#cf222e" for r in series.rows]
        ax.plot(idx, vals, "-", color="#888", lw=1)
        ax.scatter(idx, vals, c=colors, zorder=3, label="value (colour: verdict)")
        for key in ("min", "max", "max_abs"):
            lim = [r["limits"].get(key) for r in series.rows]
            if any(v is not None for v in lim):
                y = [math.nan if v is None else v for v in lim]
                ax.step(idx, y, "r-", where="mid", lw=1, label=f"limit ({key})")
                if key == "max_abs":
                    ax.step(idx, [-v for v in y], "r-", where="mid", lw=1)
                marg = [r["limits"].get("marginal") for r in series.rows]
                if any(m is not None for m in marg):
                    lo = [(v - m if key != "min" else v) if v is not None and m is not None
                          else math.nan for v, m in zip(y, marg, strict=True)]
                    hi = [(v if key != "min" else v + m) if v is not None and m is not None
                          else math.nan for v, m in zip(y, marg, strict=True)]
                    ax.fill_between(idx, lo, hi, step="mid", color="#bf8700", alpha=0.2,
                                    label="marginal band")
                    if key == "max_abs":
                        ax.fill_between(idx, [-v for v in hi], [-v for v in lo], step="mid",
                                        color="#bf8700", alpha=0.2)
    ringed: set[int] = set()
    for a in series.alarms:  # ringed on the plotted value (a margin's alarm too)
        if a.index in ringed or not 0 <= a.index < len(vals):
            continue
        ringed.add(a.index)
        kinds = "+".join(sorted({b.kind for b in series.alarms if b.index == a.index}))
        ax.plot([a.index], [vals[a.index]], "o", ms=14, mfc="none", mec="#cf222e", mew=2)
        ax.annotate(kinds, (a.index, vals[a.index]), textcoords="offset points",
                    xytext=(6, 8), color="#cf222e", fontsize=8)
    ax.set_xticks(idx)
    labels = [r["time_utc"][5:16].replace("T", "\n") for r in series.rows]
    if len(set(labels)) < len(labels):  # runs within a minute: their seconds too
        labels = [r["time_utc"][5:19].replace("T", "\n") for r in series.rows]
    ax.set_xticklabels(labels, fontsize=7)
    ax.set_xlabel("run (UTC)")
    ax.set_ylabel(f"{series.name} ({series.unit})" if series.unit else series.name)
    ax.set_title(series.label)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="best")


def page_html(series: Series | list[Series], path: Path) -> Path:
    """A self-contained page: per series (a rig, a run configuration) the plot, the alarms
    and the table."""
    many = series if isinstance(series, list) else [series]
    title = f"{many[0].test} {many[0].name}" if many else "history"
    parts = []
    for one in many:
        png = io.BytesIO()
        plot_png(one, png)
        img = base64.b64encode(png.getvalue()).decode()
        alarms = "".join(f"<li><b>{html.escape(a.kind)}</b>: {html.escape(a.message)}</li>"
                         for a in one.alarms) or "<li>no alarm</li>"
        alarms += "".join(f"<li><b>flaky</b>: {html.escape(f['message'])}</li>"
                          for f in one.flaky)
        parts.append(f"<h2>{html.escape(one.label)}</h2><img alt='series' "
                     f"src='data:image/png;base64,{img}'><h3>Alarms</h3><ul>{alarms}</ul>"
                     f"<h3>Runs</h3><pre>{html.escape(table(one))}</pre>")
    doc = (f"<!doctype html><html><head><meta charset='utf-8'><title>"
           f"{html.escape(title)}</title></head><body style='font-family:sans-serif'>"
           f"<h1>{html.escape(title)}</h1>{''.join(parts)}</body></html>")
    Path(path).write_text(doc)
    return Path(path)
