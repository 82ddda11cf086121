"""Test sequences in the tick. Pure: imports ``harness.state`` and ``rig_models`` (the fault
kinds), nothing of the bus, the recording or the loop.

``conditions`` is the condition language (standard library only): a condition or a value
parsed once and compiled to closures a tick calls, so reading one never runs code from the
run file. ``quantities`` names what a condition may read (state, command, reference, step
and run time, the harness's flags) with its SI dimension. ``spec`` parses and checks a run
file's ``sequence:`` before anything is sent. ``runner`` is the sequence in the tick: the
run's controller wrapped by its steps (docs/sequences.md).
"""
