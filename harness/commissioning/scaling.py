"""Before anything moves: each CANopen node's identity and device type, and the device's
own scaling objects (read by SDO during the rest run's set-up) against the rig file's
conversions:

- CiA 402: torque actual value 0x6077 and target torque 0x6071 count per mille of the
  rated torque 0x6076 (mN m): one count is 0x6076 x 1e-6 N m;
- CiA 406: position value 0x6004 and speed value 0x6030 count 1 / (measuring units per
  revolution 0x6001) of a turn: one count is 2 pi / 0x6001 rad (rad/s);
- the CiA 402 position/velocity factors (0x608F-0x6096) and CiA 401 analog scaling
  (0x642E/0x642F) are reported when a device has them; this rig's devices state their
  velocity and analog units in their EDS only (docs/canopen.md).

A disagreement is named with both numbers; its limit is ``SCALE_REL`` (the rig file's
constant written to its printed digits), not a model tolerance: the two are the same
number or the binding is wrong.
"""

from __future__ import annotations

import math
from typing import Any

from drivers.binding.quantities import COMMANDS, TELEMETRY
from harness.commissioning.checks import Check, likely_cause

SCALE_REL = 1e-3

# profile -> (scaling object label, objects it scales, SI per count from its value, text)
RULES: dict[str, list[tuple[str, tuple[int, ...], Any, str]]] = {
    "cia402": [("0x6076.0", (0x6077, 0x6071), lambda v: float(v) * 1e-6,
                "the drive's rated torque 0x6076 = {v} mN m makes a count {x:.6g} N m (per "
                "mille)")],
    "cia406": [("0x6001.0", (0x6004, 0x6030), lambda v: 2 * math.pi / float(v),
                "the encoder's measuring units per revolution 0x6001 = {v} make a count "
                "{x:.6g} rad")],
}


def scaling_checks(binding: Any, nodes: list[dict[str, Any]] | None) -> list[Check]:
    co = binding.canopen
    if co is None:
        return []
    out: list[Check] = []
    if not nodes:
        return [Check("canopen", "nodes", "identity, device type, scaling objects", None,
                      None, None, "", None, "NOT RUN",
                      why="the rest run reported no CANopen set-up")]
    for node in nodes:
        spec = co.nodes.get(int(node["node_id"]))
        if spec is None:
            continue
        ident = ", ".join(f"{k} {node[k]}" for k in ("vendor_id", "product_code", "revision")
                          if k in node)
        out.append(Check("/".join(spec.devices), f"node {spec.node_id}",
                         "identity and device type against the EDS / rig file", None, None,
                         None, "", None, "PASS",
                         why=f"device type {node.get('device_type')}; {ident} (the set-up "
                             "refuses a node that differs)"))
        scaling = node.get("scaling") or {}
        for label, objects, per_count, text in RULES.get(spec.profile, []):
            if label not in scaling:
                continue
            v = scaling[label]
            expected = per_count(v)
            unit_of = "N.m" if spec.profile == "cia402" else "rad"
            for device, qrefs in list(spec.telemetry.items()) + list(spec.commands.items()):
                for q in qrefs:
                    if q.ref.index not in objects or q.conv.bit is not None or \
                            q.conv.mask is not None or q.conv.values is not None:
                        continue
                    got = q.conv.scale
                    rel = abs(got / expected - 1.0)
                    margin = SCALE_REL - rel
                    verdict = "PASS" if margin >= 0 else "FAIL"
                    cause = ""
                    if verdict == "FAIL":
                        cause = (f"the rig file converts a count of 0x{q.ref.index:04X} to "
                                 f"{got:.6g}; " + text.format(v=v, x=expected) + "; ")
                        unit = {**TELEMETRY.get(device, {}), **COMMANDS.get(device, {})}.get(
                            q.quantity, "")
                        if unit.split("/")[0] != unit_of:
                            cause += (f"{device}.{q.quantity} ({unit or 'a flag or count'}) "
                                      f"is bound to 0x{q.ref.index:04X} ({q.ref.name}), an "
                                      f"object in {unit_of}: a wrong object")
                        else:
                            cause += likely_cause(got / expected)
                    out.append(Check(device, q.quantity, f"conversion of 0x{q.ref.index:04X} "
                                     f"vs the device's scaling object {label}", got, expected,
                                     SCALE_REL, "SI per count (relative limit)",
                                     margin * abs(expected), verdict, cause,
                                     text.format(v=v, x=expected)))
        other = {k: v for k, v in scaling.items() if k not in {r[0] for r in
                                                                  RULES.get(spec.profile, [])}}
        if other:
            out.append(Check("/".join(spec.devices), f"node {spec.node_id}",
                             "other scaling objects (reported)", None, None, None, "", None,
                             "INFO", why=", ".join(f"{k} = {v}" for k, v in other.items())))
    return out
