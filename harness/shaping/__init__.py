"""Input shapers and the sequences they give: impulse shapers (ZV, ZVD, EI), their robust
and variable-amplitude kinds, CSVS and the two-amplitude fuel-efficient shapers (LHHL, HLLH).

Pure: numbers in, impulse sequences out. It may import ``rig_models`` (the rig's figures);
no package of the harness.
"""
