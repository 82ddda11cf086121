"""What a reviewer sees in the Rerun viewer: default layouts per kind of run, events and their
markers on the plots, the run's summary as text, and the CAN bus decoded into the recording.

Depends on ``harness.loop``'s channel names and the DBC only; see docs/review.md.
"""
