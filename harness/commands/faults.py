"""`harness faults`: the faults the virtual rig can inject, and how the harness detects them."""

from __future__ import annotations

import argparse

from harness.core import monitor
from rig_models.faults import DEVICE_FAULTS, FAULT_KINDS


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("faults", help="list injectable faults and the detection bounds")
    p.set_defaults(func=cmd_faults)


def cmd_faults(args: argparse.Namespace) -> int:
    print("Inject with 'harness run NAME --fault KIND@AT_S[+DURATION_S][:DEVICE][=VALUE]' "
          "or a run file's 'faults:' list.\n")
    for kind, what in FAULT_KINDS.items():
        dev = " (needs :DEVICE)" if kind in DEVICE_FAULTS else ""
        print(f"  {kind:<18} {what}{dev}")
    print("\nDetection" + monitor.__doc__.split("Detection", 1)[1])
    return 0
