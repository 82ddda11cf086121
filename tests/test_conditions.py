"""The condition language of test sequences: parsing and precedence, units, the errors a run
file's author sees, each temporal form tick by tick, that no Python is ever run, the
descriptions of a decision and the generated reference."""

from __future__ import annotations

import ast
import math
import sys
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from harness.sequences import conditions as cond_module
from harness.sequences.conditions import (
    FALSE,
    FUNCTIONS,
    PENDING,
    TEMPORAL_FORMS,
    TRUE,
    UNITS,
    ConditionError,
    Quantity,
    compile_condition,
    compile_value,
    reference_markdown,
)

DT = 0.002


class Ctx:
    """A tick's view: values in SI by base name, events by name."""

    def __init__(self, **values: float):
        self.t_s = 0.0
        self.values = {"hub.angle": 0.0, "hub.rate": 0.0, "wheel.speed": 0.0,
                       "wheel.torque": 0.0, "tip.accel": 0.0, "rig.safe": 1.0,
                       "valves.state": 0.0, "step.index": 0.0} | values
        self.events: dict[str, float] = {}

    def event_time(self, name: str) -> float | None:
        return self.events.get(name)


def _reader(base: str):
    return lambda ctx: ctx.values[base]


Q = {base: Quantity(dim, _reader(base)) for base, dim in {
    "hub.angle": "angle", "hub.rate": "angular_rate", "wheel.speed": "angular_rate",
    "wheel.torque": "torque", "tip.accel": "acceleration", "rig.safe": "flag",
    "valves.state": "count", "step.index": "count"}.items()}

WHERE = "step 'settle' wait_until"


def cond(text: str):
    return compile_condition(text, Q, WHERE)


def holds(text: str, ctx: Ctx) -> int:
    c = cond(text)
    c.reset(ctx.t_s)
    return c.update(ctx)


def error(text: str) -> str:
    with pytest.raises(ConditionError) as e:
        compile_condition(text, Q, WHERE)
    msg = str(e.value)
    assert msg.startswith(WHERE + ": "), msg
    assert text.replace("\n", " ") in msg, msg  # the text, then a caret under the position
    return msg


# ------------------------------------------------------------------ parsing, precedence


@pytest.mark.parametrize("text, expected", [
    ("1 + 2 * 3 == 7", TRUE),
    ("(1 + 2) * 3 == 9", TRUE),
    ("-2 * 3 == -6", TRUE),
    ("10 - 4 - 3 == 3", TRUE),          # + - associate to the left
    ("12 / 3 / 2 == 2", TRUE),
    ("not true or true", TRUE),         # (not true) or true
    ("not (true or true)", FALSE),
    ("true or true and false", TRUE),   # and binds tighter than or
    ("(true or true) and false", FALSE),
    ("not 1 > 2", TRUE),                # not (1 > 2)
    ("min(3, 1, 2) == 1 and max(3, 1, 2) == 3 and abs(-2) == 2", TRUE),
    ("rig.safe", TRUE),
    ("not rig.safe", FALSE),
    ("rig.safe == true", TRUE),
    ("rig.safe != true", FALSE),
    ("valves.state == 0 and step.index + 1 == 1", TRUE),
    ("2.5e1 == 25 and .5 == 0.5", TRUE),
])
def test_precedence_and_values(text, expected):
    assert holds(text, Ctx()) == expected


def test_the_temporal_form_takes_the_whole_or():
    """``a or b for 2 s`` is ``(a or b) for 2 s``: either holding keeps it running."""
    c = cond("hub.angle_deg > 1 or rig.safe for 10 ms")
    ctx = Ctx()
    c.reset(0.0)
    out = []
    for k in range(6):
        ctx.t_s = k * DT
        out.append(c.update(ctx))
    assert out == [PENDING] * 5 + [TRUE]


def test_parenthesised_temporal_forms_combine_three_valued():
    c = cond("(hub.angle_deg > 1 for 4 ms) and (rig.safe stays true)")
    ctx = Ctx(**{"hub.angle": math.radians(2)})
    c.reset(0.0)
    got = []
    for k in range(4):
        ctx.t_s = k * DT
        if k == 3:
            ctx.values["rig.safe"] = 0.0
        got.append(c.update(ctx))
    # for: P P T T; stays: P P P F  -> and: P P P F
    assert got == [PENDING, PENDING, PENDING, FALSE]
    c2 = cond("(hub.angle_deg > 1 for 4 ms) or (rig.safe stays true)")
    c2.reset(0.0)
    ctx.values["rig.safe"] = 1.0
    got = []
    for k in range(3):
        ctx.t_s = k * DT
        got.append(c2.update(ctx))
    assert got == [PENDING, PENDING, TRUE]


def test_names_events_and_min_time():
    c = cond("(abs(hub.angle_deg - 10) < 0.05 for 2 s) and (rig.safe within 500 ms after fault)")
    assert c.names == {"hub.angle_deg", "rig.safe"}
    assert c.events == {"fault"}
    assert c.min_time_s == pytest.approx(2.0)
    assert cond("hub.angle_deg > 1").min_time_s == 0.0
    assert cond("(rig.safe for 3 s) or (rig.safe for 1 s)").min_time_s == pytest.approx(1.0)
    assert cond("(rig.safe for 1 s) for 2 s").min_time_s == pytest.approx(3.0)
    assert cond("rig.safe stays true").min_time_s == math.inf


# ------------------------------------------------------------------ units


def test_a_unit_literal_is_converted_deg_against_rad():
    ctx = Ctx(**{"hub.angle": math.radians(0.6)})
    assert holds("hub.angle_deg > 0.5 deg", ctx) == TRUE
    assert holds("hub.angle_deg > 0.5", ctx) == TRUE        # 0.5 deg: the name's unit
    assert holds("hub.angle_rad > 0.5", ctx) == FALSE       # 0.5 rad
    assert holds("hub.angle_rad > 0.5 deg", ctx) == TRUE
    assert holds("hub.angle_deg < 0.011 rad", ctx) == TRUE  # 0.63 deg
    assert holds("hub.angle_deg < 0.01 rad", ctx) == FALSE  # 0.57 deg


def test_a_bare_number_takes_its_neighbours_unit():
    ctx = Ctx(**{"hub.angle": math.radians(10.03)})
    assert holds("abs(hub.angle_deg - 10) < 0.05", ctx) == TRUE
    assert holds("abs(hub.angle_deg - 10) < 0.02", ctx) == FALSE
    assert holds("abs(hub.angle_rad - 10) < 0.05", ctx) == FALSE
    assert holds("0.05 > abs(hub.angle_deg - 10)", ctx) == TRUE
    assert holds("0.02 >= abs(hub.angle_deg - 10)", ctx) == FALSE
    assert holds("abs(10 - hub.angle_deg) > 0.02", ctx) == TRUE
    assert holds("abs(hub.angle_deg - 10) <= 0.02 deg", ctx) == FALSE
    assert holds("2 * hub.angle_deg > 20", ctx) == TRUE       # a scale factor keeps deg


def test_rpm_and_other_units():
    ctx = Ctx(**{"wheel.speed": 110.0, "wheel.torque": 0.02, "tip.accel": 0.5})
    assert holds("wheel.speed_rpm > 1000", ctx) == TRUE       # 110 rad/s = 1050 rpm
    assert holds("wheel.speed_rpm > 1100", ctx) == FALSE
    assert holds("wheel.speed_rad_s > 1000 rpm", ctx) == TRUE
    assert holds("wheel.speed_rad_s > 1100 rpm", ctx) == FALSE
    assert holds("wheel.torque_mn_m == 20", ctx) == TRUE
    assert holds("tip.accel_g < 0.051 and tip.accel_g > 0.050", ctx) == TRUE


def test_values_come_back_in_their_written_unit():
    ctx = Ctx(**{"wheel.speed": 2 * math.pi, "hub.angle": math.radians(10)})
    v = compile_value("wheel.speed_rpm", Q, "step 'spin' record")
    assert (v.unit, v.dimension) == ("rpm", "angular_rate")
    assert v.evaluate(ctx) == pytest.approx(60.0)
    v = compile_value("hub.angle_deg - 0.1 rad / 2", Q, "x")
    assert v.unit == "deg"
    assert v.evaluate(ctx) == pytest.approx(10 - math.degrees(0.05))
    assert compile_value("10 deg + 5", Q, "x").evaluate(ctx) == pytest.approx(15.0)
    assert compile_value("3 * 4", Q, "x").evaluate(ctx) == 12.0
    assert compile_value("step.index + 1", Q, "x").unit == ""
    with pytest.raises(ConditionError, match="expected a value"):
        compile_value("hub.angle_deg > 1", Q, "x")


# ------------------------------------------------------------------ errors


def test_unknown_name_lists_close_matches():
    msg = error("hub.angel_deg > 1")
    assert "unknown name hub.angel_deg" in msg
    assert "did you mean hub.angle_deg" in msg
    assert "\n    ^" in msg  # the caret under column 1


def test_a_unit_of_another_dimension():
    msg = error("hub.angle_rad_s > 1")
    assert "hub.angle_rad_s: hub.angle is an angle" in msg
    assert "write hub.angle_deg or hub.angle_rad" in msg


def test_a_unit_on_a_flag_or_count():
    assert "rig.safe is a flag and takes no unit; write rig.safe" in error("rig.safe_s")
    assert "valves.state is a count" in error("valves.state_deg > 1")


def test_a_missing_unit():
    msg = error("hub.angle > 1")
    assert "hub.angle is an angle and needs its unit: write hub.angle_deg or hub.angle_rad" \
        in msg


def test_dimensions_that_differ():
    msg = error("hub.angle_deg + 1 s > 0")
    assert "hub.angle_deg (an angle) and 1 s (a time)" in msg
    assert "hub.angle_deg (an angle) and hub.rate_deg_s (an angular rate)" in \
        error("hub.angle_deg < hub.rate_deg_s")
    assert "one side must be dimensionless" in error("hub.angle_deg * hub.rate_deg_s > 1")
    assert "a divisor must be dimensionless" in error("hub.angle_deg / hub.angle_deg > 1")
    assert "division by zero" in error("hub.angle_deg / 0 > 1")


def test_a_flag_against_a_number_and_a_number_as_a_condition():
    assert "compare a flag with true or false" in error("rig.safe > 0")
    assert "expected a condition, found the value hub.angle_deg" in error("hub.angle_deg")
    assert "expected a condition, found the number 5" in error("5")
    assert "and needs a condition" in error("rig.safe and 5")
    assert "rig.safe is a flag: use it as a condition" in error("hub.angle_deg - rig.safe > 1")
    assert "- needs a value, found the condition (1 > 0)" in error("hub.angle_deg - (1 > 0) > 1")


def test_durations_need_a_time_unit():
    assert "for needs a duration with a time unit" in error("rig.safe for 2")
    assert "found 2 deg" in error("rig.safe for 2 deg")
    assert "within needs a duration" in error("rig.safe within 0.5 after fault")
    assert "expected 'after'" not in error("rig.safe within 0.5 s fault")
    assert "after EVENT" in error("rig.safe within 0.5 s fault")


@pytest.mark.parametrize("text, expected", [
    ("0 < hub.angle_deg < 1", "chained comparison"),
    ("rig.safe for 2 s and rig.safe", "in parentheses"),
    ("rig.safe becomes false", "expected true after becomes"),
    ("hub.angle_deg > 1 rig.safe", "expected an operator or the end"),
    ("(hub.angle_deg > 1", "closing )"),
    ("10 degrees > 1", "degrees after 10 is not a unit"),
    ("sqrt(2) > 1", "unknown function sqrt"),
    ("", "empty"),
    ("hub.angle_deg = 1", "compare with =="),
    ("rig.safe && rig.safe", "combine with and"),
    ("hub.angle_deg > ${angle}", "${variable}"),
    ("rig.safe < true", "only == and != compare them"),
])
def test_syntax_errors_say_what_was_expected(text, expected):
    with pytest.raises(ConditionError) as e:
        compile_condition(text, Q, WHERE)
    assert expected in str(e.value)
    assert e.value.where == WHERE and e.value.text == text


def test_the_caret_points_at_the_position():
    with pytest.raises(ConditionError) as e:
        compile_condition("rig.safe and hub.angel_deg > 1", Q, WHERE)
    assert e.value.position == 13
    lines = str(e.value).splitlines()
    assert "(column 14)" in lines[0]
    assert lines[2].index("^") == lines[1].index("hub.angel_deg")


# ------------------------------------------------------------------ no Python


@pytest.mark.parametrize("text", [
    "__import__('os')",
    "__import__('os').system('true')",
    "rig.safe.__class__",
    "hub.angle_deg.real > 1",
    "open",
    "hub.angle_deg[0] > 1",
    "(lambda: 1)()",
    "lambda x: x",
    "'a' == 'a'",
    '"rig.safe"',
    "True",
    "None",
    "1 if rig.safe else 0",
    "[x for x in ()]",
    "2 ** 3 > 1",
    "rig.safe; import os",
    "eval(1)",
    "exec(1)",
    "print(1)",
    "abs.__self__",
])
def test_python_is_not_run(text):
    with pytest.raises(ConditionError):
        compile_condition(text, Q, WHERE)


def test_the_module_imports_only_the_standard_library():
    path = Path(cond_module.__file__)
    tree = ast.parse(path.read_text(encoding="utf-8"))
    roots = {a.name.split(".")[0] for n in ast.walk(tree) if isinstance(n, ast.Import)
             for a in n.names}
    roots |= {n.module.split(".")[0] for n in ast.walk(tree)
              if isinstance(n, ast.ImportFrom) and n.module and n.level == 0}
    assert roots - {"__future__"} <= set(sys.stdlib_module_names), roots
    assert "ast" not in roots
    called = {n.func.id for n in ast.walk(tree)
              if isinstance(n, ast.Call) and isinstance(n.func, ast.Name)}
    assert not called & {"eval", "exec", "compile", "__import__", "getattr"}, called


# ------------------------------------------------------------------ temporal forms


def _run(c, ctx: Ctx, ticks: int, change=None, t0: float = 0.0) -> list[int]:
    c.reset(t0)
    out = []
    for k in range(ticks):
        ctx.t_s = t0 + k * DT
        if change:
            change(k, ctx)
        out.append(c.update(ctx))
    return out


def test_for_is_true_on_the_tick_it_reaches_the_duration():
    c = cond("abs(hub.angle_deg - 10) < 0.05 for 2 s")
    ctx = Ctx(**{"hub.angle": math.radians(10.01)})
    out = _run(c, ctx, 1002)
    assert out[:1000] == [PENDING] * 1000  # held 0 .. 1.998 s
    assert out[1000] == TRUE               # held exactly 2 s
    assert out[1001] == TRUE


def test_for_on_accumulated_time_still_reaches_the_boundary():
    """A clock summing dt drifts by rounding; the tick at 2 s still counts."""
    c = cond("rig.safe for 2 s")
    ctx = Ctx()
    c.reset(0.3)
    t, out = 0.3, []
    for _ in range(1001):
        ctx.t_s = t
        out.append(c.update(ctx))
        t += DT
    assert out[-2:] == [PENDING, TRUE]


def test_for_starts_again_when_the_condition_fails():
    c = cond("hub.angle_deg > 1 for 10 ms")  # 5 ticks of 2 ms

    def change(k, ctx):
        ctx.values["hub.angle"] = math.radians(0 if k == 3 else 2)

    out = _run(c, Ctx(), 12, change)
    # true 0..2, false at 3, true from 4: reaches 10 ms at tick 9
    assert out == [PENDING] * 9 + [TRUE] * 3
    c.reset(1.0)  # a step's start clears the held time
    ctx = Ctx(**{"hub.angle": math.radians(2)})
    ctx.t_s = 1.0
    assert c.update(ctx) == PENDING


def test_becomes_true_is_the_rising_edge_only():
    c = cond("wheel.speed_rad_s > 100 becomes true")
    speeds = [120, 120, 90, 95, 101, 130, 80, 110]

    def change(k, ctx):
        ctx.values["wheel.speed"] = speeds[k]

    # the first tick has no previous value: 120 at tick 0 is no edge
    assert _run(c, Ctx(), len(speeds), change) == [FALSE, FALSE, FALSE, FALSE, TRUE, FALSE,
                                                   FALSE, TRUE]


def test_stays_true_latches_false():
    c = cond("rig.safe stays true")
    safe = [1, 1, 0, 1, 1]

    def change(k, ctx):
        ctx.values["rig.safe"] = safe[k]

    assert _run(c, Ctx(), 5, change) == [PENDING, PENDING, FALSE, FALSE, FALSE]
    assert _run(c, Ctx(), 2) == [PENDING, PENDING]  # reset clears the latch


def test_within_after_true_in_time():
    c = cond("rig.safe within 0.5 s after injected")
    ctx = Ctx(**{"rig.safe": 0.0})

    def change(k, ctx):
        if k == 10:
            ctx.events["injected"] = ctx.t_s          # at 0.02 s
        if k == 60:
            ctx.values["rig.safe"] = 1.0              # 0.1 s after it
        if k == 70:
            ctx.values["rig.safe"] = 0.0              # later failures: the decision is kept

    out = _run(c, ctx, 80, change)
    assert out[:60] == [PENDING] * 60
    assert out[60:] == [TRUE] * 20
    assert "true at 0.120 s, 0.100 s after injected" in c.describe(ctx)


def test_within_after_true_on_the_last_tick_of_the_window():
    c = cond("rig.safe within 100 ms after injected")
    ctx = Ctx(**{"rig.safe": 0.0})

    def change(k, ctx):
        if k == 0:
            ctx.events["injected"] = 0.0
        ctx.values["rig.safe"] = 1.0 if k == 50 else 0.0  # exactly at 0.1 s

    out = _run(c, ctx, 52, change)
    assert out[:50] == [PENDING] * 50 and out[50:] == [TRUE, TRUE]


def test_within_after_false_when_late():
    c = cond("rig.safe within 100 ms after injected")
    ctx = Ctx(**{"rig.safe": 0.0})

    def change(k, ctx):
        if k == 0:
            ctx.events["injected"] = 0.0
        ctx.values["rig.safe"] = 1.0 if k >= 51 else 0.0  # 0.102 s: one tick late

    out = _run(c, ctx, 55, change)
    assert out[:51] == [PENDING] * 51
    assert out[51:] == [FALSE] * 4
    assert "injected at 0.000 s; not true by 0.100 s" in c.describe(ctx)


def test_within_after_pending_without_the_event_and_before_the_reset():
    c = cond("rig.safe within 100 ms after injected")
    ctx = Ctx()
    assert _run(c, ctx, 100) == [PENDING] * 100
    assert "injected has not happened" in c.describe(ctx)
    ctx.events["injected"] = 0.5   # before the step started at 1 s: not this step's event
    assert _run(c, ctx, 100, t0=1.0) == [PENDING] * 100
    ctx.events["injected"] = 1.0   # at the step's start: counts
    assert _run(c, ctx, 1, t0=1.0) == [TRUE]


def test_temporal_operands_are_evaluated_every_tick():
    """A nested temporal form keeps its state though the outer one short-circuits nothing."""
    c = cond("(rig.safe for 4 ms) becomes true")
    out = _run(c, Ctx(), 4)
    assert out == [FALSE, FALSE, TRUE, FALSE]


# ------------------------------------------------------------------ describe


def test_describe_for():
    c = cond("abs(hub.angle_deg - 10) < 0.05 for 2 s")
    ctx = Ctx(**{"hub.angle": math.radians(10.031)})
    _run(c, ctx, 701)
    assert c.describe(ctx) == "abs(hub.angle_deg - 10) = 0.031 deg; held 1.40 s of 2 s"
    ctx.values["hub.angle"] = math.radians(11)
    c.update(ctx)
    assert c.describe(ctx) == "abs(hub.angle_deg - 10) = 1 deg; not holding; needs 2 s"


def test_describe_uses_the_written_units():
    ctx = Ctx(**{"wheel.speed": 2 * math.pi, "rig.safe": 0.0, "valves.state": 3})
    c = cond("wheel.speed_rpm > 100 or rig.safe or valves.state == 1")
    c.update(ctx)
    assert c.describe(ctx) == "wheel.speed_rpm = 60 rpm; rig.safe = false; valves.state = 3"
    c = cond("wheel.speed_rad_s < hub.rate_deg_s")
    assert c.describe(ctx) == "wheel.speed_rad_s = 6.283 rad/s; hub.rate_deg_s = 0 deg/s"


def test_describe_becomes_and_stays():
    c = cond("wheel.speed_rad_s > 100 becomes true")
    ctx = Ctx(**{"wheel.speed": 50.0})
    _run(c, ctx, 3)
    assert c.describe(ctx) == "wheel.speed_rad_s = 50 rad/s; no rising edge"
    ctx.values["wheel.speed"] = 150.0
    ctx.t_s = 0.01
    assert c.update(ctx) == TRUE
    assert c.describe(ctx) == "wheel.speed_rad_s = 150 rad/s; became true at 0.010 s"
    c = cond("rig.safe stays true")
    ctx = Ctx(**{"rig.safe": 0.0})
    _run(c, ctx, 3, t0=2.0)
    assert c.describe(ctx) == "rig.safe = false; false at 2.000 s"


# ------------------------------------------------------------------ reference


def test_reference_names_every_unit_function_and_temporal_form():
    md = reference_markdown()
    for unit in UNITS:
        assert f"`{unit}`" in md, unit
    for name in FUNCTIONS:
        assert f"`{name}`" in md, name
    for form in ("C for D", "C becomes true", "C stays true", "C within D after EVENT"):
        assert f"`{form}`" in md, form
    assert len(TEMPORAL_FORMS) == 4
    for op in ("`or`", "`and`", "`not`", "`<=`", "`!=`", "`*`"):
        assert op in md, op


# ------------------------------------------------------------------ hostile text


def test_deep_nesting_is_bad_text_not_a_crash():
    for text in ("(" * 5000 + "rig.safe" + ")" * 5000, "-" * 5000 + "1 > 0",
                 "not " * 5000 + "rig.safe"):
        with pytest.raises(ConditionError, match="nested too deeply"):
            compile_condition(text, Q, WHERE)


def test_a_division_by_a_zero_reading_is_nan_not_an_exception():
    c = cond("hub.angle_deg / valves.state > 1")
    assert c.update(Ctx(**{"hub.angle": 1.0, "valves.state": 0.0})) == FALSE
    assert c.update(Ctx(**{"hub.angle": 1.0, "valves.state": 2.0})) == TRUE


_PIECES = ["hub.angle_deg", "rig.safe", "wheel.speed_rpm", "valves.state", "1", "0.5",
           " deg", " s", " ms", "(", ")", ",", "+", "-", "*", "/", "<", ">=", "==", " and ",
           " or ", "not ", " for ", " becomes ", " stays ", " within ", " after ", "fault",
           "true", "abs(", "min(", "'", "[", "_", ".", "$", "lambda"]


@settings(max_examples=300, deadline=None)
@given(st.lists(st.sampled_from(_PIECES), max_size=14))
def test_any_text_compiles_or_is_a_condition_error(pieces):
    """Whatever the text, compiling it gives a condition that updates and describes, or a
    ConditionError: never another exception."""
    text = "".join(pieces)
    try:
        c = compile_condition(text, Q, WHERE)
    except ConditionError:
        return
    ctx = Ctx()
    ctx.events["fault"] = 0.0
    c.reset(0.0)
    for k in range(3):
        ctx.t_s = k * DT
        assert c.update(ctx) in (TRUE, FALSE, PENDING)
    assert isinstance(c.describe(ctx), str)
