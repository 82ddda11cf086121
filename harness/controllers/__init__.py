"""The controllers: what a tick commands from the rig's state (``registry`` maps a run file's
``controller.type`` to one, with its schema).

Pure: the tick's arithmetic, no bus, no recording, no files. It may import
``harness.shaping`` (the shapers a slew is convolved with), ``harness.state`` (the state in
and the command out) and ``rig_models`` (the rig's figures and the schema); no other package
of the harness.
"""
