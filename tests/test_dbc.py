"""The compiled frame codecs agree with cantools on every frame of the DBC."""

from __future__ import annotations

import cantools
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.dbc import DBC_PATH, FrameError, frame_bits_worst_case, load_protocol

PROTOCOL = load_protocol()
DB = cantools.database.load_file(str(DBC_PATH))
EXPECTED_FRAMES = {"SYNC", "HEARTBEAT", "WHEEL_CMD", "VALVE_CMD", "PIEZO_CMD", "ROTOR_CMD",
                   "HUB_TLM", "ACCEL_TLM", "WHEEL_TLM", "VALVE_TLM", "PIEZO_TLM", "ROTOR_TLM"}


def test_every_device_frame_is_defined():
    assert set(PROTOCOL.by_name) == EXPECTED_FRAMES
    assert len(PROTOCOL.by_id) == len(EXPECTED_FRAMES)


@pytest.mark.parametrize("name", sorted(EXPECTED_FRAMES))
@settings(max_examples=60, deadline=None)
@given(data=st.data())
def test_decode_matches_cantools(name, data):
    codec = PROTOCOL[name]
    payload = data.draw(st.binary(min_size=codec.length, max_size=codec.length))
    ours = codec.decode(payload)
    theirs = DB.get_message_by_name(name).decode(payload, decode_choices=False, scaling=True)
    for key, value in theirs.items():
        assert ours[key] == pytest.approx(float(value), rel=1e-12, abs=1e-12), key


@pytest.mark.parametrize("name", sorted(EXPECTED_FRAMES))
@settings(max_examples=60, deadline=None)
@given(data=st.data())
def test_encode_matches_cantools(name, data):
    msg = DB.get_message_by_name(name)
    values = {}
    for s in msg.signals:
        raw = data.draw(st.integers(
            min_value=-(1 << (s.length - 1)) if s.is_signed else 0,
            max_value=(1 << (s.length - 1)) - 1 if s.is_signed else (1 << s.length) - 1))
        values[s.name] = raw * s.scale + s.offset
    values = {k: min(max(v, DB.get_message_by_name(name).get_signal_by_name(k).minimum), DB.
                     get_message_by_name(name).get_signal_by_name(k).maximum)
              for k, v in values.items()}
    assert PROTOCOL[name].encode(values) == msg.encode(values, strict=False)


def test_encode_clamps_to_dbc_range():
    codec = PROTOCOL["WHEEL_CMD"]
    out = codec.decode(codec.encode({"torque_cmd": 10.0, "enable": 1}))
    assert out["torque_cmd"] == pytest.approx(0.32767)


def test_wrong_length_names_the_frame():
    with pytest.raises(FrameError, match="HUB_TLM"):
        PROTOCOL["HUB_TLM"].decode(b"\x00" * 3)


def test_worst_case_frame_bits():
    # classic CAN, 11-bit id, 8 data bytes: 111 bits + up to 24 stuff bits
    assert frame_bits_worst_case(8) == 135
    assert frame_bits_worst_case(0) == 55
