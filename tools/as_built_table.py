"""Every built-in run (each variant) on the ideal virtual rig and on the rig as built: the
verdict of each and the criteria that failed, as the markdown table of docs/as_built.md.

    .venv/bin/python tools/as_built_table.py [--devices-rig sgsrt-as-built] [CASE ...]

Each run is `harness run CASE --rig sgsrt` with the virtual rig emulating the ideal model,
then the same with `--devices-rig` (the as-built devices: friction, biases, lags, inertia
and modes off the file, damping a quarter of it). A FAULT or an ERROR on the as-built rig is
the harness's own fault (the checks must hold a real rig within its tolerances); a FAIL is
a criterion the real rig cannot meet, each explained in docs/as_built.md. Progress on
stderr, the table on stdout; a few minutes of CPU.
"""

from __future__ import annotations

import argparse
import io
import json
import sys
import tempfile
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from harness.cli import main  # noqa: E402
from harness.core.runs import RUNS_DIR  # noqa: E402


def _run(case: str, out: Path, devices_rig: str | None) -> list[dict]:
    """The verdicts of every variant of ``case`` (run in this process, output captured)."""
    args = ["run", case, "--out", str(out), "--quiet"]
    if devices_rig:
        args += ["--devices-rig", devices_rig]
    with redirect_stdout(io.StringIO()), redirect_stderr(io.StringIO()):
        main(args)
    rows = []
    for run_dir in sorted(p for p in out.iterdir() if p.is_dir()):
        verdict_path = run_dir / "verdict.json"
        summary_path = run_dir / "summary.json"
        v = json.loads(verdict_path.read_text()) if verdict_path.exists() else {}
        s = json.loads(summary_path.read_text()) if summary_path.exists() else {}
        failed = [c["name"] for c in v.get("criteria", [])
                  if c.get("verdict") in ("FAIL", "MARGINAL")]
        # a fault after the run's sequence injected one is the sequence's to judge (its
        # steps say whether the rig was made safe in time), not the monitor's finding
        seq = s.get("sequence") or {}
        t_inj = min((f["at_s"] for f in seq.get("injected") or []), default=None)
        faults = [f"{f['device']}: {f['kind']}" for f in s.get("faults", [])
                  if t_inj is None or f.get("time_s", 0.0) < t_inj]
        rows.append({"run": s.get("run", run_dir.name), "verdict": v.get("verdict", "?"),
                     "failed": failed, "faults": faults})
    return rows


def main_table(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--devices-rig", default="sgsrt-as-built")
    p.add_argument("cases", nargs="*", help="built-in runs (default: all)")
    a = p.parse_args(argv)
    cases = a.cases or sorted(x.stem for x in RUNS_DIR.glob("*.yaml"))
    print(f"| run | ideal rig | as built ({a.devices_rig}) | failed on the rig as built |")
    print("|---|---|---|---|")
    bad = 0
    with tempfile.TemporaryDirectory() as tmp:
        for i, case in enumerate(cases, 1):
            print(f"[{i}/{len(cases)}] {case} ...", file=sys.stderr, flush=True)
            ideal = _run(case, Path(tmp) / f"{case}-ideal", None)
            built = _run(case, Path(tmp) / f"{case}-built", a.devices_rig)
            by_run = {r["run"]: r for r in ideal}
            for r in built:
                i_r = by_run.get(r["run"], {"verdict": "?"})
                what = ", ".join(r["faults"] + r["failed"]) or "-"
                bad += bool(r["faults"]) or r["verdict"] == "ERROR"
                print(f"| {r['run']} | {i_r['verdict']} | {r['verdict']} | {what} |",
                      flush=True)
    print(f"\n{bad} run(s) with a fault or an ERROR on the rig as built", file=sys.stderr)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main_table())
