"""The condition language of test sequences: conditions and values over the rig's named
quantities, with units and temporal forms, parsed once and compiled to nested closures.

Imports only the standard library. The text is read by this module's own tokenizer and
recursive-descent parser; nothing of it reaches Python's ``eval``, ``exec`` or ``ast``, so a
condition in a run file can read quantities, do arithmetic and compare, and nothing else.

A name is a quantity's base name with its unit suffix (``hub.angle_deg``, ``wheel.speed_rpm``)
or, for a count or a flag, the base name alone (``rig.safe``). Every value carries a
dimension and is computed in SI; the units the text is written in come back only at the
edges (``describe``, ``Value.evaluate``). A bare number beside a dimensioned operand takes
that operand's unit: in ``abs(hub.angle_deg - 10) < 0.05`` both 10 and 0.05 are degrees.

Temporal forms (``for``, ``becomes true``, ``stays true``, ``within .. after``) keep state
between ticks, cleared by ``Condition.reset`` at a step's start; they give TRUE, FALSE or
PENDING (three-valued: ``and``, ``or`` and ``not`` combine them as Kleene's logic does, with
PENDING as unknown). A temporal form's operand counts as holding only when it is TRUE.

``update`` costs a handful of closure calls a tick: no tree is walked and nothing is
allocated beyond the floats the quantities' readers return. ``reference_markdown`` writes
the grammar from the tables below, so the docs and the language cannot drift apart.
"""

from __future__ import annotations

import difflib
import keyword
import math
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, Protocol

TRUE, FALSE, PENDING = 1, 0, -1

DIMENSIONS: dict[str, str] = {
    "angle": "a rotation angle",
    "angular_rate": "an angular rate",
    "angular_acceleration": "an angular acceleration",
    "torque": "a torque",
    "force": "a force",
    "length": "a length or a displacement",
    "acceleration": "a linear acceleration",
    "voltage": "a voltage",
    "time": "a time or a duration",
    "frequency": "a frequency",
    "count": "a count or a dimensionless number (no unit)",
    "flag": "a boolean: true or false (no unit; a condition by itself)",
}

UNITS: dict[str, tuple[str, float]] = {
    "deg": ("angle", math.pi / 180.0),
    "rad": ("angle", 1.0),
    "deg_s": ("angular_rate", math.pi / 180.0),
    "rad_s": ("angular_rate", 1.0),
    "rpm": ("angular_rate", 2.0 * math.pi / 60.0),
    "deg_s2": ("angular_acceleration", math.pi / 180.0),
    "rad_s2": ("angular_acceleration", 1.0),
    "n_m": ("torque", 1.0),
    "mn_m": ("torque", 1e-3),
    "n": ("force", 1.0),
    "mn": ("force", 1e-3),
    "m": ("length", 1.0),
    "mm": ("length", 1e-3),
    "m_s2": ("acceleration", 1.0),
    "g": ("acceleration", 9.80665),
    "v": ("voltage", 1.0),
    "s": ("time", 1.0),
    "ms": ("time", 1e-3),
    "hz": ("frequency", 1.0),
}
"""Unit word -> (dimension, SI value of one unit). Names end in these words (``_deg_s``);
numbers are followed by them (``0.5 deg``, ``100 rpm``, ``2 s``)."""

UNIT_LABELS: dict[str, str] = {
    "deg": "deg", "rad": "rad", "deg_s": "deg/s", "rad_s": "rad/s", "rpm": "rpm",
    "deg_s2": "deg/s^2", "rad_s2": "rad/s^2", "n_m": "N m", "mn_m": "mN m", "n": "N",
    "mn": "mN", "m": "m", "mm": "mm", "m_s2": "m/s^2", "g": "g", "v": "V", "s": "s",
    "ms": "ms", "hz": "Hz",
}
"""How ``describe`` writes a value's unit."""

OPERATORS: tuple[tuple[str, str], ...] = (
    ("`C for D`, `C becomes true`, `C stays true`, `C within D after EVENT`",
     "temporal forms (postfix, lowest precedence: parenthesise one to combine it)"),
    ("`or`", "either condition"),
    ("`and`", "both conditions"),
    ("`not`", "the negation of a condition"),
    ("`<` `<=` `>` `>=` `==` `!=`",
     "one comparison of two values of the same dimension (no chains: combine with `and`); "
     "`==` and `!=` also compare two conditions"),
    ("`+` `-`", "sum and difference of two values of the same dimension"),
    ("`*` `/`", "product and quotient with a dimensionless side (a scale factor or a count)"),
    ("unary `-`", "negation of a value"),
    ("atoms", "a number with an optional unit (`10`, `0.5 deg`, `100 rpm`), a name "
     "(`hub.angle_deg`, `rig.safe`), `true`, `false`, a function call, `( ... )`"),
)
"""The grammar's levels, lowest precedence first."""

FUNCTIONS: dict[str, str] = {
    "abs": "`abs(x)`: the magnitude of x, in x's unit",
    "min": "`min(a, b, ...)`: the least of values of one dimension",
    "max": "`max(a, b, ...)`: the greatest of values of one dimension",
}

TEMPORAL_FORMS: dict[str, str] = {
    "for": "`C for D`: TRUE once C has held continuously for D (the tick it reaches D "
           "counts), PENDING before; it starts again whenever C fails. D is a duration "
           "with a time unit (`2 s`, `500 ms`).",
    "becomes true": "`C becomes true`: TRUE on a tick where C holds and did not on the tick "
                    "before, FALSE otherwise; the first tick after a step's start has no "
                    "tick before it, so it is no edge.",
    "stays true": "`C stays true`: FALSE (latched) from the first tick C does not hold, "
                  "PENDING until then: it never becomes TRUE, so it is for `verify:`, "
                  "which fails on FALSE only.",
    "within after": "`C within D after EVENT`: PENDING until EVENT happens (at or after the "
                    "step's start); then TRUE (latched) on the first tick C holds at or "
                    "before EVENT + D, FALSE (latched) once the time passes EVENT + D "
                    "without it.",
}

_TIME_EPS = 1e-9
"""Slack on time comparisons: a tick at k * dt reaches a duration despite rounding."""


class ConditionError(ValueError):
    """Bad condition text: the message names where it is, the text, the position (with a
    caret line) and what was expected."""

    def __init__(self, where: str, text: str, position: int | None, detail: str):
        self.where, self.text, self.position, self.detail = where, text, position, detail
        head = f"{where}: {detail}"
        if position is not None:
            head += f" (column {position + 1})"
        shown = re.sub(r"\s", " ", text)
        lines = [head, "    " + shown]
        if position is not None:
            lines.append("    " + " " * position + "^")
        super().__init__("\n".join(lines))


@dataclass(frozen=True)
class Quantity:
    """A name a condition may read."""

    dimension: str
    """One of ``DIMENSIONS``."""
    read: Callable[[Any], float]
    """ctx -> the value in SI (a flag as 0.0 / 1.0, a count as n)."""
    doc: str = ""


class Context(Protocol):
    """What a condition reads besides its quantities."""

    t_s: float
    """The run time (s)."""

    def event_time(self, name: str) -> float | None:
        """The latest time the event ``name`` happened, None if not yet."""
        ...


Fn = Callable[[Any], Any]


class Condition:
    """A compiled condition. ``update`` is the compiled closure itself (set on each
    instance, so a tick's call costs no method dispatch)."""

    def __init__(self, text: str, names: frozenset[str], events: frozenset[str],
                 min_time_s: float, update: Fn, resets: tuple[Callable[[float], None], ...],
                 describe: Callable[[Any], list[str]]):
        self.text = text
        self.names = names
        """The quantities' names as written (``hub.angle_deg``)."""
        self.events = events
        """The events named after ``after``."""
        self.min_time_s = min_time_s
        """The least time from ``reset`` it can take to become TRUE: the ``for`` durations
        on its way (the largest of an ``and``, the least of an ``or``); ``math.inf`` when it
        can never be TRUE (a ``stays true``)."""
        self.update = update  # type: ignore[method-assign]
        self._resets = resets
        self._describe = describe

    def reset(self, t_s: float) -> None:
        """Clear the temporal state: called at a step's start, ``t_s`` its time."""
        for r in self._resets:
            r(t_s)

    def update(self, ctx: Context) -> int:  # replaced on each instance by the closure
        """Once a tick: TRUE, FALSE or PENDING."""
        raise NotImplementedError

    def describe(self, ctx: Context) -> str:
        """Its values now (at the decision), in the units written, and its temporal state:
        ``abs(hub.angle_deg - 10) = 0.031 deg; held 1.40 s of 2 s``."""
        parts = list(dict.fromkeys(self._describe(ctx)))
        return "; ".join(parts) if parts else "constant"

    def __repr__(self) -> str:
        return f"Condition({self.text!r})"


class Value:
    """A compiled arithmetic expression: ``evaluate(ctx)`` gives it in the unit it is
    written in (``unit``, a key of ``UNITS``, or "" for a count or a plain number)."""

    def __init__(self, text: str, names: frozenset[str], unit: str, dimension: str,
                 evaluate: Fn):
        self.text = text
        self.names = names
        self.unit = unit
        self.dimension = dimension
        self.evaluate = evaluate  # type: ignore[method-assign]

    def evaluate(self, ctx: Context) -> float:  # replaced on each instance by the closure
        """Its value now, in ``unit``."""
        raise NotImplementedError

    def __repr__(self) -> str:
        return f"Value({self.text!r})"


# ------------------------------------------------------------------ tokens

_TOKEN = re.compile(r"""
    (?P<ws>\s+)
  | (?P<num>(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?)
  | (?P<name>[A-Za-z_][A-Za-z0-9_]*(?:\.[A-Za-z_][A-Za-z0-9_]*)*)
  | (?P<op><=|>=|==|!=|[<>+\-*/(),])
""", re.VERBOSE)

_CHAR_HINTS = {
    "'": "strings are not part of the condition language",
    '"': "strings are not part of the condition language",
    "[": "subscripts are not part of the condition language",
    "]": "subscripts are not part of the condition language",
    "=": "compare with ==",
    "!": "negate with not",
    "&": "combine with and",
    "|": "combine with or",
    "$": "a ${variable} is replaced before the condition is read: is it defined?",
    ":": "the condition language has no lambda, slices or blocks",
    ".": "a name's parts are joined by dots without spaces (hub.angle_deg)",
}

_WORDS = frozenset({"and", "or", "not", "for", "becomes", "stays", "within", "after",
                    "true", "false"})
_TEMPORAL_WORDS = frozenset({"for", "becomes", "stays", "within"})
_PY_CONSTANTS = {"True": "true", "False": "false"}


@dataclass(frozen=True, slots=True)
class _Tok:
    kind: str  # "num", "name", "op", "end"
    text: str
    pos: int

    @property
    def end(self) -> int:
        return self.pos + len(self.text)


# ------------------------------------------------------------------ closures


def _const(k: Any) -> Fn:
    return lambda ctx: k


_CMP_K: dict[str, Callable[[Fn, float], Fn]] = {
    "<": lambda f, k: lambda ctx: f(ctx) < k,
    "<=": lambda f, k: lambda ctx: f(ctx) <= k,
    ">": lambda f, k: lambda ctx: f(ctx) > k,
    ">=": lambda f, k: lambda ctx: f(ctx) >= k,
    "==": lambda f, k: lambda ctx: f(ctx) == k,
    "!=": lambda f, k: lambda ctx: f(ctx) != k,
}
_CMP_F: dict[str, Callable[[Fn, Fn], Fn]] = {
    "<": lambda f, g: lambda ctx: f(ctx) < g(ctx),
    "<=": lambda f, g: lambda ctx: f(ctx) <= g(ctx),
    ">": lambda f, g: lambda ctx: f(ctx) > g(ctx),
    ">=": lambda f, g: lambda ctx: f(ctx) >= g(ctx),
    "==": lambda f, g: lambda ctx: f(ctx) == g(ctx),
    "!=": lambda f, g: lambda ctx: f(ctx) != g(ctx),
}
_CMP_PY: dict[str, Callable[[Any, Any], bool]] = {
    "<": lambda a, b: a < b, "<=": lambda a, b: a <= b, ">": lambda a, b: a > b,
    ">=": lambda a, b: a >= b, "==": lambda a, b: a == b, "!=": lambda a, b: a != b,
}
_FLIP = {"<": ">", "<=": ">=", ">": "<", ">=": "<=", "==": "==", "!=": "!="}


_CMP_ABS_K: dict[str, Callable[[Fn, float], Fn]] = {
    "<": lambda f, k: lambda ctx: abs(f(ctx)) < k,
    "<=": lambda f, k: lambda ctx: abs(f(ctx)) <= k,
    ">": lambda f, k: lambda ctx: abs(f(ctx)) > k,
    ">=": lambda f, k: lambda ctx: abs(f(ctx)) >= k,
}
"""``abs(x) OP k`` in one closure: the settle band's shape, the commonest condition."""


def _cmp_k(op: str, x: _C, k: float) -> Fn:
    if x.abs_of is not None and op in _CMP_ABS_K:
        return _CMP_ABS_K[op](x.abs_of, k)
    return _CMP_K[op](x.fn, k)  # type: ignore[arg-type]


def _div(a: float, b: float) -> float:
    return a / b if b else math.nan


def _arith(op: str, f: Fn | None, a: float, g: Fn | None, b: float) -> Fn:
    """The closure of ``left op right``; a side is a closure, or a constant when None."""
    if op == "+":
        if f is None:
            return lambda ctx: a + g(ctx)  # type: ignore[misc]
        if g is None:
            return lambda ctx: f(ctx) + b
        return lambda ctx: f(ctx) + g(ctx)
    if op == "-":
        if f is None:
            return lambda ctx: a - g(ctx)  # type: ignore[misc]
        if g is None:
            return lambda ctx: f(ctx) - b
        return lambda ctx: f(ctx) - g(ctx)
    if op == "*":
        if f is None:
            return lambda ctx: a * g(ctx)  # type: ignore[misc]
        if g is None:
            return lambda ctx: f(ctx) * b
        return lambda ctx: f(ctx) * g(ctx)
    if f is None:
        return lambda ctx: _div(a, g(ctx))  # type: ignore[misc]
    if g is None:  # a constant divisor is never zero (refused when compiled)
        return lambda ctx: f(ctx) / b
    return lambda ctx: _div(f(ctx), g(ctx))


def _fmt(v: float) -> str:
    """A value in about four significant figures, without an exponent where one reads."""
    if v != v:
        return "nan"
    if math.isinf(v):
        return "inf" if v > 0 else "-inf"
    a = abs(v)
    if a == 0:
        return "0"
    if 1e-3 <= a < 1e6:
        s = f"{v:.{max(0, 3 - math.floor(math.log10(a)))}f}"
        return s.rstrip("0").rstrip(".") if "." in s else s
    return f"{v:.3e}"


def _article(dimension: str) -> str:
    words = dimension.replace("_", " ")
    return ("an " if words[0] in "aeiou" else "a ") + words


def _units_of(dimension: str) -> list[str]:
    return [u for u, (d, _) in UNITS.items() if d == dimension]


def _or_list(items: list[str]) -> str:
    return items[0] if len(items) == 1 else ", ".join(items[:-1]) + " or " + items[-1]


_UNITS_LONGEST_FIRST = sorted(UNITS, key=len, reverse=True)


# ------------------------------------------------------------------ compiled nodes


class _C:
    """A compiled sub-expression while parsing.

    kind "num": ``fn`` ctx -> SI float, or None with ``const`` the SI value; ``dim`` None for
    a bare number (its ``const`` is the number as written, taking a neighbour's unit);
    ``unit`` the unit written ("" for counts and bare numbers), ``scale`` SI per unit.
    kind "bool": ``fn`` ctx -> truthy, or None with ``const`` a bool. kind "tri": ``fn``
    ctx -> TRUE / FALSE / PENDING (it holds temporal state). ``mt`` / ``mf``: the least
    time from a reset to TRUE / to FALSE (inf: never).
    """

    __slots__ = ("kind", "fn", "const", "dim", "unit", "scale", "start", "end", "desc",
                 "mt", "mf", "abs_of")

    def __init__(self, kind: str, fn: Fn | None, const: Any, start: int, end: int, *,
                 dim: str | None = None, unit: str = "", scale: float = 1.0,
                 desc: Callable[[Any], list[str]] | None = None,
                 mt: float = 0.0, mf: float = 0.0):
        self.kind, self.fn, self.const = kind, fn, const
        self.dim, self.unit, self.scale = dim, unit, scale
        self.start, self.end = start, end
        self.desc = desc or _no_desc
        if kind == "bool" and fn is None:
            mt, mf = (0.0, math.inf) if const else (math.inf, 0.0)
        self.mt, self.mf = mt, mf
        self.abs_of: Fn | None = None  # ``abs(x)``: x's closure, fused into a comparison

    def call(self) -> Fn:
        return self.fn if self.fn is not None else _const(self.const)


def _no_desc(ctx: Any) -> list[str]:
    return []


# ------------------------------------------------------------------ parser


class _Parser:
    def __init__(self, text: str, quantities: Mapping[str, Quantity], where: str):
        self.text, self.q, self.where = text, quantities, where
        self.names: set[str] = set()
        self.events: set[str] = set()
        self.resets: list[Callable[[float], None]] = []
        self.toks = self._tokenize()
        self.i = 0

    # --- tokens

    def error(self, pos: int | None, detail: str) -> ConditionError:
        return ConditionError(self.where, self.text, pos, detail)

    def _tokenize(self) -> list[_Tok]:
        out: list[_Tok] = []
        pos, text = 0, self.text
        while pos < len(text):
            m = _TOKEN.match(text, pos)
            if m is None:
                ch = text[pos]
                hint = _CHAR_HINTS.get(ch, "expected a name, a number, an operator or ( )")
                raise self.error(pos, f"unexpected character {ch!r}: {hint}")
            if m.lastgroup != "ws":
                out.append(_Tok(m.lastgroup or "", m.group(), pos))
            pos = m.end()
        if not out:
            raise self.error(0, "empty: expected a condition")
        out.append(_Tok("end", "", len(text)))
        return out

    def peek(self) -> _Tok:
        return self.toks[self.i]

    def next(self) -> _Tok:
        tok = self.toks[self.i]
        self.i += 1
        return tok

    def at(self, text: str) -> bool:
        tok = self.toks[self.i]
        return tok.kind in ("op", "name") and tok.text == text

    def expect(self, text: str, what: str) -> _Tok:
        tok = self.peek()
        if not self.at(text):
            raise self.error(tok.pos, f"expected {what}, found {_shown(tok)}")
        return self.next()

    def src(self, c: _C) -> str:
        return self.text[c.start:c.end]

    # --- kinds

    def need_cond(self, c: _C, where: str) -> _C:
        """c as a condition; ``where`` is the operator that needs it ("" at the top)."""
        if c.kind == "num":
            s = self.src(c)
            head = f"{where} needs a condition" if where else "expected a condition"
            if c.fn is None:
                raise self.error(c.start, f"{head}, found the number {s}")
            raise self.error(c.start, f"{head}, found the value {s}: compare it "
                                      f"(for example {s} > 0)")
        return c

    def need_num(self, c: _C, where: str) -> _C:
        if c.kind != "num":
            s = self.src(c)
            if c.kind == "bool" and c.fn is not None and s in self.names:
                raise self.error(c.start, f"{s} is a flag: use it as a condition ({s}, "
                                          f"not {s}) or compare it with true or false")
            raise self.error(c.start, f"{where} needs a value, found the condition {s}")
        return c

    # --- grammar

    def parse(self) -> _C:
        c = self.temporal()
        tok = self.peek()
        if tok.kind != "end":
            if c.kind == "tri" and tok.text in ("and", "or"):
                raise self.error(tok.pos, f"{tok.text} after a temporal form: put the "
                                          f"temporal form in parentheses to combine it")
            raise self.error(tok.pos, f"expected an operator or the end, found {_shown(tok)}")
        return c

    def parse_guarded(self) -> _C:
        """``parse``, with nesting beyond Python's recursion limit refused as bad text."""
        try:
            return self.parse()
        except RecursionError:
            raise self.error(None, "nested too deeply") from None

    def temporal(self) -> _C:
        c = self.or_()
        while self.peek().kind == "name" and self.peek().text in _TEMPORAL_WORDS:
            c = self.postfix(c)
        return c

    def or_(self) -> _C:
        c = self.and_()
        while self.at("or"):
            self.next()
            c = self.logic("or", c, self.and_())
        return c

    def and_(self) -> _C:
        c = self.not_()
        while self.at("and"):
            self.next()
            c = self.logic("and", c, self.not_())
        return c

    def not_(self) -> _C:
        if self.at("not"):
            tok = self.next()
            x = self.need_cond(self.not_(), "not")
            return _not(x, tok.pos)
        return self.comparison()

    def comparison(self) -> _C:
        a = self.additive()
        tok = self.peek()
        if not (tok.kind == "op" and tok.text in _CMP_K):
            return a
        self.next()
        b = self.additive()
        nxt = self.peek()
        if nxt.kind == "op" and nxt.text in _CMP_K:
            raise self.error(nxt.pos, "a chained comparison: write two joined by and "
                                      "(0 < x and x < 1)")
        return self.compare(tok.text, a, b, tok.pos)

    def additive(self) -> _C:
        a = self.term()
        while self.peek().kind == "op" and self.peek().text in "+-":
            tok = self.next()
            a = self.arith(tok.text, a, self.term(), tok.pos)
        return a

    def term(self) -> _C:
        a = self.unary()
        while self.peek().kind == "op" and self.peek().text in "*/":
            tok = self.next()
            a = self.arith(tok.text, a, self.unary(), tok.pos)
        return a

    def unary(self) -> _C:
        if self.at("-"):
            tok = self.next()
            x = self.need_num(self.unary(), "unary -")
            f = x.fn
            return _C("num", None if f is None else (lambda ctx: -f(ctx)),
                      None if x.const is None else -x.const, tok.pos, x.end,
                      dim=x.dim, unit=x.unit, scale=x.scale)
        if self.at("+"):
            self.next()
            return self.need_num(self.unary(), "unary +")
        return self.atom()

    def atom(self) -> _C:
        tok = self.next()
        if tok.kind == "num":
            return self.number(tok)
        if tok.kind == "op" and tok.text == "(":
            inner = self.temporal()
            close = self.expect(")", "the closing )")
            inner.start, inner.end = tok.pos, close.end
            return inner
        if tok.kind != "name":
            raise self.error(tok.pos, f"expected a value or a condition, found {_shown(tok)}")
        word = tok.text
        if word in ("true", "false"):
            return _C("bool", None, word == "true", tok.pos, tok.end)
        if self.at("("):
            if word in FUNCTIONS:
                return self.call(tok)
            raise self.error(tok.pos, f"unknown function {word} (functions: "
                                      f"{', '.join(FUNCTIONS)})")
        if word in _WORDS:
            raise self.error(tok.pos, f"expected a value or a condition, found {word}")
        if word in _PY_CONSTANTS:
            raise self.error(tok.pos, f"{word} is Python: write {_PY_CONSTANTS[word]}")
        if keyword.iskeyword(word) or word in FUNCTIONS:
            raise self.error(tok.pos, f"{word} is not part of the condition language")
        return self.name(tok)

    def number(self, tok: _Tok) -> _C:
        value = float(tok.text)
        nxt = self.peek()
        if nxt.kind == "name" and nxt.text in UNITS:
            self.next()
            dim, scale = UNITS[nxt.text]
            return _C("num", None, value * scale, tok.pos, nxt.end, dim=dim, unit=nxt.text,
                      scale=scale)
        if nxt.kind == "name" and nxt.text not in _WORDS and "." not in nxt.text:
            close = difflib.get_close_matches(nxt.text.lower(), list(UNITS), n=3, cutoff=0.5)
            hint = f"; did you mean {_or_list(close)}?" if close else ""
            raise self.error(nxt.pos, f"{nxt.text} after {tok.text} is not a unit{hint} "
                                      f"(units: {', '.join(UNITS)})")
        return _C("num", None, value, tok.pos, tok.end)

    def duration(self, word: str) -> tuple[float, str, int]:
        tok = self.peek()
        what = f"{word} needs a duration with a time unit ({_or_list(_units_of('time'))}: " \
               f"2 s, 500 ms)"
        if tok.kind != "num":
            raise self.error(tok.pos, f"{what}, found {_shown(tok)}")
        self.next()
        unit = self.peek()
        if unit.kind != "name" or unit.text not in UNITS or UNITS[unit.text][0] != "time":
            found = "no unit" if unit.kind == "end" else f"{tok.text} {unit.text}"
            raise self.error(unit.pos, f"{what}, found {found}")
        self.next()
        return float(tok.text) * UNITS[unit.text][1], self.text[tok.pos:unit.end], unit.end

    def call(self, tok: _Tok) -> _C:
        self.next()
        args = [self.need_num(self.additive(), f"{tok.text}()")]
        while self.at(","):
            self.next()
            args.append(self.need_num(self.additive(), f"{tok.text}()"))
        close = self.expect(")", f"the closing ) of {tok.text}(")
        if tok.text == "abs":
            if len(args) != 1:
                raise self.error(tok.pos, f"abs takes one value, found {len(args)}")
            x = args[0]
            f = x.fn
            out = _C("num", None if f is None else (lambda ctx: abs(f(ctx))),
                     None if x.const is None else abs(x.const), tok.pos, close.end,
                     dim=x.dim, unit=x.unit, scale=x.scale)
            out.abs_of = f
            return out
        if len(args) < 2:
            raise self.error(tok.pos, f"{tok.text} takes two values or more, found {len(args)}")
        pick = min if tok.text == "min" else max
        acc = args[0]
        for b in args[1:]:
            acc, b = self.unify(acc, b, f"{tok.text}()", b.start)
            f, g = acc.fn, b.fn
            if f is None and g is None:
                fn, const = None, pick(acc.const, b.const)
            else:
                ff, gg = acc.call(), b.call()
                fn, const = (lambda ctx, ff=ff, gg=gg: pick(ff(ctx), gg(ctx))), None
            acc = _C("num", fn, const, acc.start, b.end, dim=acc.dim, unit=acc.unit,
                     scale=acc.scale)
        acc.start, acc.end = tok.pos, close.end
        return acc

    def name(self, tok: _Tok) -> _C:
        written = tok.text
        base, unit, q = self.resolve(written, tok.pos)
        self.names.add(written)
        read = q.read
        if q.dimension == "flag":
            src = written

            def flag_desc(ctx: Any) -> list[str]:
                return [f"{src} = {'true' if read(ctx) >= 0.5 else 'false'}"]

            return _C("bool", lambda ctx: read(ctx) >= 0.5, None, tok.pos, tok.end,
                      desc=flag_desc)
        if unit is None:
            return _C("num", read, None, tok.pos, tok.end, dim=q.dimension)
        return _C("num", read, None, tok.pos, tok.end, dim=q.dimension, unit=unit,
                  scale=UNITS[unit][1])

    def resolve(self, written: str, pos: int) -> tuple[str, str | None, Quantity]:
        q = self.q
        if written in q:
            quantity = q[written]
            dim = quantity.dimension
            if dim not in DIMENSIONS:
                raise ValueError(f"quantity {written}: unknown dimension {dim!r}")
            if dim in ("count", "flag"):
                return written, None, quantity
            spelled = _or_list([f"{written}_{u}" for u in _units_of(dim)])
            raise self.error(pos, f"{written} is {_article(dim)} and needs its unit: "
                                  f"write {spelled}")
        guess = None
        for unit in _UNITS_LONGEST_FIRST:
            if not written.endswith("_" + unit):
                continue
            base = written[: -len(unit) - 1]
            if base not in q:
                guess = guess or (base, unit)
                continue
            dim = q[base].dimension
            if dim not in DIMENSIONS:
                raise ValueError(f"quantity {base}: unknown dimension {dim!r}")
            if dim in ("count", "flag"):
                raise self.error(pos, f"{written}: {base} is {_article(dim)} and takes no "
                                      f"unit; write {base}")
            if UNITS[unit][0] != dim:
                spelled = _or_list([f"{base}_{u}" for u in _units_of(dim)])
                raise self.error(pos, f"{written}: {base} is {_article(dim)}, not "
                                      f"{_article(UNITS[unit][0])}; write {spelled}")
            return base, unit, q[base]
        base, unit = guess if guess else (written, None)
        close = difflib.get_close_matches(base, list(q), n=3, cutoff=0.6)
        detail = f"unknown name {written}"
        if close:
            detail += f"; did you mean {_or_list([self.spell(c, unit) for c in close])}?"
        known = sorted(q)
        detail += (f" (known: {', '.join(known)})" if len(known) <= 30
                   else f" ({len(known)} names known)")
        raise self.error(pos, detail)

    def spell(self, base: str, unit: str | None) -> str:
        dim = self.q[base].dimension
        if dim in ("count", "flag") or dim not in DIMENSIONS:
            return base
        if unit is not None and UNITS[unit][0] == dim:
            return f"{base}_{unit}"
        return _or_list([f"{base}_{u}" for u in _units_of(dim)])

    # --- typing and combining

    def unify(self, a: _C, b: _C, what: str, pos: int) -> tuple[_C, _C]:
        """Two numeric operands in one dimension: a bare number takes the other's unit."""
        if a.dim is None and b.dim is None:
            return a, b
        if a.dim is None:
            return _adopt(a, b), b
        if b.dim is None:
            return a, _adopt(b, a)
        if a.dim != b.dim:
            raise self.error(pos, f"{what} of {self.src(a)} ({_article(a.dim)}) and "
                                  f"{self.src(b)} ({_article(b.dim)}): the dimensions differ")
        return a, b

    def arith(self, op: str, a: _C, b: _C, pos: int) -> _C:
        a = self.need_num(a, op)
        b = self.need_num(b, op)
        if op in "+-":
            a, b = self.unify(a, b, "+" if op == "+" else "-", pos)
            dim, unit, scale = (a.dim, a.unit, a.scale) if a.dim is not None else \
                (b.dim, b.unit, b.scale)
        else:
            plain_a = a.dim in (None, "count")
            plain_b = b.dim in (None, "count")
            if op == "/" and not plain_b:
                raise self.error(pos, f"/ by {self.src(b)} ({_article(b.dim or '')}): "
                                      f"a divisor must be dimensionless (a scale factor)")
            if not plain_a and not plain_b:
                raise self.error(pos, f"* of {self.src(a)} ({_article(a.dim or '')}) and "
                                      f"{self.src(b)} ({_article(b.dim or '')}): one side "
                                      f"must be dimensionless (a scale factor)")
            if op == "/" and b.fn is None and b.const == 0:
                raise self.error(b.start, "division by zero")
            if plain_a and plain_b:
                dim = "count" if "count" in (a.dim, b.dim) else None
                unit, scale = "", 1.0
            else:
                keep = b if plain_a else a
                dim, unit, scale = keep.dim, keep.unit, keep.scale
        if a.fn is None and b.fn is None:
            x, y = a.const, b.const
            const = x + y if op == "+" else x - y if op == "-" else x * y if op == "*" else x / y
            return _C("num", None, const, a.start, b.end, dim=dim, unit=unit, scale=scale)
        return _C("num", _arith(op, a.fn, a.const, b.fn, b.const), None, a.start, b.end,
                  dim=dim, unit=unit, scale=scale)

    def compare(self, op: str, a: _C, b: _C, pos: int) -> _C:
        if a.kind == "tri" or b.kind == "tri":
            raise self.error(pos, f"{op} of a temporal form: combine temporal forms with "
                                  f"and, or, not")
        if a.kind == "bool" or b.kind == "bool":
            return self.compare_bools(op, a, b, pos)
        a, b = self.unify(a, b, op, pos)
        start, end = a.start, b.end
        if a.fn is None and b.fn is None:
            return _C("bool", None, _CMP_PY[op](a.const, b.const), start, end)
        if b.fn is None:
            fn = _cmp_k(op, a, b.const)
        elif a.fn is None:
            fn = _cmp_k(_FLIP[op], b, a.const)
        else:
            fn = _CMP_F[op](a.fn, b.fn)
        sides = [(self.src(s), s.call(), s.scale, UNIT_LABELS.get(s.unit, ""))
                 for s in (a, b) if s.fn is not None]

        def desc(ctx: Any) -> list[str]:
            return [f"{src} = {_fmt(f(ctx) / scale)}{' ' + label if label else ''}"
                    for src, f, scale, label in sides]

        return _C("bool", fn, None, start, end, desc=desc)

    def compare_bools(self, op: str, a: _C, b: _C, pos: int) -> _C:
        for x in (a, b):
            if x.kind == "num":
                other = b if x is a else a
                s = self.src(other)
                raise self.error(x.start, f"{op} of the condition {s} and the value "
                                          f"{self.src(x)}: compare a flag with true or false, "
                                          f"or use it as a condition ({s}, not {s})")
        if op not in ("==", "!="):
            raise self.error(pos, f"{op} between conditions: only == and != compare them")
        start, end = a.start, b.end
        if a.fn is None and b.fn is None:
            return _C("bool", None, _CMP_PY[op](a.const, b.const), start, end)
        if a.fn is None:
            a, b = b, a
        f = a.fn
        if b.fn is None:
            keep = b.const == (op == "==")
            fn = f if keep else (lambda ctx: not f(ctx))
        else:
            g = b.fn
            fn = (lambda ctx: bool(f(ctx)) == bool(g(ctx))) if op == "==" else \
                (lambda ctx: bool(f(ctx)) != bool(g(ctx)))
        da, db = a.desc, b.desc
        return _C("bool", fn, None, start, end, desc=lambda ctx: da(ctx) + db(ctx))

    def logic(self, op: str, a: _C, b: _C) -> _C:
        a = self.need_cond(a, op)
        b = self.need_cond(b, op)
        start, end = a.start, b.end
        da, db = a.desc, b.desc

        def desc(ctx: Any) -> list[str]:
            return da(ctx) + db(ctx)

        if op == "and":
            mt, mf = max(a.mt, b.mt), min(a.mf, b.mf)
        else:
            mt, mf = min(a.mt, b.mt), max(a.mf, b.mf)
        if a.kind == "bool" and b.kind == "bool":
            for x, y in ((a, b), (b, a)):
                if x.fn is None:  # a constant side decides or drops out
                    if x.const == (op == "or"):
                        return _C("bool", None, x.const, start, end)
                    return _C("bool", y.fn, y.const, start, end, desc=y.desc, mt=y.mt,
                              mf=y.mf)
            f, g = a.fn, b.fn
            fn = (lambda ctx: f(ctx) and g(ctx)) if op == "and" else \
                (lambda ctx: f(ctx) or g(ctx))
            return _C("bool", fn, None, start, end, desc=desc, mt=mt, mf=mf)
        f, g = _tri(a), _tri(b)
        if op == "and":
            def fn3(ctx: Any) -> int:
                x = f(ctx)
                y = g(ctx)
                if x == 1:
                    return y
                return 0 if (x == 0 or y == 0) else -1
        else:
            def fn3(ctx: Any) -> int:
                x = f(ctx)
                y = g(ctx)
                if x == 0:
                    return y
                return 1 if (x == 1 or y == 1) else -1
        return _C("tri", fn3, None, start, end, desc=desc, mt=mt, mf=mf)

    # --- temporal forms

    def postfix(self, c: _C) -> _C:
        tok = self.next()
        word = tok.text
        c = self.need_cond(c, word)
        op = _holds(c)
        dc = c.desc
        if word == "for":
            d, d_text, end = self.duration("for")
            fn, reset, state = _for(op, d, d_text)
            mt, mf = c.mt + d, math.inf
        elif word in ("becomes", "stays"):
            nxt = self.peek()
            if not self.at("true"):
                hint = " (write (not C) becomes true)" if nxt.text == "false" else ""
                raise self.error(nxt.pos, f"expected true after {word}, found "
                                          f"{_shown(nxt)}{hint}")
            end = self.next().end
            if word == "becomes":
                fn, reset, state = _becomes(op)
                mt, mf = (c.mt if c.mf < math.inf else math.inf), 0.0
            else:
                fn, reset, state = _stays(op)
                mt, mf = math.inf, c.mf
        else:
            d, d_text, _ = self.duration("within")
            self.expect("after", "after EVENT")
            ev = self.next()
            if ev.kind != "name" or ev.text in _WORDS:
                raise self.error(ev.pos, f"expected an event's name after after, found "
                                         f"{_shown(ev)}")
            end = ev.end
            self.events.add(ev.text)
            fn, reset, state = _within(op, d, d_text, ev.text)
            mt, mf = c.mt, d
        self.resets.append(reset)

        def desc(ctx: Any) -> list[str]:
            return dc(ctx) + [state(ctx)]

        return _C("tri", fn, None, c.start, end, desc=desc, mt=mt, mf=mf)


def _shown(tok: _Tok) -> str:
    return "the end" if tok.kind == "end" else repr(tok.text)


def _adopt(bare: _C, other: _C) -> _C:
    """A bare number in ``other``'s unit, in SI."""
    return _C("num", None, bare.const * other.scale, bare.start, bare.end, dim=other.dim,
              unit=other.unit, scale=other.scale)


def _tri(c: _C) -> Fn:
    if c.kind == "tri":
        return c.fn  # type: ignore[return-value]
    if c.fn is None:
        return _const(TRUE if c.const else FALSE)
    f = c.fn
    return lambda ctx: 1 if f(ctx) else 0


def _holds(c: _C) -> Fn:
    """ctx -> truthy when c is TRUE (a temporal form's operand)."""
    if c.kind == "tri":
        f = c.fn
        return lambda ctx: f(ctx) == 1  # type: ignore[misc]
    return c.call()


def _not(x: _C, pos: int) -> _C:
    if x.kind == "tri":
        f = x.fn

        def fn(ctx: Any) -> int:
            v = f(ctx)  # type: ignore[misc]
            return v if v < 0 else 1 - v

        return _C("tri", fn, None, pos, x.end, desc=x.desc, mt=x.mf, mf=x.mt)
    if x.fn is None:
        return _C("bool", None, not x.const, pos, x.end)
    g = x.fn
    return _C("bool", lambda ctx: not g(ctx), None, pos, x.end, desc=x.desc, mt=x.mf,
              mf=x.mt)


def _held_text(held: float, d_text: str) -> str:
    if d_text.endswith("ms"):
        return f"{held * 1e3:.0f} ms"
    return f"{held:.2f} s"


def _for(op: Fn, d: float, d_text: str) -> tuple[Fn, Callable[[float], None], Fn]:
    start: float | None = None
    reach = d - _TIME_EPS

    def update(ctx: Any) -> int:
        nonlocal start
        if op(ctx):
            t = ctx.t_s
            if start is None:
                start = t
                return 1 if reach <= 0.0 else -1
            return 1 if t - start >= reach else -1
        start = None
        return -1

    def reset(t_s: float) -> None:
        nonlocal start
        start = None

    def state(ctx: Any) -> str:
        if start is None:
            return f"not holding; needs {d_text}"
        return f"held {_held_text(max(0.0, ctx.t_s - start), d_text)} of {d_text}"

    return update, reset, state


def _becomes(op: Fn) -> tuple[Fn, Callable[[float], None], Fn]:
    prev: Any = True  # after a reset no tick before: the first update is no edge
    edge_t: float | None = None
    seen = False

    def update(ctx: Any) -> int:
        nonlocal prev, edge_t, seen
        now = op(ctx)
        was = prev
        prev = now
        seen = True
        if now and not was:
            edge_t = ctx.t_s
            return 1
        edge_t = None
        return 0

    def reset(t_s: float) -> None:
        nonlocal prev, edge_t, seen
        prev, edge_t, seen = True, None, False

    def state(ctx: Any) -> str:
        if edge_t is not None:
            return f"became true at {edge_t:.3f} s"
        return "no tick yet" if not seen else "no rising edge"

    return update, reset, state


def _stays(op: Fn) -> tuple[Fn, Callable[[float], None], Fn]:
    failed_t: float | None = None
    since = 0.0

    def update(ctx: Any) -> int:
        nonlocal failed_t
        if failed_t is not None:
            return 0
        if op(ctx):
            return -1
        failed_t = ctx.t_s
        return 0

    def reset(t_s: float) -> None:
        nonlocal failed_t, since
        failed_t, since = None, t_s

    def state(ctx: Any) -> str:
        if failed_t is not None:
            return f"false at {failed_t:.3f} s"
        return f"true since {since:.3f} s"

    return update, reset, state


def _within(op: Fn, d: float, d_text: str, event: str
            ) -> tuple[Fn, Callable[[float], None], Fn]:
    after_t = -math.inf  # the reset's time, less the slack
    decided: int | None = None
    decided_t = 0.0
    event_t = 0.0
    window = d + _TIME_EPS

    def update(ctx: Any) -> int:
        nonlocal decided, decided_t, event_t
        if decided is not None:
            return decided
        held = op(ctx)
        te = ctx.event_time(event)
        if te is None or te < after_t:
            return -1
        t = ctx.t_s
        if t - te <= window:
            if held:
                decided, decided_t, event_t = 1, t, te
                return 1
            return -1
        decided, decided_t, event_t = 0, t, te
        return 0

    def reset(t_s: float) -> None:
        nonlocal after_t, decided
        after_t, decided = t_s - _TIME_EPS, None

    def state(ctx: Any) -> str:
        if decided == 1:
            return f"true at {decided_t:.3f} s, {decided_t - event_t:.3f} s after {event}"
        if decided == 0:
            return f"{event} at {event_t:.3f} s; not true by {event_t + d:.3f} s ({d_text})"
        te = ctx.event_time(event)
        if te is None or te < after_t:
            return f"{event} has not happened"
        return f"{event} at {te:.3f} s; not true yet ({ctx.t_s - te:.3f} s of {d_text})"

    return update, reset, state


# ------------------------------------------------------------------ entry points


def compile_condition(text: str, quantities: Mapping[str, Quantity], where: str) -> Condition:
    """Parse and compile a condition; ``where`` names it in errors (a step and its key).
    Raises ConditionError."""
    p = _Parser(text, quantities, where)
    c = p.need_cond(p.parse_guarded(), "")
    if c.kind == "tri":
        update = c.fn
    elif c.fn is None:
        update = _const(TRUE if c.const else FALSE)
    else:
        f = c.fn

        def update(ctx: Any) -> int:
            return 1 if f(ctx) else 0

    return Condition(text, frozenset(p.names), frozenset(p.events), c.mt,
                     update,  # type: ignore[arg-type]
                     tuple(p.resets), c.desc)


def compile_value(text: str, quantities: Mapping[str, Quantity], where: str) -> Value:
    """Parse and compile an arithmetic expression: its ``evaluate(ctx)`` is in the unit it is
    written in (``hub.angle_deg + 5`` in degrees). Raises ConditionError."""
    p = _Parser(text, quantities, where)
    c = p.parse_guarded()
    if c.kind != "num":
        raise p.error(c.start, f"expected a value (an arithmetic expression), found the "
                               f"condition {p.src(c)}")
    dim = c.dim or "count"
    if c.fn is None:
        k = c.const if c.dim is None else c.const / c.scale
        evaluate: Fn = _const(k)
    elif c.scale == 1.0:
        evaluate = c.fn
    else:
        f, inv = c.fn, 1.0 / c.scale

        def evaluate(ctx: Any) -> float:
            return f(ctx) * inv

    return Value(text, frozenset(p.names), c.unit, dim, evaluate)


def reference_markdown() -> str:
    """The language as a Markdown reference, written from this module's tables."""
    out = [
        "A condition is read once when the run file is loaded and compiled; it can read the "
        "rig's named quantities, do arithmetic and compare, and nothing else (it is never "
        "run as Python). A value (a recorded value, an action's computed parameter) is an "
        "arithmetic expression of the same language.",
        "",
        "**Names.** A quantity's name with its unit word: `hub.angle_deg`, "
        "`hub.rate_deg_s`, `wheel.speed_rpm`, `tip.accel_g`. Counts and flags take no "
        "unit: `step.index`, `rig.safe`. Any unit of the quantity's dimension may be "
        "written; the value is the same quantity, in that unit.",
        "",
        "**Units.** Every value is computed in SI. A bare number beside a dimensioned "
        "operand of `+`, `-`, a comparison, `min` or `max` takes that operand's unit: in "
        "`abs(hub.angle_deg - 10) < 0.05` both numbers are degrees; `hub.angle_deg < "
        "0.01 rad` converts. Operands of different dimensions are an error, and so are a "
        "flag compared with a number and a value used as a condition. Dividing by a "
        "quantity that reads zero gives NaN, which no comparison but `!=` holds.",
        "",
        "**Results.** A condition without a temporal form is TRUE or FALSE on each tick. "
        "Temporal forms keep state from the step's start and give TRUE, FALSE or PENDING "
        "(not decided yet); `and`, `or` and `not` combine those three values with PENDING "
        "as unknown (FALSE and PENDING is FALSE, TRUE or PENDING is TRUE). A temporal "
        "form's operand counts as holding only when it is TRUE.",
        "",
        "### Operators, lowest precedence first",
        "",
        "| operators | meaning |",
        "|---|---|",
    ]
    out += [f"| {ops} | {meaning} |" for ops, meaning in OPERATORS]
    out += ["", "### Functions", "", "| function | value |", "|---|---|"]
    out += [f"| `{name}` | {doc} |" for name, doc in FUNCTIONS.items()]
    out += ["", "### Temporal forms", "", "| form | value |", "|---|---|"]
    out += [f"| {name} | {doc} |" for name, doc in TEMPORAL_FORMS.items()]
    out += ["", "### Units", "", "| unit | dimension | one unit in SI |", "|---|---|---|"]
    for unit, (dim, scale) in UNITS.items():
        out.append(f"| `{unit}` ({UNIT_LABELS[unit]}) | {dim} | {scale:.9g} |")
    out += ["", "### Dimensions", "", "| dimension | what | units |", "|---|---|---|"]
    for dim, doc in DIMENSIONS.items():
        units = ", ".join(f"`{u}`" for u in _units_of(dim)) or "none"
        out.append(f"| {dim} | {doc} | {units} |")
    return "\n".join(out) + "\n"
