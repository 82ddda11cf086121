"""Every conversion of a rig file has one meaning, the physical one, pinned by worked
examples with a data sheet's numbers:

- a sensor's ``sensitivity``/``offset``: it reads value = offset + sensitivity x quantity,
  so SI = (value - offset) / sensitivity (offset in the value's unit);
- ``scale``/``offset``: SI = value x scale + offset (offset in SI), for telemetry and
  commands (an actuator is sent value = (SI - offset) / scale).

Both ends use the same map: the harness decodes with it, the virtual rig encodes with it,
so each example is checked in both directions."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from drivers.binding import BindingError, build_binding
from rig_models.canopen.rig_devices import CanopenDevices
from rig_models.rig_file import load_rig

G = 9.80665

# a 5 V unipolar 16-bit ADC board speaking its own DBC: the accelerometer's output in volts
ADC_DBC = """VERSION ""
NS_ :
BS_:
BU_: ADC HIL
BO_ 1700 ADC_Tlm: 2 ADC
 SG_ ADC_Ch1_V : 0|16@1+ (7.62939453125E-005,0) [0|4.99992370605469] "V" HIL
"""


def _accel_dbc_binding(tmp_path: Path, spec: dict) -> object:
    (tmp_path / "adc.dbc").write_text(ADC_DBC)
    data = {"bus": {}, "devices": {"accelerometer": {
        "binding": "dbc", "dbc": "adc.dbc",
        "telemetry": {"accel": {"message": "ADC_Tlm", "signal": "ADC_Ch1_V", **spec}}}}}
    (tmap,) = build_binding(data, tmp_path).telemetry["accelerometer"]
    return tmap


def test_accelerometer_sensitivity_and_offset_on_a_dbc_adc(tmp_path):
    """Data sheet: 100 mV/g, 2.5 V at 0 g, on a 0..5 V 16-bit ADC (76.29 uV a count).
    Rig file: sensitivity 0.1 / 9.80665 V per m/s^2, offset 2.5 V. 2.5 V is 0 m/s^2;
    2.6 V (count 34079) is 1 g; 2.3 V is -2 g."""
    tmap = _accel_dbc_binding(tmp_path, {"sensitivity": 0.1 / G, "offset": 2.5})
    lsb = 5.0 / 65536

    def decode(count: int) -> float:
        return tmap.decode(count.to_bytes(2, "little"))["accel"]

    assert decode(32768) == pytest.approx(0.0, abs=1e-9)            # 2.5 V
    assert decode(round(2.6 / lsb)) == pytest.approx(G, abs=lsb / 0.1 * G)  # 1 g
    assert decode(round(2.3 / lsb)) == pytest.approx(-2 * G, abs=lsb / 0.1 * G)
    # the virtual rig's direction: 1 g is sent as 2.6 V, 0 as 2.5 V (not 0 V: the offset is
    # the sensor's reading at rest, never an acceleration)
    enc = tmap.encoder(("accel",))
    assert int.from_bytes(enc(G), "little") == round(2.6 / lsb)
    assert int.from_bytes(enc(0.0), "little") == 32768
    assert tmap.codec.decode(tmap.encode({"accel": -2 * G}))["ADC_Ch1_V"] == pytest.approx(
        2.3, abs=lsb)


def test_scale_and_offset_is_si_at_a_value_of_zero(tmp_path):
    """The same board with scale/offset, the DBC's own factor/offset convention: SI = volts
    x 98.0665 - 245.16625 (9.80665 / 0.1 m/s^2 per V, minus 2.5 V's worth): the same
    numbers as the sensitivity form."""
    tmap = _accel_dbc_binding(tmp_path, {"scale": G / 0.1, "offset": -2.5 * G / 0.1})
    lsb = 5.0 / 65536
    assert tmap.decode((32768).to_bytes(2, "little"))["accel"] == pytest.approx(0.0, abs=1e-9)
    assert tmap.decode(round(2.6 / lsb).to_bytes(2, "little"))["accel"] == pytest.approx(
        G, abs=lsb / 0.1 * G)


def test_scale_and_sensitivity_together_are_refused_saying_what_each_means(tmp_path):
    with pytest.raises(BindingError, match=r"telemetry\.accel: give scale .*SI = DBC value x "
                       r"scale \+ offset.* or sensitivity .*DBC value = offset \+ sensitivity "
                       r"x SI"):
        _accel_dbc_binding(tmp_path, {"scale": 1.0, "sensitivity": 2.0})


def _co_rig(accel: dict | None = None, piezo: dict | None = None):
    data = yaml.safe_load(yaml.safe_dump(load_rig("sgsrt-canopen").data))
    if accel is not None:
        data["devices"]["accelerometer"]["telemetry"]["accel"] = accel
    if piezo is not None:
        data["devices"]["piezo_amplifier"]["commands"]["voltage_ch1"] = piezo
    return build_binding(data)


def _qref(binding, device: str, quantity: str, commands: bool = False):
    co = binding.canopen
    spec = co.nodes[co.node_of[device]]
    table = spec.commands if commands else spec.telemetry
    return next(q for q in table[device] if q.quantity == quantity)


def test_accelerometer_on_a_cia401_analog_input_counts():
    """The same accelerometer on the I/O module's +-10 V 16-bit input (3276.8 counts a
    volt): sensitivity 327.68 counts/g = 33.414 counts per m/s^2, offset 2.5 V = 8192
    counts. The virtual rig writes 1 g as 8520 counts; the harness reads 8520 as 1 g."""
    sens = 0.1 * 3276.8 / G
    b = _co_rig(accel={"object": 0x6401, "sub": 1, "sensitivity": sens, "offset": 8192})
    q = _qref(b, "accelerometer", "accel")
    assert q.conv.to_raw(G, q.ref) == 8192 + 328 == q.conv.to_raw(G + 1e-4, q.ref)
    assert q.conv.to_raw(0.0, q.ref) == 8192
    assert q.conv.si_function()(8192) == pytest.approx(0.0, abs=1e-12)
    assert q.conv.si_function()(8192 + 327.68) == pytest.approx(G)
    # the virtual rig's compiled writer puts the same counts into the node's object
    devices = CanopenDevices(b.canopen, lambda *_: None)
    write = devices.telemetry_writer("accelerometer", ("accel",))
    node = devices.nodes[b.canopen.node_of["accelerometer"]]
    write(-2 * G)
    assert node.values[(0x6401, 1)] == 8192 - 655
    write(0.0)
    assert node.values[(0x6401, 1)] == 8192


def test_drive_rated_torque_in_per_mille():
    """CiA 402: torque actual value 0x6077 and target torque 0x6071 in per mille of the
    rated torque 0x6076 (mN.m); the wheel drive's is 65 mN.m, so a count is 65e-3 x 1e-3 =
    6.5e-5 N.m (sgsrt-canopen.yaml). 500 per mille is 32.5 mN.m; 10 mN.m is sent as 154."""
    b = load_rig("sgsrt-canopen").binding
    tq = _qref(b, "reaction_wheel", "torque")
    assert tq.ref.index == 0x6077 and tq.conv.scale == pytest.approx(65e-3 * 1e-3)
    assert tq.conv.si_function()(500) == pytest.approx(0.0325)
    cmd = _qref(b, "reaction_wheel", "torque_cmd", commands=True)
    assert cmd.ref.index == 0x6071
    assert cmd.conv.to_raw(0.010, cmd.ref) == 154
    assert cmd.conv.to_raw(-0.065, cmd.ref) == -1000


def test_actuator_scale_and_offset_on_an_analog_output():
    """An actuator's scale/offset: SI = value x scale + offset, sent as (SI - offset) /
    scale. A unipolar amplifier taking 0..10 V to -200..+200 V (40 V/V, -200 V at 0 V) on
    the I/O module's 16-bit +-10 V output (3276.8 counts a volt): scale 40 / 3276.8 V a
    count, offset -200 V. +100 V is 7.5 V in, 24576 counts; -200 V is 0 counts."""
    b = _co_rig(piezo={"object": 0x6411, "sub": 1, "scale": 40 / 3276.8, "offset": -200.0})
    q = _qref(b, "piezo_amplifier", "voltage_ch1", commands=True)
    assert q.conv.to_raw(100.0, q.ref) == 24576
    assert q.conv.to_raw(-200.0, q.ref) == 0
    assert q.conv.si_function()(24576) == pytest.approx(100.0)
    # the same amplifier written as its data sheet does (sensitivity 3276.8 / 40 counts per
    # V of output, 0 V out at 5 V in = 16384 counts) sends the same counts
    b2 = _co_rig(piezo={"object": 0x6411, "sub": 1, "sensitivity": 3276.8 / 40,
                        "offset": 16384})
    q2 = _qref(b2, "piezo_amplifier", "voltage_ch1", commands=True)
    for v in (-200.0, -37.5, 0.0, 100.0):
        assert q2.conv.to_raw(v, q2.ref) == q.conv.to_raw(v, q.ref)
