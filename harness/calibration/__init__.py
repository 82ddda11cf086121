"""`harness calibrate`: from the rig's vibration to a verified shaped slew (see
docs/calibrate.md). ``plan`` (excitation, pure), ``candidates`` (shaper design and scoring,
pure), ``residual`` (residual readings, pure), ``workflow`` (the runs), ``report``."""
