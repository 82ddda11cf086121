"""`harness twin` as an alarm: the devices' quantisation reproduced, every channel judged,
a threshold with exit 1 beyond it, the worst channel first."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import pytest
import yaml

from harness.cli import main
from harness.core.runs import load_run
from harness.core.session import execute_run

ROOT = Path(__file__).resolve().parent.parent


def _canopen_rig(tmp_path: Path, speed_object: int | None = None) -> Path:
    """sgsrt-canopen as a file of the lab's own; ``speed_object``: the wheel speed bound to
    another object (a wrong binding)."""
    src = yaml.safe_load((ROOT / "rig_models/rigs/sgsrt-canopen.yaml").read_text())
    src["extends"] = str(ROOT / "rig_models/rigs/sgsrt.yaml")
    for d in src["devices"].values():
        if "eds" in d:
            d["eds"] = str(ROOT / "drivers/eds" / d["eds"])
    rig = copy.deepcopy(src)
    if speed_object is not None:
        rig["name"] = "sgsrt-canopen-wrong"
        rig["devices"]["reaction_wheel"]["telemetry"]["speed"] = {"object": speed_object,
                                                                   "scale": 0.001}
    path = tmp_path / f"{rig['name']}.yaml"
    path.write_text(yaml.safe_dump(rig))
    return path


def _twin(run_dir: Path, capsys, *extra: str) -> tuple[int, dict]:
    capsys.readouterr()
    code = main(["twin", str(run_dir), "--json", *extra])
    return code, json.loads(capsys.readouterr().out)


@pytest.fixture(scope="module")
def canopen_runs(tmp_path_factory) -> dict[str, Path]:
    tmp = tmp_path_factory.mktemp("twin")
    out = {}
    for name, rig in (("model", _canopen_rig(tmp)), ("wrong", _canopen_rig(tmp, 0x6077))):
        out[name] = execute_run(load_run("slew-rw", {"duration_s": 8.0, "rig": str(rig),
                                                     "bus": None}),
                                out_dir=tmp / name, show_progress=False).run_dir
    return out


def test_a_canopen_rig_that_is_its_model_passes_every_channel(canopen_runs, capsys):
    code, out = _twin(canopen_runs["model"], capsys)
    assert code == 0 and out["beyond"] == []
    by = {c["channel"]: c for c in out["channels"]}
    # the drive quantises the torque command to its per mille: so does the twin (without it
    # the wheel speed's residual is 4.4 x its resolution on this slew: an alarm on a rig
    # that is exactly its model)
    assert 0.8 < by["/attitude/angle_deg"]["rms_over_noise"] < 1.3
    # every channel judged: the wheel's from the drive's resolution (device data)
    for name in ("/wheel/speed_rad_s", "/wheel/torque_n_m"):
        assert by[name]["noise_from"] == "device data's resolution"
        assert by[name]["rms_over_noise"] < out["max_ratio"]


def test_a_wrong_binding_is_an_alarm_naming_that_channel_first(canopen_runs, capsys):
    code, out = _twin(canopen_runs["wrong"], capsys)
    assert code == 1
    assert out["beyond"][0] == "/wheel/speed_rad_s"
    assert out["channels"][0]["channel"] == "/wheel/speed_rad_s"
    capsys.readouterr()
    assert main(["twin", str(canopen_runs["wrong"])]) == 1
    cap = capsys.readouterr()
    assert cap.err.splitlines()[0].startswith("ALARM /wheel/speed_rad_s")
    first_row = next(line for line in cap.out.splitlines() if line.startswith("/"))
    assert first_row.startswith("/wheel/speed_rad_s")


def test_the_threshold_is_an_option(canopen_runs, capsys):
    code, out = _twin(canopen_runs["model"], capsys, "--max-ratio", "0.5")
    assert code == 1 and out["max_ratio"] == 0.5 and out["beyond"]
    capsys.readouterr()
    assert main(["twin", str(canopen_runs["model"]), "--max-ratio", "0"]) == 2
    assert "--max-ratio" in capsys.readouterr().err
