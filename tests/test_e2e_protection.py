"""End-to-end protection of DBC messages: each checksum scheme against published check
values; the sgsrt-dbc2 rig (checksums on its commands and telemetry) runs PASS in lockstep;
a telemetry frame with a bad checksum (the ``bad_checksum`` fault) or a broken counter is a
fault naming the device and the message; the virtual rig drops a command frame with a bad
checksum or a repeated counter, as a device does; a wrong declaration is refused naming the
rig file's key."""

from __future__ import annotations

import copy
import pickle
from pathlib import Path

import can
import pytest
import yaml
from cantools.autosar.end_to_end import compute_profile2_crc
from crccheck.crc import Crc8Autosar, Crc8SaeJ1850
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.binding import BindingError, build_binding
from drivers.binding.e2e import H2F, J1850, Checksum, _crc
from harness.core.runs import load_run
from harness.core.session import execute_run
from rig_models.faults import parse_fault
from rig_models.rig_file import load_rig
from rig_models.virtual_rig import VirtualRig
from tests.in_process import harness_in_process

CHECK = b"123456789"  # the CRC catalogue's check input


# -- the schemes -------------------------------------------------------------------------
def test_crc8_check_values():
    # CRC-8/SAE-J1850: check 0x4B; CRC-8/AUTOSAR (8H2F): check 0xDF (the CRC catalogue's)
    assert _crc(J1850, 0xFF, CHECK) ^ 0xFF == 0x4B
    assert _crc(H2F, 0xFF, CHECK) ^ 0xFF == 0xDF
    # the scheme over a payload whose checksum byte follows the data, not covering it
    assert Checksum("crc8_sae_j1850", "c", 9, covers="others").compute(CHECK + b"\0") == 0x4B
    # covering the whole payload, the checksum's own byte taken as 0
    assert Checksum("crc8_sae_j1850", "c", 9).compute(CHECK + b"\x77") == (
        Crc8SaeJ1850.calc(CHECK + b"\0"))


@settings(max_examples=200, deadline=None)
@given(data=st.binary(min_size=2, max_size=64), pos=st.integers(0, 63))
def test_tables_agree_with_the_crc_library(data, pos):
    pos %= len(data)
    others = data[:pos] + data[pos + 1:]
    zeroed = data[:pos] + b"\0" + data[pos + 1:]
    assert Checksum("crc8_sae_j1850", "c", pos).compute(data) == Crc8SaeJ1850.calc(zeroed)
    assert Checksum("crc8_sae_j1850", "c", pos, covers="others").compute(data) == (
        Crc8SaeJ1850.calc(others))
    assert Checksum("autosar_p2", "c", pos, data_id=0x5A).compute(data) == (
        Crc8Autosar.calc(others + b"\x5a"))
    assert Checksum("sum8", "c", pos).compute(data) == sum(others) % 256
    x = 0
    for b in others:
        x ^= b
    assert Checksum("xor8", "c", pos).compute(data) == x


@settings(max_examples=200, deadline=None)
@given(data=st.binary(min_size=2, max_size=64), pos=st.integers(0, 63),
       scheme=st.sampled_from(["sum8", "xor8", "crc8_sae_j1850", "autosar_p1", "autosar_p2"]),
       covers=st.sampled_from(["payload", "others"]), data_id=st.integers(0, 0xFF),
       ids=st.booleans())
def test_the_code_generated_for_a_message_length_is_the_loop(data, pos, scheme, covers,
                                                              data_id, ids):
    """A bound message's checksum is straight-line code for its length: the same value as
    the loop over the bytes, whatever the payload and the checksum's position."""
    pos = 0 if scheme == "autosar_p2" and ids else pos % len(data)
    kw = {"data_id": list(range(data_id % 16, data_id % 16 + 16)) if ids else data_id}
    if not scheme.startswith("autosar"):
        kw = {"covers": covers}
    loop = Checksum(scheme, "c", pos, **kw)
    fixed = Checksum(scheme, "c", pos, length=len(data), **kw)
    assert fixed.compute(data) == loop.compute(data)
    sealed = fixed.seal(data)
    assert len(sealed) == len(data) and fixed.error(sealed) is None


def test_a_protected_rig_pickles():
    """A rig goes to other processes (a suite's workers): its checksums regenerate there."""
    binding = pickle.loads(pickle.dumps(load_rig("sgsrt-dbc2").binding))
    for device, maps in binding.commands.items():
        for m in maps:
            payload = m.encode({}, 5)
            assert m.checksum.error(payload) is None, device
    p2 = Checksum("autosar_p2", "c", 0, "M", list(range(16)), length=8)
    again = pickle.loads(pickle.dumps(p2))
    assert again.compute(bytes([0, 2, 2, 3, 4, 5, 6, 7])) == 0xBC


def test_sum_and_xor():
    assert Checksum("sum8", "c", 2).compute(bytes([0x10, 0xF0, 0xAA, 0x05])) == 0x05
    assert Checksum("xor8", "c", 0).compute(bytes([0xAA, 0xF0, 0x0F, 0x01])) == 0xFE


def test_autosar_profile_1_and_2():
    """Profile 1 (DataIDMode BOTH, data id 0x123) and Profile 2 (CRC in byte 0, counter in
    byte 1): the values the AUTOSAR E2E library's reference implementation (the
    ``autosar-e2e`` package's tests) gives for these payloads; Profile 2 also against
    cantools' own Profile 2 helper."""
    p1 = Checksum("autosar_p1", "c", 0, data_id=0x123)
    assert p1.compute(bytes(8)) == 0xCC  # counter 0
    assert p1.compute(bytes([0, 0x01, 0, 0, 0, 0, 0, 0])) == 0x91  # counter 1
    ids = list(range(16))
    p2 = Checksum("autosar_p2", "c", 0, data_id=ids)
    assert p2.compute(bytes([0, 2, 2, 3, 4, 5, 6, 7])) == 0xBC  # counter 2: data id 2
    assert p2.compute(bytes([0, 1, 2, 3, 4, 5, 6, 7])) == 0x61  # counter 1: data id 1
    assert Checksum("autosar_p2", "c", 0, data_id=[0] * 16).compute(
        bytes([0, 1, 0, 0, 0, 0, 0, 0])) == 0x45
    payload = bytes([0, 1, 2, 3, 4, 5, 6, 7])
    assert Checksum("autosar_p2", "c", 0, data_id=1).compute(payload) == (
        compute_profile2_crc(payload, 1))


def test_seal_and_error():
    c = Checksum("crc8_sae_j1850", "RW_CmdCrc", 4, "RW_Cmd")
    sealed = c.seal(bytes([1, 2, 3, 4, 0]))
    assert c.error(sealed) is None
    bad = sealed[:4] + bytes([sealed[4] ^ 1])
    why = c.error(bad)
    assert why is not None and why.startswith("RW_Cmd: checksum RW_CmdCrc (crc8_sae_j1850)")
    assert f"expected 0x{sealed[4]:02X}" in why


# -- on the shipped rig ------------------------------------------------------------------
def _run(tmp_path: Path, rig: str = "sgsrt-dbc2", faults: tuple[str, ...] = (),
         duration_s: float = 3.0):
    run = load_run("slew-rw", {"rig": rig, "duration_s": duration_s, "clock": "lockstep"})
    return execute_run(run, out_dir=tmp_path, show_progress=False,
                       faults=[parse_fault(f) for f in faults])


def test_protected_rig_runs_pass_and_its_commands_carry_checksums(tmp_path):
    res = _run(tmp_path)
    s = res.summary
    assert s["stopped_by"] == "completed" and s["faults"] == [], s["faults"]
    rig = res.virtual_rig
    # the rig accepted every command: none refused for its checksum or counter
    assert rig.counters.malformed == 0 and rig.counters.repeated == 0
    assert s["virtual_rig"]["malformed"] == 0 and s["virtual_rig"]["repeated"] == 0
    b = load_rig("sgsrt-dbc2").binding
    (cmap,) = b.commands["reaction_wheel"]
    frames = [f for f in can.LogReader(str(res.run_dir / "can.blf"))
              if (f.arbitration_id, f.is_extended_id) == cmap.key]
    assert len(frames) > 1000
    for f in frames:
        assert cmap.checksum.error(bytes(f.data)) is None
    assert {f.data[cmap.checksum.byte] for f in frames} != {0}


@pytest.mark.parametrize(("device", "message", "signal"), [
    ("reaction_wheel", "RW_Tlm", "RW_TlmCrc"),  # CRC-8 SAE J1850, a frame of its own
    ("piezo_amplifier", "PZ_Tlm", "PZ_TlmChk"),  # XOR
    ("disturbance_rotor", "AUX_STATUS", "AUX_Crc"),  # one page of a multiplexed frame
])
def test_bad_telemetry_checksum_is_a_fault_naming_device_and_message(tmp_path, device,
                                                                     message, signal):
    res = _run(tmp_path, faults=(f"bad_checksum@1:{device}",))
    s = res.summary
    assert s["stopped_by"] == "fault"
    (event,) = s["faults"]
    assert event["device"] == device and event["kind"] == "malformed frame"
    assert f"{message}: checksum {signal}" in event["message"]
    assert "expected 0x" in event["message"]
    assert 500 <= event["tick"] <= 505  # within the device's divider of the fault's start
    assert not res.virtual_rig.armed


def _rig_file(tmp_path: Path, name: str, devices: dict) -> str:
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump({"extends": "sgsrt-dbc2", "name": name,
                                    "devices": devices}))
    return str(path)


def _device(device: str) -> dict:
    return copy.deepcopy(load_rig("sgsrt-dbc2").data["devices"][device])


def test_a_telemetry_counter_error_is_counted_and_judged(tmp_path):
    wheel = _device("reaction_wheel")
    wheel["telemetry"]["counter"]["modulus"] = 16  # checked: +1 per frame
    rig = _rig_file(tmp_path, "counted", {"reaction_wheel": wheel})
    assert _run(tmp_path / "ok", rig).summary["stopped_by"] == "completed"
    res = _run(tmp_path / "lost", rig, faults=("drop_frames@1:reaction_wheel",))
    (event,) = res.summary["faults"]
    assert event["device"] == "reaction_wheel" and event["kind"] == "frames lost"
    assert "counter went" in event["message"]
    assert event["tick"] <= 502


# -- the virtual rig receiving -----------------------------------------------------------
def test_virtual_rig_drops_a_command_with_a_bad_checksum_or_a_repeated_counter():
    rig_cfg = load_rig("sgsrt-dbc2")
    b = rig_cfg.binding
    (cmap,) = b.commands["reaction_wheel"]
    channel = f"e2e-{id(rig_cfg)}"
    with can.Bus(interface="virtual", channel=channel) as rig_bus, \
            can.Bus(interface="virtual", channel=channel) as master:
        rig = VirtualRig(rig_cfg, rig_bus, dt_s=0.002)

        def send(data: bytes, key: tuple[int, bool] = cmap.key) -> None:
            master.send(can.Message(arbitration_id=key[0], is_extended_id=key[1],
                                    data=data))
            rig.service()

        send(b.heartbeat.encode(1, True), b.heartbeat.key)
        assert rig.armed
        send(cmap.encode({"torque_cmd": 0.02, "enable": 1}, 1))
        assert rig.wheel.enabled and rig.wheel.command_n_m == pytest.approx(0.02)
        good = cmap.encode({"torque_cmd": 0.04, "enable": 1}, 2)
        bad = bytearray(good)
        bad[cmap.checksum.byte] ^= 0x01
        send(bytes(bad))
        assert rig.wheel.command_n_m == pytest.approx(0.02)  # not applied
        assert rig.counters.malformed == 1
        # the same frame with a right checksum but the counter of the last one: stale
        send(cmap.encode({"torque_cmd": 0.04, "enable": 1}, 1))
        assert rig.wheel.command_n_m == pytest.approx(0.02)
        assert rig.counters.repeated == 1
        send(good)
        assert rig.wheel.command_n_m == pytest.approx(0.04)
        # a checksum of 0 (what a sender without end-to-end protection puts there)
        zero = bytearray(cmap.encode({"torque_cmd": 0.0, "enable": 0}, 3))
        zero[cmap.checksum.byte] = 0
        send(bytes(zero))
        assert rig.wheel.enabled and rig.wheel.command_n_m == pytest.approx(0.04)
        assert rig.counters.malformed == 2


# -- refusals ----------------------------------------------------------------------------
def _binding_of(devices: dict) -> None:
    data = copy.deepcopy(load_rig("sgsrt-dbc2").data)
    data["devices"].update(devices)
    build_binding(data)


@pytest.mark.parametrize(("spec", "key", "what"), [
    ({"signal": "RW_CmdCrc", "scheme": "crc16_ccitt"}, "RW_Cmd.scheme", "unknown checksum"),
    ({"signal": "RW_Crc", "scheme": "sum8"}, "RW_Cmd.signal", "not a signal of RW_Cmd"),
    ({"scheme": "sum8"}, "RW_Cmd.signal", "None"),
    ({"signal": "RW_CmdAlive", "scheme": "sum8"}, "RW_Cmd.signal", "already carries"),
    ({"signal": "RW_EnaReq", "scheme": "sum8"}, "RW_Cmd.signal", "one whole byte"),
    ({"signal": "RW_CmdCrc", "scheme": "autosar_p1"}, "RW_Cmd.data_id", "missing"),
    ({"signal": "RW_CmdCrc", "scheme": "autosar_p1", "data_id": 0x10000}, "RW_Cmd.data_id",
     "0..0xFFFF"),
    ({"signal": "RW_CmdCrc", "scheme": "autosar_p2", "data_id": list(range(16))},
     "RW_Cmd.data_id", "byte 0"),
    ({"signal": "RW_CmdCrc", "scheme": "sum8", "data_id": 3}, "RW_Cmd.data_id", "no data id"),
    ({"signal": "RW_CmdCrc", "scheme": "sum8", "covers": "half"}, "RW_Cmd.covers", "half"),
    ({"signal": "RW_CmdCrc", "scheme": "sum8", "where": 1}, "RW_Cmd.where", "unknown key"),
])
def test_a_wrong_checksum_declaration_is_refused_naming_the_key(spec, key, what):
    wheel = _device("reaction_wheel")
    del wheel["commands"]["enable"]  # RW_EnaReq free: a bit, not a byte
    wheel["checksums"]["RW_Cmd"] = spec
    with pytest.raises(BindingError) as exc:
        _binding_of({"reaction_wheel": wheel})
    msg = str(exc.value)
    assert msg.startswith(f"devices.reaction_wheel.checksums.{key}"), msg
    assert what in msg and "\n" not in msg


def test_a_checksum_on_a_message_the_device_does_not_bind_is_refused():
    wheel = _device("reaction_wheel")
    wheel["checksums"]["PZ_Cmd"] = {"signal": "PZ_CmdCrc", "scheme": "sum8"}
    with pytest.raises(BindingError, match=r"^devices\.reaction_wheel\.checksums\.PZ_Cmd: "
                                           r"'PZ_Cmd' is not a message the reaction_wheel"):
        _binding_of({"reaction_wheel": wheel})


def test_the_cli_refuses_an_unknown_scheme_before_the_run(tmp_path):
    wheel = _device("reaction_wheel")
    wheel["checksums"]["RW_Tlm"]["scheme"] = "crc4"
    rig = _rig_file(tmp_path, "bad-scheme", {"reaction_wheel": wheel})
    out = harness_in_process("run", "slew-rw", "--rig", rig, "--duration-s", "1", "--quiet",
                             "--out", str(tmp_path / "logs"))
    assert out.returncode == 2, out.stderr
    assert "devices.reaction_wheel.checksums.RW_Tlm.scheme" in out.stderr
    assert "crc4" in out.stderr and "Traceback" not in out.stderr
    assert not (tmp_path / "logs").exists() or not any((tmp_path / "logs").iterdir())


def test_a_bad_checksum_fault_on_a_device_without_one_is_refused(tmp_path):
    """The fault could not happen there: refused before the run rather than run unseen."""
    out = harness_in_process("run", "slew-rw", "--rig", "sgsrt-dbc2", "--duration-s", "1",
                             "--quiet", "--out", str(tmp_path / "logs"),
                             "--fault", "bad_checksum@0.5:hub_sensor")
    assert out.returncode == 2, out.stderr
    assert "bad_checksum:hub_sensor" in out.stderr
    assert "devices.hub_sensor.checksums" in out.stderr and "Traceback" not in out.stderr
