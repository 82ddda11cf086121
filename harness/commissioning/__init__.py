"""`harness commission`: proves a rig file's bindings by the physics (docs/commission.md).

``plan`` (the two runs: sensors at rest, then a short scripted excitation of every bound
device), ``estimates`` (pure: the rig's model measured from arrays, value and 1-sigma),
``model`` (the measured model: a row per rig-file key, PASS / DIFFERS against the file's
tolerance, and the model the bindings are judged with), ``checks`` (each device's
quantities against the physics, as criteria: value, expected, limit, margin, verdict, the
likely cause of a miss), ``analysis`` (the checks of the two recordings), ``scaling``
(CANopen devices' own scaling objects against the rig file's conversions), ``report``
(commission.json, report.html, commission.rrd), ``rig_writer`` (``--write-rig``) and
``workflow`` (the runs, in order).

May import: ``harness.core`` (the runs, through ``execute_run``), ``harness.record``,
``harness.history.twin`` (the rig model's response to the recorded commands),
``harness.identification`` (the ring-down's modes), ``harness.controllers``, ``drivers``,
``rig_models``. Never ``harness.commands``.
"""
