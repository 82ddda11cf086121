"""Which rig said it: ``rig_models.rig_file.rig_identity`` (name, hash of the resolved rig
file, binding summary), the one function every output names its rig with."""

from __future__ import annotations

import shutil
from pathlib import Path

import yaml

from harness.core.runs import load_run
from rig_models.rig_file import (
    RIGS_DIR,
    binding_text,
    identity_text,
    load_rig,
    rig_identity,
    rig_sha256,
)

DRIVERS = Path(__file__).resolve().parents[1] / "drivers"


def _lab_rig(folder: Path, name: str = "lab-rig", **beam: float) -> Path:
    """A lab's own rig file: extends the shipped sgsrt, its own name, its own DBC copy."""
    folder.mkdir(parents=True, exist_ok=True)
    shutil.copy(RIGS_DIR / "sgsrt.yaml", folder / "sgsrt.yaml")
    shutil.copy(DRIVERS / "sgsrt_dbc2.dbc", folder / "lab.dbc")
    dbc2 = yaml.safe_load((RIGS_DIR / "sgsrt-dbc2.yaml").read_text())
    for dev in dbc2["devices"].values():
        dev["dbc"] = "lab.dbc"
    for key in ("sync", "heartbeat"):
        dbc2["bus"][key]["dbc"] = "lab.dbc"
    dbc2.update(extends="sgsrt.yaml", name=name)
    if beam:
        dbc2["beam"] = beam
    path = folder / f"{name}.yaml"
    path.write_text(yaml.safe_dump(dbc2, sort_keys=False))
    return path


def test_a_labs_own_rig_file_shows_its_own_name_hash_and_binding(tmp_path):
    path = _lab_rig(tmp_path / "a")
    ident = rig_identity(load_rig(str(path)).data, "socketcan:can0")
    assert ident["rig"] == "lab-rig" and ident["bus"] == "socketcan:can0"
    assert ident["binding"]["reaction_wheel"] == {"binding": "dbc", "dbc": "lab.dbc"}
    assert binding_text(ident["binding"]) == "dbc lab.dbc: every device"
    assert identity_text(ident).startswith(f"rig lab-rig (sha256 {ident['rig_sha256'][:12]}), "
                                           "bus socketcan:can0, binding dbc lab.dbc")
    # the same files in another folder: the same rig
    other = _lab_rig(tmp_path / "b")
    assert rig_sha256(load_rig(str(other)).data) == ident["rig_sha256"]
    # the base it extends is part of it: another beam in the base is another rig
    base = yaml.safe_load((tmp_path / "b" / "sgsrt.yaml").read_text())
    base["beam"]["youngs_modulus_pa"] *= 1.01
    (tmp_path / "b" / "sgsrt.yaml").write_text(yaml.safe_dump(base))
    assert rig_sha256(load_rig(str(other)).data) != ident["rig_sha256"]
    # so is the DBC it names: an edited DBC is another rig
    third = _lab_rig(tmp_path / "c")
    with (tmp_path / "c" / "lab.dbc").open("a") as f:
        f.write("\nCM_ \"edited\";\n")
    assert rig_sha256(load_rig(str(third)).data) != ident["rig_sha256"]


def test_each_shipped_rig_has_its_own_identity_and_default_bus():
    seen = set()
    for rig in ("sgsrt", "sgsrt-canopen", "sgsrt-dbc2"):
        run = load_run("slew-rw", {"rig": rig})
        assert run.data["bus"] == f"virtual:{rig}"
        ident = rig_identity(run.rig.data, run.data["bus"])
        assert ident["rig"] == rig
        seen.add(ident["rig_sha256"])
    assert len(seen) == 3
    canopen = rig_identity(load_rig("sgsrt-canopen").data)["binding"]
    assert canopen["hub_sensor"] == {"binding": "canopen", "node_id": 4,
                                     "eds": "sgsrt_encoder.eds"}
    assert rig_identity(load_rig("sgsrt").data)["binding"]["accelerometer"] == {
        "binding": "sgsrt"}
    # rig_overrides make another resolved rig
    over = load_run("slew-rw", {"rig_overrides": {"beam": {"damping_ratio": 0.02}}})
    assert rig_sha256(over.rig.data) != rig_sha256(load_rig("sgsrt").data)
