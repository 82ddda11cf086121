"""Recording and replay: what a run leaves on disk and how it is read back.

``recording`` streams a run's channels to Rerun (.rrd) in blocks, ``reader`` reads a
recording back chunk by chunk (also one cut short by a SIGKILL or a full disk), ``can_log``
writes the raw CAN log (can.blf), ``append`` adds to a finished recording (the verdict into
run.rrd), ``streams`` frees Rerun's recording and blueprint streams once done (many runs in
one process), ``output`` tells a full or failing output folder from a bug (``OutputError``,
the free-space guard, atomic writes, no write through a link), ``summary_file`` reads a
summary.json of any shape, ``run_folder`` reads a run folder's config.yaml and side files
(identify.json) checked, for every reader of a run folder (the twin, the scatter, replay).
They import nothing of ``harness.core``, ``harness.bus`` or ``harness.review``: the review
layer's names, event markers and summary text come in as the recorder's ``Annotator``,
handed in by the caller. Replaying a log, which re-runs a run's controller and monitor, is
``harness.core.replay``.
"""
