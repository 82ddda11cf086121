"""Bad rig/run files and bus names give errors naming the file, key path and expectation."""

from __future__ import annotations

import pytest

from harness.bus import BusSpecError, parse_bus
from harness.core.runs import load_run, run_from_dict
from harness.core.session import RunRefused, execute_run
from rig_models.rig_file import load_rig, rig_from_dict
from rig_models.schema import ConfigError


def test_rig_value_error_names_key_and_unit():
    data = dict(load_rig("sgsrt").data)
    data["hub"] = dict(data["hub"], inertia_kg_m2="heavy")
    with pytest.raises(ConfigError,
                       match=r"hub\.inertia_kg_m2: expected a finite number > 0 \(kg m\^2\)"):
        rig_from_dict(data, "rig file x.yaml")


def test_rig_unknown_key_is_an_error():
    data = dict(load_rig("sgsrt").data)
    data["beam"] = dict(data["beam"], lenght_m=2.0)
    with pytest.raises(ConfigError, match=r"beam\.lenght_m: unknown key"):
        rig_from_dict(data, "rig file x.yaml")


def test_run_controller_error_names_path():
    raw = {"name": "x", "duration_s": 1.0,
           "controller": {"type": "pd_wheel", "angle_deg": "ten"}}
    with pytest.raises(ConfigError,
                       match=r"controller\.angle_deg: expected a finite number \(deg\)"):
        run_from_dict(raw)


def test_unknown_controller_type():
    with pytest.raises(ConfigError, match="controller.type"):
        run_from_dict({"name": "x", "duration_s": 1.0, "controller": {"type": "magic"}})


def test_unknown_run_lists_builtins():
    with pytest.raises(ConfigError, match="slew-rw"):
        load_run("no-such-run")


@pytest.mark.parametrize("text", ["udp_multicast:224.0.0.1", "nonsense", "pcan:PCAN_USBBUS1",
                                  "socketcand:10.0.0.5:29536"])
def test_bad_bus_specs_refused(text):
    with pytest.raises(BusSpecError):
        parse_bus(text)


def test_bus_specs():
    assert str(parse_bus("virtual:sgsrt")) == "virtual:sgsrt"
    assert parse_bus("socketcan:vcan0").channel == "vcan0"
    spec = parse_bus("socketcand:127.0.0.1:29536")
    assert (spec.host, spec.port) == ("127.0.0.1", 29536)


def test_bus_overload_refused_before_anything_is_sent(tmp_path):
    run = load_run("slew-rw", {"rate_hz": 2000.0})
    with pytest.raises(RunRefused, match="bus load"):
        execute_run(run, out_dir=tmp_path, show_progress=False)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -float("inf"), 10**400],
                         ids=["nan", "inf", "-inf", "1e400-int"])
@pytest.mark.parametrize("key", ["max_angle_deg", "max_rate_deg_s", "max_tip_accel_m_s2",
                                 "max_wheel_speed_rad_s"])
def test_safety_limit_that_is_not_a_finite_number_is_refused(key, bad):
    """A NaN limit compares False with everything, so it would switch its abort off: the
    run file is refused, naming the key, before anything runs."""
    raw = {"name": "x", "duration_s": 1.0,
           "controller": {"type": "pd_wheel", "angle_deg": 10.0}, "limits": {key: bad}}
    with pytest.raises(ConfigError, match=rf"limits\.{key}: expected a finite number"):
        run_from_dict(raw)


def test_nan_angle_limit_in_yaml_is_refused_and_a_finite_one_aborts(tmp_path):
    """A NaN limit: a 30 deg slew with limits.max_angle_deg .nan ran to 14 deg with the
    abort off. Now the file is refused; the same run with the limit 10 is refused before
    its first frame (its plan passes the limit, harness.core.limits)."""
    text = ("name: nan-limit\nduration_s: 25.0\n"
            "controller: {type: pd_wheel, angle_deg: 30.0}\n"
            "limits: {max_angle_deg: %s}\n")
    bad = tmp_path / "bad.yaml"
    bad.write_text(text % ".nan")
    with pytest.raises(ConfigError, match=r"limits\.max_angle_deg: expected a finite number"):
        load_run(str(bad))
    good = tmp_path / "good.yaml"
    good.write_text(text % "10.0")
    with pytest.raises(RunRefused, match=r"hub angle to 2\d\.\d+ deg, beyond the run's "
                       r"limits\.max_angle_deg of 10 deg"):
        execute_run(load_run(str(good)), out_dir=tmp_path / "logs", show_progress=False)
    assert not (tmp_path / "logs").exists() or not any((tmp_path / "logs").iterdir())
