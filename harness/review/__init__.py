"""What a reviewer sees in the Rerun viewer: default layouts per kind of run, events and their
markers on the plots, the run's summary as text, the CAN bus decoded into the recording, and
each plotted series' legend name, colour and aggregation (``names``), the verdict in run.rrd
(``verdict``), units as written (``units``) and the recorder's ``Annotator``
(``annotations``).

May import ``harness.record``, ``harness.identification`` (results it draws) and the DBC
(``drivers``); never ``harness.core`` or ``harness.testing`` (they import it): channel
names are the entity paths themselves, recorded channels come from layout.json. See
docs/review.md.
"""
