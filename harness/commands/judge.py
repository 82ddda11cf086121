"""`harness judge RUN_DIR [--expect FILE [--write]] [--json]`: judge (or re-judge) a recorded run.

The run's criteria (the ``expect:`` section of its run file, as written in config.yaml, with
the rig file's ``expect_overrides``), or those of ``--expect FILE`` (a YAML file with an
``expect:`` section, or a run file), are checked against the run directory's summary.json,
run.rrd and can.blf; the run's own checks are added (it raised, was interrupted, a fault no
criterion expects, files missing). Writes verdict.json and verdict.rrd into RUN_DIR (the
same verdict.json ``harness run`` wrote at the end of the run, for the same criteria and
code) and prints the verdict. Judged by ``--expect FILE`` (a what-if) it writes nothing
unless ``--write`` is given, so the run's own verdict (what ``harness logs`` reports) stays.
It prints one line per criterion (value, limit, margin, verdict, the
worst sample's time). Forms of criteria: docs/criteria.md.

A real-time run is also judged by the bench's timing (overruns, lateness, telemetry missing
in ticks the loop held, against the run file's ``realtime:`` limits): beyond one it is
INCONCLUSIVE, and the reason says whose the lost time was (host, harness, device).

Exit codes: 0 PASS (or NO CRITERIA), 1 FAIL, 2 bad input (no such directory, bad criteria),
3 ERROR by a fault the run did not expect, 4 ERROR otherwise (the run raised, missing data),
5 MARGINAL, 6 INCONCLUSIVE (the bench did not hold real time), 130 the run was interrupted.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from harness.commands import examples
from rig_models.schema import ConfigError


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("judge", help="judge a recorded run by its criteria; writes verdict.json",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("run_dir", type=Path, help="a run directory (logs/<UTC time>-<name>/)")
    p.add_argument("--expect", type=Path, metavar="FILE",
                   help="judge by this file's expect: section instead of the run's own")
    p.add_argument("--write", action="store_true",
                   help="with --expect: make this the run's verdict (verdict.json, "
                   "verdict.rrd); without, a what-if judgement writes nothing")
    p.add_argument("--json", action="store_true", help="print verdict.json on stdout")
    p.epilog = examples(
        "harness judge logs/20260101T120000.000000Z-slew-rw",
        "harness judge logs/20260101T120000.000000Z-slew-rw --expect criteria.yaml --json")
    p.set_defaults(func=cmd_judge)


def cmd_judge(args: argparse.Namespace) -> int:
    # numpy, scipy and Rerun's reader only when judging (start-up of `harness --help`)
    from harness.testing import JudgeInputError, format_block, judge_run, write_verdict

    try:
        verdict = judge_run(args.run_dir, args.expect)
    except (ConfigError, JudgeInputError) as exc:
        print(f"harness judge: {exc}", file=sys.stderr)
        return 2
    path = None
    if args.expect is None or args.write:
        path = write_verdict(verdict, args.run_dir)
        from harness.history.record import record_verdict  # the results database

        record_verdict(args.run_dir, verdict.to_dict())
    else:  # a what-if: the run's own verdict (what 'harness logs' reads) stays as it is
        print(f"harness judge: judged by {args.expect}, not the run's own criteria: "
              "verdict.json left as it was (--write to replace it)", file=sys.stderr)
    if args.json:
        print(json.dumps(verdict.to_dict(), indent=2))
        print(format_block(verdict, path), file=sys.stderr)
    else:
        print(format_block(verdict, path))
    return verdict.exit_code
