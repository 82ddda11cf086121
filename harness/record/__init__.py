"""Recording and replay: what a run leaves on disk and how it is read back.

``recording`` streams a run's channels to Rerun (.rrd) in blocks, ``reader`` reads a
recording back chunk by chunk (also one cut short by a SIGKILL), ``can_log`` writes the raw
CAN log (can.blf) and ``replay`` puts a CAN log back through the drivers. ``recording``,
``reader`` and ``can_log`` import nothing of ``harness.core`` or ``harness.bus`` (the
recorder uses ``harness.review``'s names and events, lazily). ``replay`` is the exception:
it re-runs a run's controller and monitor as the run built them, so it imports
``harness.bus.rig_interface`` and ``harness.core`` (``monitor``, ``runs``, and
``session.make_monitor`` lazily).
"""
