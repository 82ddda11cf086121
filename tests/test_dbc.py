"""The compiled frame codecs agree with cantools on every frame of the DBC."""

from __future__ import annotations

import math
import pickle

import cantools
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.dbc import (
    DBC_PATH,
    DbcError,
    FrameCodec,
    FrameError,
    frame_bits_worst_case,
    load_protocol,
)

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
    _check_positional(PROTOCOL[name], msg, values, data)


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


# --- any lab's DBC: Motorola signals, extended ids, multiplexing, floats -------------------

DBC2_PATH = DBC_PATH.with_name("sgsrt_dbc2.dbc")
P2 = load_protocol(DBC2_PATH)
DB2 = cantools.database.load_file(str(DBC2_PATH))
HEADER = 'VERSION ""\nNS_ :\nBS_:\nBU_: A\n'


def _same(ours: dict[str, float], theirs: dict[str, float]) -> None:
    assert set(ours) == set(theirs)
    for key, value in theirs.items():
        if math.isnan(value):
            assert math.isnan(ours[key]), key
        else:
            assert ours[key] == pytest.approx(float(value), rel=1e-12, abs=1e-12), key


def _check_decode(codec: FrameCodec, msg: cantools.database.Message, payload: bytes) -> None:
    try:
        theirs = msg.decode(payload, decode_choices=False, scaling=True)
    except cantools.database.DecodeError:  # an unknown multiplexer value
        with pytest.raises(FrameError, match=msg.name):
            codec.decode(payload)
        return
    _same(codec.decode(payload), theirs)


def _raw_strategy(s: cantools.database.Signal) -> st.SearchStrategy:
    if s.is_float:
        return st.floats(width=s.length, allow_nan=False, allow_infinity=False)
    return st.integers(min_value=-(1 << (s.length - 1)) if s.is_signed else 0,
                       max_value=(1 << (s.length - 1)) - 1 if s.is_signed
                       else (1 << s.length) - 1)


def _draw_values(data: st.DataObject, msg: cantools.database.Message) -> dict[str, float]:
    """Physical values of the signals present under a drawn multiplexer value (cantools
    encodes only those), within each signal's DBC range."""
    ids = sorted({i for s in msg.signals for i in (s.multiplexer_ids or ())})
    mux_id = data.draw(st.sampled_from(ids)) if ids else None
    values: dict[str, float] = {}
    for s in msg.signals:
        if s.is_multiplexer and ids:  # without multiplexed signals, a plain one
            values[s.name] = mux_id
            continue
        if s.multiplexer_ids is not None and mux_id not in s.multiplexer_ids:
            continue
        raw = data.draw(_raw_strategy(s))
        if not s.is_float and abs(raw) >= 2**53:
            # a float holds integers exactly only up to 2^53: a wider raw value plus an
            # offset rounds to a neighbour that may lie outside the signal (2^58 in a 59-bit
            # signed one), which cantools, the oracle, cannot encode
            raw = int(math.copysign(2**52, raw))
        v = raw * s.scale + s.offset
        if s.is_float:
            v = raw  # scale 1, offset 0 (see _random_dbc): the value as drawn
        if s.minimum is not None:
            v = max(v, s.minimum)
        if s.maximum is not None:
            v = min(v, s.maximum)
        values[s.name] = v
    return values


def _check_positional(codec: FrameCodec, msg: cantools.database.Message,
                      values: dict[str, float], data: st.DataObject) -> None:
    """The positional encoder gives cantools' bytes for the same values, taking
    the signals in any order, with a name that is no signal taken and ignored."""
    names = data.draw(st.permutations(list(values)))
    extra = data.draw(st.booleans())
    args = [values[n] for n in names]
    if extra:
        names, args = [*names, "not_a_signal"], [*args, 12345.0]
    assert codec.encoder(tuple(names))(*args) == msg.encode(values, strict=False), codec.source


@st.composite
def _random_dbc(draw: st.DrawFn) -> str:
    """One message: 1-8 bytes, signals of either byte order at any free position and
    length, signed or not, scaled, some floats, optionally multiplexed, standard or
    extended id. Positions are drawn in the order's own word (an Intel signal is contiguous
    in the payload read little-endian, a Motorola one read big-endian) and converted to
    cantools' start bits; a signal overlapping one it coexists with is dropped."""
    n = draw(st.integers(1, 8))
    extended = draw(st.booleans())
    frame_id = draw(st.integers(0, (1 << 29) - 1 if extended else 0x7FF))
    muxed = draw(st.booleans()) and n >= 2
    lines = [f"BO_ {frame_id | (0x80000000 if extended else 0)} MSG: {n} A"]
    floats = []
    taken: dict[int | None, set[tuple[int, int]]] = {None: set()}

    def bits(big: bool, shift: int, length: int) -> set[tuple[int, int]]:
        return {((n - 1 - k // 8) if big else k // 8, k % 8) for k in range(shift, shift + length)}

    def place(big: bool, shift: int, length: int) -> int:
        if not big:
            return shift
        msb = shift + length - 1
        return 8 * (n - 1 - msb // 8) + msb % 8

    if muxed:
        big = draw(st.booleans())
        length = draw(st.integers(2, 8))
        shift = draw(st.integers(0, 8 * n - length))
        taken[None] |= bits(big, shift, length)
        lines.append(f' SG_ MUX M : {place(big, shift, length)}|{length}@{0 if big else 1}+ '
                     f'(1,0) [0|0] "" A')
    for k in range(draw(st.integers(1, 7))):
        big = draw(st.booleans())
        is_float = draw(st.integers(0, 5)) == 0 and 8 * n >= 32
        length = (draw(st.sampled_from([32, 64] if n == 8 else [32])) if is_float
                  else draw(st.integers(1, min(64, 8 * n))))
        shift = draw(st.integers(0, 8 * n - length))
        group = draw(st.sampled_from([None, 0, 1, 2])) if muxed else None
        used = bits(big, shift, length)
        clash = taken[None] if group is not None else set().union(*taken.values())
        if used & (clash | taken.get(group, set())):
            continue
        taken.setdefault(group, set()).update(used)
        signed = draw(st.booleans())
        scale, offset = (1, 0) if is_float else (draw(st.sampled_from(
            [1, 0.1, 0.001, 1e-5, 1e-7, 0.0054931640625, 2.5, 3])), draw(st.sampled_from(
                [0, -327.68, 100, 0.5])))
        narrow = draw(st.booleans()) and not is_float
        rng = f"[{(-3 * scale if signed else 0) + offset}|{7 * scale + offset}]" if narrow \
            else "[0|0]"
        tag = "" if group is None else f" m{group}"
        lines.append(f' SG_ S{k}{tag} : {place(big, shift, length)}|{length}@{0 if big else 1}'
                     f'{"-" if signed else "+"} ({scale},{offset}) {rng} "u" A')
        if is_float:
            floats.append(f"SIG_VALTYPE_ {frame_id | (0x80000000 if extended else 0)} S{k} : "
                          f"{1 if length == 32 else 2};")
    return HEADER + "\n".join(lines) + "\n" + "\n".join(floats) + "\n"


@settings(max_examples=300, deadline=None)
@given(text=_random_dbc(), data=st.data())
def test_random_messages_match_cantools(text, data):
    msg = cantools.database.load_string(text, "dbc").messages[0]
    codec = FrameCodec(msg)
    assert (codec.frame_id, codec.is_extended) == (msg.frame_id, msg.is_extended_frame)
    payload = data.draw(st.binary(min_size=msg.length, max_size=msg.length))
    _check_decode(codec, msg, payload)
    values = _draw_values(data, msg)
    ours = codec.encode(values)
    assert ours == msg.encode(values, strict=False), codec.source
    _same(codec.decode(ours), msg.decode(ours, decode_choices=False))
    _check_positional(codec, msg, values, data)


def test_motorola_signal_across_three_bytes():
    # WhlTrq_mNm: MSB at bit 5 of byte 2 (start 21), 16 bits over bytes 2, 3 and 4
    codec = P2["RW_Tlm"]
    data = codec.encode({"WhlTrq_mNm": -0.005})  # raw -1: every field bit set
    assert data == bytes([0, 0, 0x3F, 0xFF, 0xC0, 0, 0, 0])
    assert codec.decode(data)["WhlTrq_mNm"] == pytest.approx(-0.005)
    sig = codec.signals[codec.signal_names.index("WhlTrq_mNm")]
    assert (sig.word_order, sig.shift(codec.length)) == ("big", 30)


@pytest.mark.parametrize("name", sorted(m.name for m in DB2.messages))
@settings(max_examples=80, deadline=None)
@given(data=st.data())
def test_dbc2_round_trips_against_cantools(name, data):
    msg = DB2.get_message_by_name(name)
    codec = P2[name]
    payload = bytearray(data.draw(st.binary(min_size=msg.length, max_size=msg.length)))
    if codec.multiplexer and data.draw(st.booleans()):
        payload[0] = data.draw(st.sampled_from([0, 1]))  # AuxMux is byte 0
    _check_decode(codec, msg, bytes(payload))
    values = _draw_values(data, msg)
    ours = codec.encode(values)
    assert ours == msg.encode(values, strict=False)
    _same(codec.decode(ours), msg.decode(ours, decode_choices=False))
    _check_positional(codec, msg, values, data)


def test_dbc2_frames_ids_and_byte_orders():
    assert {c.name for c in P2.by_key.values()} == {m.name for m in DB2.messages}
    extended = {c.name for c in P2.by_key.values() if c.is_extended}
    assert extended == {"RW_Cmd", "PZ_Cmd", "HUB_Tlm", "RW_Tlm", "AUX_STATUS"}
    assert set(P2.by_id) == {c.frame_id for c in P2.by_key.values() if not c.is_extended}
    big = [c for c in P2.by_key.values()
           if sum(s.byte_order == "big_endian" for s in c.signals) > len(c.signals) / 2]
    assert len(big) > len(P2.by_key) / 2
    assert P2.get(0x18FF2210, True) is P2["AUX_STATUS"]
    assert P2.get(0x18FF2210) is None  # the standard id of equal value is another frame
    assert P2["MST_Sync"].length == 4 and P2["MST_Sync"].frame_id == 0x080
    for c in P2.by_key.values():
        assert c.comment, c.name
        for s in c.signals:
            assert P2.database.get_message_by_name(c.name).get_signal_by_name(s.name).comment


# quantity -> (message, signal, SI per DBC unit, the rig's largest |value| and the finest
# step it needs, both SI); the rig file's conversion is SI = DBC value x factor
DBC2_QUANTITIES = {
    "wheel speed": ("RW_Tlm", "WhlSpd_rpm", 2 * math.pi / 60, 628.0, None),
    "wheel torque": ("RW_Tlm", "WhlTrq_mNm", 1e-3, 0.065, 1e-5),
    "wheel torque command": ("RW_Cmd", "RW_TrqReq_mNm", 1e-3, 0.065, 1e-5),
    "tip acceleration": ("ACC_Tlm", "ACC_TipAcc_mg", 9.80665e-3, 19.6, 1e-3),
    "hub angle": ("HUB_Tlm", "HUB_Ang_urad", 1e-6, math.pi, 1e-7),
    "hub rate": ("HUB_Tlm", "HUB_Rate_dps", math.pi / 180, 0.2, 1e-7),
    "piezo command ch1": ("PZ_Cmd", "PZ_Vout1Req_V", 1.0, 200.0, 0.01),
    "piezo command ch2": ("PZ_Cmd", "PZ_Vout2Req_V", 1.0, 200.0, 0.01),
    "piezo sensor ch1": ("PZ_Tlm", "PZ_Sns1_mV", 1e-3, 32.0, 1e-3),
    "rotor speed": ("AUX_STATUS", "ROT_Spd_rpm", 2 * math.pi / 60, 32.0, 1e-3),
    "rotor speed command": ("ROT_Cmd", "ROT_SpdReq_rpm", 2 * math.pi / 60, 32.0, 1e-3),
    "rotor angle": ("AUX_STATUS", "ROT_Ang_deg", math.pi / 180, 2 * math.pi - 1e-3, None),
    "valve on-time": ("AUX_STATUS", "THR_OnTime_s", 1.0, 1000.0, 1e-4),
}


@pytest.mark.parametrize("quantity", sorted(DBC2_QUANTITIES))
def test_dbc2_ranges_hold_the_rig(quantity):
    frame, name, factor, largest, step = DBC2_QUANTITIES[quantity]
    codec = P2[frame]
    sig = codec.signals[codec.signal_names.index(name)]
    if step is not None:
        assert abs(sig.scale) * factor <= step * (1 + 1e-9)
    mux = {codec.multiplexer: DB2.get_message_by_name(frame).get_signal_by_name(name)
           .multiplexer_ids[0]} if codec.multiplexer else {}
    for si in (largest, -largest if sig.signed or sig.offset < 0 else 0.0):
        back = codec.decode(codec.encode({**mux, name: si / factor}))[name] * factor
        assert back == pytest.approx(si, abs=abs(sig.scale) * factor), (quantity, si)


def test_multiplexed_frame_carries_only_its_mux_values_signals():
    codec = P2["AUX_STATUS"]
    out = codec.decode(codec.encode({"AuxMux": 1, "ROT_Spd_rpm": -120.5, "THR_FireCnt": 9}))
    assert out["AuxMux"] == 1 and out["ROT_Spd_rpm"] == pytest.approx(-120.5)
    assert not any(k.startswith("THR_") for k in out)
    out = codec.decode(codec.encode({"AuxMux": 0, "THR_OnTime_s": 999.9999}))
    assert set(out) == {"AuxMux", "THR_PosOpen", "THR_NegOpen", "THR_Flt", "THR_TlmAlive",
                        "THR_FireCnt", "THR_OnTime_s", "AUX_Crc"}  # the checksum: every page
    assert out["THR_OnTime_s"] == pytest.approx(999.9999)
    with pytest.raises(FrameError, match="AuxMux"):
        codec.encode({"ROT_Spd_rpm": 1.0})
    with pytest.raises(FrameError, match="AuxMux = 7"):
        codec.encode({"AuxMux": 7})
    with pytest.raises(FrameError, match="AUX_STATUS.*AuxMux = 2"):
        codec.decode(bytes([2, 0, 0, 0, 0, 0, 0, 0]))


def test_standard_and_extended_ids_of_equal_value_are_two_frames(tmp_path):
    path = tmp_path / "two.dbc"
    path.write_text(HEADER + 'BO_ 256 STD: 1 A\n SG_ a : 0|8@1+ (1,0) [0|255] "" A\n'
                    f'BO_ {0x100 | 0x80000000} EXT: 2 A\n SG_ b : 7|16@0+ (1,0) [0|65535] "" A\n'
                    'BO_ 1 BARE: 0 A\n')
    p = load_protocol(path)
    assert p.by_id == {0x100: p["STD"], 1: p["BARE"]}
    assert p["BARE"].encode({}) == b"" and p["BARE"].decode(b"") == {}
    assert p.get(0x100) is p["STD"] and p.get(0x100, is_extended=True) is p["EXT"]
    assert p.by_key == {(0x100, False): p["STD"], (0x100, True): p["EXT"], (1, False): p["BARE"]}


def test_extended_multiplexing_is_a_problem_of_that_message_only(tmp_path):
    """A message the codecs cannot carry is noted against it, not fatal to the file: the
    other messages load (a rig that binds it is refused, tests/test_device_files.py)."""
    path = tmp_path / "extmux.dbc"
    path.write_text(HEADER + 'BO_ 100 NESTED: 8 A\n SG_ S0 M : 0|8@1+ (1,0) [0|0] "" A\n'
                    ' SG_ S1 m0M : 8|8@1+ (1,0) [0|0] "" A\n'
                    ' SG_ S2 m1 : 16|8@1+ (1,0) [0|0] "" A\n'
                    'BO_ 101 PLAIN: 1 A\n SG_ x : 0|8@1+ (1,0) [0|255] "" A\n'
                    'SG_MUL_VAL_ 100 S1 S0 0-0;\nSG_MUL_VAL_ 100 S2 S1 1-1;\n')
    p = load_protocol(path)
    assert "NESTED" not in p.by_name and "PLAIN" in p.by_name
    assert p.problems["NESTED"].startswith("NESTED: extended multiplexing")


def test_a_bad_dbc_is_an_error_naming_the_file(tmp_path):
    path = tmp_path / "broken.dbc"
    path.write_text(HEADER + "BO_ 100 M: 8 A\n SG_ x : 0|8@1+ (1,0 [0|1] \"\" A\n")
    with pytest.raises(DbcError, match=r"broken\.dbc: not a valid DBC"):
        load_protocol(path)
    with pytest.raises(DbcError, match=r"missing\.dbc: cannot read"):
        load_protocol(tmp_path / "missing.dbc")


def test_float_signals_and_a_bad_value_names_the_signal(tmp_path):
    path = tmp_path / "floats.dbc"
    path.write_text(HEADER + 'BO_ 100 F: 8 A\n SG_ f32 : 7|32@0- (1,0) [0|0] "m" A\n'
                    ' SG_ i16 : 32|16@1- (0.5,0) [0|0] "" A\n'
                    'SIG_VALTYPE_ 100 f32 : 1;\n')
    codec = load_protocol(path)["F"]
    out = codec.decode(codec.encode({"f32": 1.5e-3, "i16": -3.0}))
    assert out == {"f32": pytest.approx(1.5e-3, rel=1e-7), "i16": -3.0}
    with pytest.raises(ValueError, match=r"F\.i16: cannot encode nan"):
        codec.encode({"f32": 0.0, "i16": float("nan")})
    with pytest.raises(ValueError, match=r"F\.f32: cannot encode 'x'"):
        codec.encode({"f32": "x"})
    with pytest.raises(ValueError, match=r"F\.f32: .* does not fit a 32-bit float"):
        codec.encode({"f32": 1e300})


def test_encode_clamps_to_what_the_field_holds():
    # a DBC range wider than the raw field: clamped to the field, never wrapped
    db = cantools.database.load_string(
        HEADER + 'BO_ 100 W: 1 A\n SG_ x : 0|4@1- (1,0) [-100|100] "" A\n', "dbc")
    codec = FrameCodec(db.messages[0])
    assert codec.decode(codec.encode({"x": 50}))["x"] == 7
    assert codec.decode(codec.encode({"x": -50}))["x"] == -8
    # 64-bit raw integers stay exact (no float on the way): the largest, not 0 by wrapping
    db = cantools.database.load_string(
        HEADER + 'BO_ 100 W: 8 A\n SG_ x : 7|64@0+ (1,0) [0|0] "" A\n', "dbc")
    codec = FrameCodec(db.messages[0])
    assert codec.encode({"x": 2**64 + 5}) == b"\xff" * 8
    assert codec.encode({"x": 2**64 - 2}) == b"\xff" * 7 + b"\xfe"


def test_a_named_multiplexer_value_without_signals_decodes():
    # cantools counts a multiplexer's named values (VAL_) as valid ids even with no signal
    db = cantools.database.load_string(
        HEADER + 'BO_ 100 N: 2 A\n SG_ sel M : 0|8@1+ (1,0) [0|0] "" A\n'
        ' SG_ a m0 : 8|8@1+ (1,0) [0|0] "" A\nVAL_ 100 sel 0 "A" 2 "Idle" ;\n', "dbc")
    codec = FrameCodec(db.messages[0])
    assert codec.decode(b"\x02\x07") == {"sel": 2.0}
    assert codec.encode({"sel": 2, "a": 5}) == b"\x02\x00"
    with pytest.raises(FrameError, match="sel = 1"):
        codec.decode(b"\x01\x07")


def test_a_protocol_pickles_for_another_process():
    copy = pickle.loads(pickle.dumps(P2))
    codec = copy["AUX_STATUS"]
    values = {"AuxMux": 1, "ROT_Spd_rpm": 12.5}
    assert codec.encode(values) == P2["AUX_STATUS"].encode(values)
    assert copy.get(0x18FF2210, True) is codec
