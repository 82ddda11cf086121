"""One run: the loop and what a tick needs.

``runs`` parses a run file (the built-in ones stay in ``harness/runs/*.yaml``), ``session``
runs one end to end, ``loop`` is the tick, ``clock`` its lockstep and real-time clocks,
``monitor`` the fault monitor, ``probe`` the pre-flight check of the rig's bus, ``replay``
a CAN log back through the drivers and the run's own controller and monitor, ``frf`` the
frequency responses of a recorded run and the modes fitted to them, ``streaming``
the bounded-memory statistics, ``periodic`` the steady-state amplitude in a run's summary,
``interrupts`` Ctrl-C / SIGTERM handling, ``paths`` the guard that keeps every written
file inside the output folder, ``identify`` the identification of a recorded run (its
free-decay windows from the run's controller, identify.rrd), ``builtin_runs`` the
built-in run files' names (light: ``harness cases``) and ``plausibility`` the pure rules
that hold a run's sensors to the physics (when a repeated reading is stuck, from the
sensor's resolution and noise in the rig file; the likely cause of a ratio far from 1). It
may import ``harness.bus``, ``harness.record``, ``harness.review``, ``harness.state``,
``rig_models``, ``drivers`` and the pure packages (``controllers``, ``shaping``,
``identification``); ``harness.bus`` and ``harness.record`` never import it. ``runs``
calls ``harness.testing.criteria`` lazily to refuse bad criteria before a run.
"""
