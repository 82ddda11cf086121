"""Recording and replay: what a run leaves on disk and how it is read back.

``recording`` streams a run's channels to Rerun (.rrd) in blocks, ``reader`` reads a
recording back chunk by chunk (also one cut short by a SIGKILL), ``can_log`` writes the raw
CAN log (can.blf). They import nothing of ``harness.core`` or ``harness.bus`` (the recorder
uses ``harness.review``'s names and events, lazily); replaying a log, which re-runs a run's
controller and monitor, is ``harness.core.replay``.
"""
