"""Controller types as plugins: found by name in the entry point group
``sgsrt_harness.controllers``, their schemas checked like the built-ins', clashes and broken
plugins refused with one line; the example package installed with pip and run by its name."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import pytest
import yaml

from harness.controllers import registry
from harness.controllers.api import controller_factory
from harness.core.runs import build_controller, load_run, run_from_dict
from harness.core.session import execute_run
from harness.state import RigCommand
from rig_models.schema import ConfigError, Field

ROOT = Path(__file__).resolve().parent.parent
EXAMPLE = ROOT / "examples" / "sgsrt-example-controller"
GROUP = registry.ENTRY_POINT_GROUP


def fake_distribution(root: Path, dist: str, entries: dict[str, str],
                      modules: dict[str, str] | None = None) -> None:
    """An installed distribution as pip leaves one: a dist-info folder with its entry points
    (and the modules they name) under ``root``."""
    info = root / f"{dist.replace('-', '_')}-1.0.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {dist}\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text(
        f"[{GROUP}]\n" + "".join(f"{k} = {v}\n" for k, v in entries.items()))
    for name, code in (modules or {}).items():
        (root / f"{name}.py").write_text(code)


@pytest.fixture
def site(tmp_path, monkeypatch):
    """A folder on sys.path for fake distributions, and a registry that discovers afresh."""
    root = tmp_path / "site"
    root.mkdir()
    monkeypatch.syspath_prepend(str(root))
    monkeypatch.setattr(registry, "REGISTRY", registry.ControllerRegistry())
    return root


GOOD_PLUGIN = '''
from harness.controllers.api import Field, RigCommand, controller_factory

class Constant:
    def __init__(self, torque):
        self.torque = torque
    def reset(self):
        pass
    def step(self, state):
        return RigCommand(wheel_torque_n_m=self.torque)

@controller_factory({"torque_n_m": Field("number", "N m", default=0.0, minimum=-0.065,
                                         maximum=0.065)})
def build(section, rig, dt_s):
    if section["torque_n_m"] == 0.05:
        raise TypeError("a bug in the plugin")
    return Constant(section["torque_n_m"])

def no_schema(section, rig, dt_s):
    return Constant(0.0)

@controller_factory({"gain": 3.0})
def bad_schema(section, rig, dt_s):
    return Constant(0.0)

@controller_factory({})
def no_step(section, rig, dt_s):
    return object()
'''


def test_builtin_types_are_registered_by_the_projects_pyproject_as_the_registry_reads_them():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())
    assert project["project"]["entry-points"][GROUP] == registry.BUILTIN_ENTRY_POINTS
    for name in registry.BUILTIN_ENTRY_POINTS:
        ctype = registry.controller_type(name)
        assert ctype.builtin and ctype.schema["type"] == Field("str", required=True)


def test_a_plugin_is_found_by_name_and_its_schema_checked_like_a_builtins(site):
    fake_distribution(site, "lab-ctrl", {"lab_constant": "lab_ctrl_mod:build"},
                      {"lab_ctrl_mod": GOOD_PLUGIN})
    assert "lab_constant" in registry.controller_names()
    run = run_from_dict({"name": "p", "duration_s": 1.0,
                         "controller": {"type": "lab_constant", "torque_n_m": 0.01}})
    assert run.controller == {"type": "lab_constant", "torque_n_m": 0.01}
    assert registry.controller_type("lab_constant").distribution == "lab-ctrl"
    assert build_controller(run).torque == 0.01
    with pytest.raises(ConfigError, match=r"^run: controller.torque_m: unknown key"):
        run_from_dict({"name": "p", "duration_s": 1.0,
                       "controller": {"type": "lab_constant", "torque_m": 0.01}})
    with pytest.raises(ConfigError, match=r"controller.torque_n_m: expected a finite number "
                                          r">= -0.065 <= 0.065 \(N m\), got 'x'"):
        run_from_dict({"name": "p", "duration_s": 1.0,
                       "controller": {"type": "lab_constant", "torque_n_m": "x"}})
    # the plugin's own bug while building: named, one line, not a traceback
    bug = run_from_dict({"name": "p", "duration_s": 1.0,
                         "controller": {"type": "lab_constant", "torque_n_m": 0.05}})
    with pytest.raises(ConfigError, match=r"controller type 'lab_constant' of lab-ctrl "
                                          r"\(lab_ctrl_mod:build\) failed to build: TypeError"):
        build_controller(bug)


@pytest.mark.parametrize(("other", "dist"), [("lab_ctrl_mod:build", "lab-b"),
                                             ("lab_ctrl_mod:build", "sgsrt-harness")])
def test_a_name_two_distributions_declare_is_an_error_naming_both(site, other, dist):
    fake_distribution(site, "lab-a", {"pd_wheel" if dist == "sgsrt-harness" else "twin":
                                      "lab_ctrl_mod:build"})
    if dist != "sgsrt-harness":
        fake_distribution(site, dist, {"twin": other})
    with pytest.raises(ConfigError) as err:
        run_from_dict({"name": "p", "duration_s": 1.0, "controller": {"type": "hold"}})
    message = str(err.value)
    assert "declared twice" in message and "lab-a" in message and dist in message
    assert "\n" not in message


@pytest.mark.parametrize(("value", "problem"), [
    ("lab_missing_mod:build", "cannot be loaded: ModuleNotFoundError: No module named "
                              "'lab_missing_mod'"),
    ("lab_broken_mod:build", "cannot be loaded: ZeroDivisionError: division by zero"),
    ("lab_ctrl_mod:nowhere", "cannot be loaded: AttributeError"),
    ("lab_ctrl_mod:no_schema", "declares no run-file schema"),
    ("lab_ctrl_mod:bad_schema", "its schema: gain: expected a rig_models.schema.Field"),
])
def test_a_plugin_that_cannot_be_loaded_is_named_with_its_entry_point(site, value, problem):
    fake_distribution(site, "lab-broken", {"lab_type": value},
                      {"lab_ctrl_mod": GOOD_PLUGIN, "lab_broken_mod": "1 / 0\n"})
    with pytest.raises(ConfigError) as err:
        run_from_dict({"name": "p", "duration_s": 1.0, "controller": {"type": "lab_type"}})
    message = str(err.value)
    assert message.startswith(f"controller plugin 'lab_type' of lab-broken (entry point "
                              f"lab_type = '{value}' in group {GROUP})")
    assert problem in message and "\n" not in message
    # a broken plugin does not stop runs of the other types
    assert run_from_dict({"name": "p", "duration_s": 1.0,
                          "controller": {"type": "hold"}}).controller == {"type": "hold"}


def test_a_factory_returning_no_controller_is_refused(site):
    fake_distribution(site, "lab-c", {"lab_nostep": "lab_ctrl_mod:no_step"},
                      {"lab_ctrl_mod": GOOD_PLUGIN})
    run = run_from_dict({"name": "p", "duration_s": 1.0, "controller": {"type": "lab_nostep"}})
    with pytest.raises(ConfigError, match="returned object, which has no step"):
        build_controller(run)


def test_the_declared_schema_gets_the_type_key():
    @controller_factory({"k": Field("number")})
    def build(section, rig, dt_s):  # noqa: ANN001, ANN202
        return None

    assert build.schema == {"type": Field("str", required=True), "k": Field("number")}


class Slow:
    """A controller whose step() takes ``step_s`` of the CPU."""

    def __init__(self, step_s: float) -> None:
        self.step_s = step_s

    def reset(self) -> None:
        pass

    def step(self, state: object) -> RigCommand:
        end = time.perf_counter() + self.step_s
        while time.perf_counter() < end:
            pass
        return RigCommand()


def test_a_controller_over_its_tick_budget_is_named_in_the_summary_with_its_time(
        tmp_path, monkeypatch):
    reg = registry.ControllerRegistry()
    reg.add(registry.ControllerType(
        "lab_slow", {"type": Field("str", required=True), "step_s": Field("number")},
        lambda c, rig, dt_s: Slow(c["step_s"]), "lab-slow", "lab_slow:build"))
    monkeypatch.setattr(registry, "REGISTRY", reg)
    slow = run_from_dict({"name": "slow", "duration_s": 0.4, "controller_budget_ms": 0.5,
                          "controller": {"type": "lab_slow", "step_s": 0.001}})
    s = execute_run(slow, out_dir=tmp_path, show_progress=False).summary
    c = s["controller"]
    assert c["type"] == "lab_slow" and c["distribution"] == "lab-slow" and c["over_budget"]
    assert c["step_budget_ms"] == 0.5 and c["ticks_over_budget"] == s["ticks"] == 201
    assert c["step_mean_ms"] >= 1.0 and c["step_max_ms"] >= 1.0
    # a quick controller, the default budget (a tenth of the 2 ms period)
    hold = run_from_dict({"name": "hold", "duration_s": 1.0, "controller": {"type": "hold"}})
    c = execute_run(hold, out_dir=tmp_path, show_progress=False).summary["controller"]
    assert c["step_budget_ms"] == pytest.approx(0.2) and not c["over_budget"]
    assert c["type"] == "hold" and c["distribution"] == "sgsrt-harness"
    assert 0 < c["step_mean_ms"] < 0.2


# ---------------------------------------------------------------- the example package, for real


@pytest.fixture(scope="module")
def example_site(tmp_path_factory) -> Path:
    """The example package installed with pip into a folder of its own (built from a copy of
    its source, so the tree stays clean); that folder goes on PYTHONPATH."""
    base = tmp_path_factory.mktemp("example")
    src = base / "src"
    shutil.copytree(EXAMPLE, src,
                    ignore=shutil.ignore_patterns("build", "*.egg-info", "__pycache__"))
    target = base / "site"
    proc = subprocess.run(
        [sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--no-build-isolation",
         "--no-index", "--disable-pip-version-check", "--target", str(target), str(src)],
        capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, (
        "pip could not install the example controller package (the test environment needs "
        f"setuptools >= 70.1: pip install -e '.[test]'):\n{proc.stderr[-2000:]}")
    return target


def harness(args: list[str], site: Path | None, cwd: Path) -> subprocess.CompletedProcess:
    paths = ([str(site)] if site is not None else []) + [str(ROOT)]
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        paths + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]))
    return subprocess.run([sys.executable, "-m", "harness", *args], capture_output=True,
                          text=True, env=env, cwd=cwd, timeout=600)


@pytest.mark.slow
def test_the_installed_example_runs_by_its_name_through_the_acceptance_slew_checks(
        example_site, tmp_path):
    proc = harness(["test", str(EXAMPLE / "suite.yaml"), "--out", str(tmp_path),
                    "--workers", "1"], example_site, tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    (results,) = tmp_path.glob("*-example-controller/results.json")
    (test,) = json.loads(results.read_text())["tests"]
    checks = {c["name"]: c["verdict"] for c in test["criteria"]}
    assert test["verdict"] == "PASS"
    assert checks == {name: "PASS" for name in (
        "final_error", "settles", "wheel_torque", "wheel_torque_measured", "malformed",
        "unknown_ids", "safe", "within_budget", "residual_vibration")}
    (summary,) = tmp_path.glob("*-example-controller/*cascade-slew/summary.json")
    s = json.loads(summary.read_text())
    assert s["stopped_by"] == "completed" and s["target_angle_deg"] == 2.0
    assert s["controller"]["type"] == "cascade_slew"
    assert s["controller"]["distribution"] == "sgsrt-example-controller"
    assert s["controller"]["entry_point"] == "sgsrt_example_controller:build_cascade_slew"
    assert not s["controller"]["over_budget"], s["controller"]


def test_without_the_package_installed_the_type_is_unknown():
    if "cascade_slew" in registry.controller_names():
        pytest.skip("the example package is installed in this environment (pip install -e)")
    with pytest.raises(ConfigError, match=r"controller.type: expected one of \[.*\], got "
                                          r"'cascade_slew'"):
        load_run(str(EXAMPLE / "runs" / "cascade-slew.yaml"))


def test_the_examples_schema_errors_name_its_keys(example_site, tmp_path):
    """On the command line: one line naming the key, exit 2, nothing written."""
    run = yaml.safe_load((EXAMPLE / "runs" / "cascade-slew.yaml").read_text())
    run["controller"]["rate_gain"] = 2.0
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(run))
    out = tmp_path / "logs"
    proc = harness(["run", str(path), "--out", str(out)], example_site, tmp_path)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.strip().splitlines() == [
        "harness: run file bad.yaml: controller.rate_gain: unknown key (expected one of: "
        "angle_bandwidth_rad_s, angle_deg, feedforward, max_rate_deg_s, rate_bandwidth_rad_s, "
        "start_s, torque_fraction, type)"]
    assert not out.exists() or not list(out.iterdir())


@pytest.mark.parametrize(("change", "expected"), [
    ({"max_rate_deg_s": "fast"}, "controller.max_rate_deg_s: expected a finite number > 0 "
                                 "(deg/s), got 'fast'"),
    ({"torque_fraction": 1.5}, "controller.torque_fraction: expected a finite number > 0 "
                               "<= 1, got 1.5"),
    ({"rate_bandwidth_rad_s": 400.0}, "controller: rate_bandwidth_rad_s 400 is too fast"),
])
def test_the_installed_examples_values_are_checked_by_its_schema(example_site, monkeypatch,
                                                                 change, expected):
    monkeypatch.syspath_prepend(str(example_site))
    monkeypatch.setattr(registry, "REGISTRY", registry.ControllerRegistry())
    path = EXAMPLE / "runs" / "cascade-slew.yaml"
    assert build_controller(load_run(str(path))).step is not None
    with pytest.raises(ConfigError) as err:
        build_controller(load_run(str(path), {"controller": change}))
    assert str(err.value).startswith(f"run file cascade-slew.yaml: {expected}")
