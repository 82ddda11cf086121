"""Test sequences in the tick: conditions (pure: imports only the standard library), the
language a run file's ``sequence:`` steps write their conditions and computed values in.
``conditions`` parses a condition or a value once and compiles it to closures that a tick
calls, so reading a condition never runs code from the run file.
"""
