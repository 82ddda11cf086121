"""The lockstep tick near its floor: the positional frame maps give what their dict
forms give, the rig's one fused product gives its outputs and patch volts, and the loop's
table of the frames due is right at every tick."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from harness.core.runs import load_run
from harness.core.session import execute_run
from rig_models.faults import parse_fault
from rig_models.rig_file import load_rig
from rig_models.virtual_rig import TELEMETRY_QUANTITIES, VirtualRig

RIGS = ("sgsrt", "sgsrt-dbc2", "sgsrt-canopen")
# what the harness's drivers send (drivers' command_quantities) and the rig decodes
COMMANDS = {"reaction_wheel": ("torque_cmd", "enable"),
            "thruster_valves": ("valve_pos", "valve_neg"),
            "piezo_amplifier": ("voltage_ch1", "voltage_ch2"),
            "disturbance_rotor": ("speed_cmd", "enable")}

_values = st.one_of(st.integers(-300, 70_000),
                    st.floats(-1e4, 1e4, allow_nan=False, allow_infinity=False))


def _maps(kind: str) -> list[tuple[str, object]]:
    out = []
    for rig in RIGS:
        b = load_rig(rig).binding
        for device, maps in (b.telemetry if kind == "tlm" else b.commands).items():
            out += [(f"{rig}:{device}:{i}", m) for i, m in enumerate(maps)]
    return out


TLM_MAPS = [(n, m) for n, m in _maps("tlm") if hasattr(m, "encoder")]
CMD_MAPS = _maps("cmd")


@pytest.mark.parametrize(("name", "tmap"), TLM_MAPS, ids=[n for n, _ in TLM_MAPS])
@settings(max_examples=40, deadline=None, derandomize=True)
@given(data=st.data())
def test_telemetry_encoder_is_the_dict_encode(name, tmap, data):
    device = name.split(":")[1]
    names = TELEMETRY_QUANTITIES[device]
    values = [data.draw(_values) for _ in names]
    assert tmap.encoder(names)(*values) == tmap.encode(dict(zip(names, values, strict=True)))


@pytest.mark.parametrize(("name", "cmap"), CMD_MAPS, ids=[n for n, _ in CMD_MAPS])
@settings(max_examples=40, deadline=None, derandomize=True)
@given(data=st.data())
def test_command_encoder_and_decoder_are_the_dict_forms(name, cmap, data):
    device = name.split(":")[1]
    names = COMMANDS[device]
    values = [data.draw(_values) for _ in names]
    counter = data.draw(st.integers(0, 1000))
    payload = cmap.encoder(names)(*values, counter)
    assert payload == cmap.encode(dict(zip(names, values, strict=True)), counter)
    if hasattr(cmap, "decoder"):  # the rig decodes a DBC's command frames positionally
        defaults = tuple(float(k) for k in range(len(names)))
        got = cmap.decoder(names, defaults)(payload)
        want = cmap.decode(payload)
        assert got == tuple(want.get(q, d) for q, d in zip(names, defaults, strict=True))


def test_the_fused_product_gives_outputs_and_patch_volts():
    """y and the piezo sensor patches' volts from the rig's one product a step equal
    C x + D u and each patch's sensor gains times the modal coordinates."""
    rig = VirtualRig(load_rig("sgsrt"), bus=None, dt_s=0.002)  # type: ignore[arg-type]
    rig.armed, rig.safe = True, True
    rig.wheel.command(0.03, True)
    rig.piezo.command(30.0, -20.0)
    d = rig.plant
    n_x, n_y = d.ad.shape[0], d.c.shape[0]
    for _ in range(300):
        rig.step()
        np.testing.assert_allclose(rig.y, d.c @ rig.x + d.d @ rig.u, rtol=1e-9, atol=1e-15)
        volts = rig._state[n_x + n_y:]
        want = [g.sensor @ rig.x[1:1 + rig.n_modes] for g in rig.piezo_gains]
        np.testing.assert_allclose(volts, want, rtol=1e-9, atol=1e-15)
    assert abs(rig.truth.angle_rad) > 0 and rig.truth.modal.shape == (rig.n_modes,)


def test_a_frame_missing_at_a_multiple_of_the_dividers_period_is_counted(tmp_path):
    """On a CANopen rig tick 0 expects fewer frames (a TPDO every n-th SYNC starts at tick
    n); the loop's table of the frames due used that count at every multiple of the
    dividers' period, so a frame missing there went uncounted."""
    run = load_run("slew-rw", {"rig": "sgsrt-canopen", "duration_s": 3.0})
    # tick 1000 (t = 2 s) is a multiple of the period (5): the accelerometer's frame one
    # byte short there is malformed, so missing at its tick
    res = execute_run(run, out_dir=tmp_path, show_progress=False,
                      faults=[parse_fault("wrong_length@2:accelerometer")])
    frames = res.summary["frames"]
    assert res.summary["faults"][0]["tick"] == 1000
    assert frames["malformed"] == 1 and frames["missing"] == 1
