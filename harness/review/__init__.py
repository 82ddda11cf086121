"""What a reviewer sees in the Rerun viewer: default layouts per kind of run, events and their
markers on the plots, the run's summary as text, the CAN bus decoded into the recording, and
short legend names for every plotted series (``names``).

Depends on ``harness.core.loop``'s channel names and the DBC only; see docs/review.md.
"""
