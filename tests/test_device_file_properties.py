"""Property tests over the files a lab brings: a rig file with one value replaced by
something odd, an EDS with one line changed, removed or cut, a DBC with one token changed
or cut. Each either loads (and the virtual rig can be it, or refuses naming the key) or is
refused with a ``ConfigError`` / ``DbcError`` naming the file; never another exception,
never a hang (each example is bounded by an alarm)."""

from __future__ import annotations

import contextlib
import copy
import math
import re
import signal
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import yaml
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from drivers.dbc import DbcError, load_protocol
from rig_models.rig_file import RIGS_DIR, load_rig
from rig_models.schema import ConfigError
from rig_models.virtual_rig import check_virtual_rig

ROOT = Path(__file__).resolve().parents[1]
CO_RIG = load_rig("sgsrt-canopen")
WHEEL_EDS = Path(CO_RIG.binding.files["reaction_wheel"]).read_text()
DBC2 = (ROOT / "drivers" / "sgsrt_dbc2.dbc").read_text()
ODD = [math.nan, math.inf, -1, 0, 10**400, 2**64, 1e308, "", "x" * 300, [], {}, None, True,
       [1, [2]], {"a": {"b": 1}}, 0x6071, "0x6071", "../../etc/passwd", "/dev/zero"]
ODD_TEXT = ["", "0x", "-1", "0xFFFFFFFFFFFFFFFFFF", "abc", "$NODEID+", "$NODEID+0x180",
            "0x7", "0x9", "0x40", "9" * 400, "=", "[", "0x8", "255", "-0x10", "1e9"]
SETTINGS = {"deadline": None, "derandomize": True,
            "suppress_health_check": [HealthCheck.function_scoped_fixture]}


@contextlib.contextmanager
def _bounded(seconds: int = 20) -> Iterator[None]:
    """A hang becomes a failure: SIGALRM after ``seconds``."""
    def _timeout(*_: object) -> None:
        raise TimeoutError(f"no answer within {seconds} s")

    old = signal.signal(signal.SIGALRM, _timeout)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


def _fresh(tmp_path: Path) -> Path:
    """A folder of its own for each example: the EDS and DBC loaders cache by path."""
    d = tmp_path / uuid.uuid4().hex[:12]
    d.mkdir()
    return d


def _paths(doc: Any, prefix: tuple = ()) -> list[tuple]:
    out = []
    if isinstance(doc, dict):
        for k, v in doc.items():
            out.append((*prefix, k))
            out += _paths(v, (*prefix, k))
    return out


RIG_DATA = yaml.safe_load(yaml.safe_dump(CO_RIG.data))
RIG_PATHS = [p for p in _paths(RIG_DATA) if p[0] in ("devices", "bus", "hub_sensor",
                                                         "accelerometer", "piezo_amplifier")]


def _load_or_refuse(path: Path) -> None:
    try:
        rig = load_rig(path)
        check_virtual_rig(rig)
    except ConfigError as exc:
        text = str(exc)
        assert "\n" not in text.strip() or "Traceback" not in text
        assert text and "Traceback" not in text


@settings(max_examples=60, **SETTINGS)
@given(path=st.sampled_from(RIG_PATHS), value=st.sampled_from(ODD))
def test_a_mutated_rig_file_loads_or_is_refused(tmp_path, path, value):
    tmp_path = _fresh(tmp_path)
    doc = copy.deepcopy(RIG_DATA)
    node = doc
    for k in path[:-1]:
        node = node[k]
    node[path[-1]] = value
    rig = tmp_path / "rig.yaml"
    try:
        rig.write_text(yaml.safe_dump(doc))
    except (ValueError, yaml.YAMLError):
        return
    with _bounded():
        _load_or_refuse(rig)


def _sections(text: str) -> list[str]:
    return re.findall(r"^\[([^\]]+)\]", text, flags=re.M)


WHEEL_LINES = WHEEL_EDS.splitlines()
VALUE_LINES = [i for i, line in enumerate(WHEEL_LINES) if "=" in line]


@pytest.mark.slow
@settings(max_examples=80, **SETTINGS)
@given(kind=st.sampled_from(["value", "drop", "cut", "duplicate"]),
       line=st.sampled_from(VALUE_LINES), value=st.sampled_from(ODD_TEXT))
def test_a_mutated_eds_binds_or_is_refused_naming_the_file(tmp_path, kind, line, value):
    tmp_path = _fresh(tmp_path)
    lines = list(WHEEL_LINES)
    if kind == "value":
        key = lines[line].split("=", 1)[0]
        lines[line] = f"{key}={value}"
    elif kind == "drop":
        del lines[line]
    elif kind == "cut":
        lines = lines[:line] + [lines[line][: len(lines[line]) // 2]]
    else:
        lines.insert(line, lines[line])
    eds = tmp_path / "wheel.eds"
    eds.write_text("\r\n".join(lines) + "\r\n")
    doc = copy.deepcopy(RIG_DATA)
    doc["devices"]["reaction_wheel"]["eds"] = str(eds)
    doc.pop("extends", None)
    rig = tmp_path / "rig.yaml"
    rig.write_text(yaml.safe_dump(doc))
    with _bounded():
        _load_or_refuse(rig)


DBC_TOKENS = [m.span() for m in re.finditer(r"-?\d+(\.\d+)?|@\d[+-]|\|", DBC2)]


@pytest.mark.slow
@settings(max_examples=80, **SETTINGS)
@given(kind=st.sampled_from(["token", "cut"]), where=st.sampled_from(DBC_TOKENS),
       value=st.sampled_from(ODD_TEXT + ["@2+", "0|0", "64", "-64", "999999999999"]))
def test_a_mutated_dbc_loads_or_is_refused_naming_the_file(tmp_path, kind, where, value):
    tmp_path = _fresh(tmp_path)
    a, b = where
    text = DBC2[:a] + value + DBC2[b:] if kind == "token" else DBC2[:a]
    dbc = tmp_path / "sgsrt_dbc2.dbc"
    dbc.write_text(text)
    with _bounded():
        try:
            load_protocol(dbc)
        except DbcError as exc:
            assert "sgsrt_dbc2.dbc" in str(exc)
        rig = tmp_path / "rig.yaml"
        doc = yaml.safe_load((RIGS_DIR / "sgsrt-dbc2.yaml").read_text())
        doc["extends"] = str(RIGS_DIR / "sgsrt.yaml")
        rig.write_text(yaml.safe_dump(doc))
        (tmp_path / "sgsrt_dbc2.dbc").write_text(text)
        _load_or_refuse(rig)


@pytest.mark.parametrize("name", ["extends_list", "extends_scalar", "fifo"])
def test_extends_bases_of_every_kind_are_refused_in_bounded_time(tmp_path, name):
    import os

    base = tmp_path / "base.yaml"
    if name == "fifo":
        os.mkfifo(base)
    else:
        base.write_text("- a\n" if name == "extends_list" else "3.5\n")
    rig = tmp_path / "rig.yaml"
    rig.write_text("extends: base.yaml\nname: x\n")
    with _bounded(5), pytest.raises(ConfigError, match=r"base\.yaml"):
        load_rig(rig)


SECTIONS = re.findall(r"^\[([0-9A-Fa-f]{4}(?:sub[0-9A-Fa-f]+)?)\]", WHEEL_EDS, flags=re.M)
DATA_TYPES = ["0x0001", "0x0002", "0x0007", "0x0008", "0x0009", "0x000F", "0x0011", "0x0040"]


@pytest.mark.slow
@settings(max_examples=80, **SETTINGS)
@given(section=st.sampled_from(SECTIONS), data_type=st.sampled_from(DATA_TYPES))
@example(section="6502", data_type="0x0009")  # a string of supported modes: was a ValueError
@example(section="1005", data_type="0x000F")  # a domain COB-ID SYNC: was a TypeError
def test_an_object_of_another_data_type_binds_or_is_refused(tmp_path, section, data_type):
    """Any object of the EDS given another type (a string, a float, a domain): the binding,
    the master's checks and the virtual node take it or refuse it naming the file."""
    tmp_path = _fresh(tmp_path)
    text = re.sub(rf"(\[{section}\][^\[]*?DataType=)0x[0-9A-Fa-f]+", rf"\g<1>{data_type}",
                  WHEEL_EDS, count=1)
    eds = tmp_path / "wheel.eds"
    eds.write_text(text)
    doc = copy.deepcopy(RIG_DATA)
    doc["devices"]["reaction_wheel"]["eds"] = str(eds)
    rig = tmp_path / "rig.yaml"
    rig.write_text(yaml.safe_dump(doc))
    with _bounded():
        _load_or_refuse(rig)
