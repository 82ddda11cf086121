"""`harness faults`: the faults the virtual rig can inject, and how the harness detects them.

Lists every fault kind (``--fault KIND@AT_S[+DURATION_S][:DEVICE][=VALUE]`` of ``harness
run``, ``harness probe`` and ``harness virtual-rig``, or a run file's ``faults:`` list) with
what it does to the device, then the fault monitor's detection bounds (a silent device, a
stale or malformed frame, a limit crossed) and what the harness does when one trips.
"""

from __future__ import annotations

import argparse

from harness.commands import examples


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("faults", help="list injectable faults and the detection bounds",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.epilog = examples(
        "harness faults",
        "harness run slew-rw --fault silent_sensor@5:hub_sensor")
    p.set_defaults(func=cmd_faults)


def cmd_faults(args: argparse.Namespace) -> int:
    # the monitor (numpy) only when listing (start-up of `harness --help`)
    from harness.core import monitor
    from rig_models.faults import DEVICE_FAULTS, FAULT_KINDS

    print("Inject with 'harness run NAME --fault KIND@AT_S[+DURATION_S][:DEVICE][=VALUE]' "
          "or a run file's 'faults:' list.\n")
    for kind, what in FAULT_KINDS.items():
        dev = " (needs :DEVICE)" if kind in DEVICE_FAULTS else ""
        print(f"  {kind:<18} {what}{dev}")
    print("\nDetection" + monitor.__doc__.split("Detection", 1)[1])
    return 0
