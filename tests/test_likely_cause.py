"""One cause, named once, whatever the tolerances: the factor nearest in log, judged against
the ratio's noise (and a capped model tolerance), never read from a loose band; a ratio near
0 is "no response" at any tolerance; tolerances a lab cannot mean are refused."""

from __future__ import annotations

import pytest

from harness.core.plausibility import likely_cause
from rig_models.rig_file import load_rig, rig_from_dict
from rig_models.schema import ConfigError


@pytest.mark.parametrize("ratio, se, tol, words, not_words", [
    (-1.0, 0.01, 1.0, "a sign (", "1000"),             # a reversed sign, loose tolerance
    (-0.98, 0.01, 0.5, "a sign (", "factor"),
    (9.81, 0.01, 0.5, "a factor of g (g read", "rpm"),   # g read as m/s^2, not 60/(2 pi)
    (9.55, 0.01, 0.5, "60/(2 pi)", "g read"),
    (0.0, 0.01, 1.0, "no response", "factor"),         # nothing at any tolerance
    (1e-4, 0.0, 1.0, "no response", "factor"),
    (0.001, 1e-5, 0.05, "1/1000", "no response"),
    (57.0, 0.5, 0.05, "180/pi", "no response"),
    (3.3, 0.01, 0.05, "a factor of 3.3", "no response"),
    (0.02, 0.1, 0.05, "pi/180", "1000"),               # noisy, on pi/180 all the same
])
def test_the_nearest_factor_is_named_against_the_noise(ratio, se, tol, words, not_words):
    cause = likely_cause(ratio, se, tol)
    assert words in cause and not_words not in cause, cause


@pytest.mark.parametrize("key", ["inertia_fraction", "torque_fraction", "couple_fraction",
                                 "modal_fraction", "speed_fraction"])
def test_a_tolerance_whose_band_holds_zero_is_refused_naming_it(key):
    data = dict(load_rig("sgsrt").data)
    data["tolerances"] = dict(data["tolerances"], **{key: 1.0})
    with pytest.raises(ConfigError, match=f"tolerances.{key}"):
        rig_from_dict(data, source="rig file loose.yaml")
