"""The rig's health over time: a results database and what reads it.

``db`` (the database: SQLite beside the logs by default, PostgreSQL by URL), ``record``
(what a judged run, a suite, an identification or a calibration adds to it; the import of
runs already on disk), ``drift`` (control charts and drift alarms with uncertainty: pure),
``scatter`` (the virtual rig's predicted scatter of each criterion, flaky or real),
``series`` (a series across runs, one test on one rig under one run configuration, as a
table, JSON, a PNG and a page), ``times`` (``--since`` / ``--until`` read as instants) and
``twin`` (a recorded run's commands through the virtual rig's physics: the twin's
residual).

It may import ``harness.testing``, ``harness.identification``, ``harness.core`` (scatter
and twin run the virtual rig), ``harness.record``, ``harness.calibration`` and
``rig_models``; only ``harness.commands`` and the few hooks that record a result (the run's
and judge's verdict, a suite's report, identify, calibrate) import it, each lazily.
"""

DEFAULT_K = 3.0
"""Alarm threshold in standard uncertainties (``drift``'s default, and ``harness history``'s
``--k``; kept here so the command's help needs no numpy)."""
DEFAULT_N_REF = 5
"""Reference points of a control chart (``--n-ref``)."""
DEFAULT_N_TREND = 5
"""Points of the trend window (``--n-trend``)."""
