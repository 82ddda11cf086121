"""commission.json, report.html and commission.rrd in the commissioning's folder.

Two tables: the bindings (each quantity against the physics) and the rig file's model
(each measured key: the file's value, the measured value and its 1-sigma, the limit, the
verdict, whether ``--write-rig`` writes it).

commission.rrd holds, per check that compares a measured change with the physics' (a
ratio), the two curves on the run's time axis (``/checks/<device>/<quantity>/<n>/measured``
and ``.../expected``), and the verdict table as a text document (``/verdict``).
"""

from __future__ import annotations

import html
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from harness.record.output import write_text_atomic

APPLICATION_ID = "sgsrt_commission"
COLOURS = {"PASS": "#1b7f3b", "FAIL": "#b3261e", "NOT RUN": "#7a7a7a", "INFO": "#44617b",
           "ERROR": "#b3261e", "DIFFERS": "#a85d00", "NOT JUDGED": "#7a7a7a"}
VERDICT_TEXT = {
    "PASS": "every binding proved; the rig within its file's tolerances",
    "FAIL": "a binding failed: fix the rig file's conversion or object the failing lines "
            "name, then commission again",
    "DIFFERS": "every binding proved; the rig differs from its file beyond the file's "
               "tolerance: run harness commission --write-rig FILE and review it",
    "ERROR": "a run stopped: see the notes",
}


def _fmt(x: Any) -> str:
    if x is None:
        return "-"
    if isinstance(x, list):
        return "[" + ", ".join(_fmt(v) for v in x) + "]"
    if isinstance(x, float):
        return "-" if not math.isfinite(x) else f"{x:.4g}"
    return str(x)


def _jsonable(x: Any) -> Any:
    if isinstance(x, dict):
        return {k: _jsonable(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


def _written(c: Any, x: Any) -> str:
    from harness.commissioning.model import written

    return "yes" if c.verdict in ("PASS", "DIFFERS") and written(x, c.plan.rig) else "no"


def markdown_table(c: Any) -> str:
    lines = [f"# Commissioning of {c.plan.rig.name}: {c.verdict}", "",
             VERDICT_TEXT.get(c.verdict, ""), "", "## The bindings", "",
             "| device.quantity | check | value | expected | limit | margin | verdict | "
             "likely cause |", "|---|---|---|---|---|---|---|---|"]
    for x in c.checks:
        if x.key:
            continue
        lines.append(f"| {x.name} | {x.check} | {_fmt(x.value)} | {_fmt(x.expected)} | "
                     f"{_fmt(x.limit)} | {_fmt(x.margin)} | {x.verdict} | {x.cause} |")
    model = [x for x in c.checks if x.key]
    if model:
        lines += ["", "## The rig file's model, measured", "",
                  "| key | what | the file's | measured | 1 sigma | limit | verdict | "
                  "written | what to do |", "|---|---|---|---|---|---|---|---|---|"]
        for x in model:
            lines.append(f"| {x.key} | {x.check} | {_fmt(x.expected)} | {_fmt(x.value)} | "
                         f"{_fmt(x.sigma)} | {_fmt(x.limit)} | {x.verdict} | "
                         f"{_written(c, x)} | {x.cause} |")
    lines += [""] + [f"- {n}" for n in c.notes]
    return "\n".join(lines) + "\n"


def write_html(c: Any, path: Path) -> None:
    rows, model = [], []
    for x in c.checks:
        colour = COLOURS.get(x.verdict, "#000")
        if x.key:
            model.append(
                "<tr>" + "".join(f"<td>{html.escape(v)}</td>" for v in (
                    x.key, x.check, _fmt(x.expected), _fmt(x.value), _fmt(x.sigma),
                    _fmt(x.limit), x.unit))
                + f"<td style='color:{colour};font-weight:bold'>{html.escape(x.verdict)}</td>"
                + f"<td>{_written(c, x)}</td><td>{html.escape(x.cause)}</td>"
                + f"<td class='why'>{html.escape(x.why)}</td></tr>")
            continue
        rows.append(
            "<tr>" + "".join(f"<td>{html.escape(v)}</td>" for v in (
                x.device, x.quantity, x.check, _fmt(x.value), _fmt(x.expected), _fmt(x.limit),
                x.unit, _fmt(x.margin)))
            + f"<td style='color:{colour};font-weight:bold'>{html.escape(x.verdict)}</td>"
            + f"<td>{html.escape(x.cause)}</td><td class='why'>{html.escape(x.why)}</td></tr>")
    runs = "".join(f"<li>{html.escape(k)}: <code>{html.escape(v)}</code></li>"
                   for k, v in c.runs.items())
    notes = "".join(f"<li>{html.escape(n)}</li>" for n in c.notes)
    colour = COLOURS.get(c.verdict, "#000")
    model_table = "" if not model else (
        "<h2>The rig file's model, measured</h2><p>Each key the runs measured: the file's "
        "value, the measured one and its 1-sigma, the limit (the file's tolerance plus 4 "
        "sigma), the verdict, and whether <code>--write-rig</code> writes it.</p>"
        "<table><tr><th>key</th><th>what</th><th>the file's</th><th>measured</th>"
        "<th>1 sigma</th><th>limit</th><th>unit</th><th>verdict</th><th>written</th>"
        "<th>what to do</th><th>how</th></tr>" + "".join(model) + "</table>")
    text = f"""<!DOCTYPE html>
<html><head><meta charset="utf-8"><title>Commissioning {html.escape(c.plan.rig.name)}</title>
<style>body{{font-family:sans-serif;margin:1.5em}}table{{border-collapse:collapse}}
td,th{{border:1px solid #ccc;padding:3px 6px;font-size:13px;vertical-align:top}}
th{{background:#f0f0f0}}td.why{{color:#555;font-size:12px}}</style></head><body>
<h1>Commissioning of {html.escape(c.plan.rig.name)}:
<span style="color:{colour}">{html.escape(c.verdict)}</span></h1>
<p>{html.escape(VERDICT_TEXT.get(c.verdict, ""))}</p>
<p>Rig file <code>{html.escape(c.options.rig)}</code>, bus
<code>{html.escape(c.options.bus or 'virtual:sgsrt')}</code>; bound devices:
{html.escape(', '.join(c.plan.bound))}; {c.wall_time_s:.1f} s. What each check proves and
what to do when one fails: docs/commission.md.</p>
<ul>{notes}</ul>
<h2>The bindings</h2>
<table><tr><th>device</th><th>quantity</th><th>check</th><th>value</th><th>expected</th>
<th>limit</th><th>unit</th><th>margin</th><th>verdict</th><th>likely cause</th><th>how</th></tr>
{''.join(rows)}</table>
{model_table}
<h2>Runs</h2><ul>{runs}</ul>
<p>Open a run's recording with <code>rerun RUN_DIR/run.rrd</code>, the checks' curves with
<code>rerun commission.rrd</code>.</p></body></html>
"""
    write_text_atomic(path, text)


def write_rrd(c: Any, path: Path) -> None:
    import rerun as rr

    from harness.record.recording import close_stream
    from harness.record.streams import sweep_orphans

    rec = rr.RecordingStream(APPLICATION_ID, recording_id=path.parent.name)
    rec.save(str(path))
    try:
        for n, x in enumerate(c.checks):
            if x.series is None:
                continue
            t, meas, pred = x.series
            base = f"/checks/{x.device}/{x.quantity}/{n}"
            for part, values, colour in (("measured", meas, (200, 80, 60)),
                                         ("expected", pred, (60, 110, 170))):
                rec.log(f"{base}/{part}", rr.SeriesLines(
                    names=f"{x.name} {part} ({x.check})", colors=[colour]), static=True)
                rec.send_columns(f"{base}/{part}", indexes=[rr.TimeColumn("time", duration=t)],
                                 columns=rr.Scalars.columns(
                                     scalars=np.asarray(values, dtype=float)))
        rec.log("/verdict", rr.TextDocument(markdown_table(c), media_type="text/markdown"),
                static=True)
    finally:
        try:
            close_stream(rec, path)  # bounded: a stuck sink never hangs the command
        finally:
            del rec
            sweep_orphans()


def write_outputs(c: Any) -> None:
    folder = Path(c.folder)
    write_text_atomic(folder / "commission.json", json.dumps(_jsonable(c.to_dict()), indent=2))
    write_html(c, folder / "report.html")
    try:
        write_rrd(c, folder / "commission.rrd")
    except Exception as exc:  # noqa: BLE001 - the JSON and the report already hold the verdict
        c.notes.append(f"commission.rrd not written ({exc})")
        write_text_atomic(folder / "commission.json",
                          json.dumps(_jsonable(c.to_dict()), indent=2))
