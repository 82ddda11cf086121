"""Run-file strings never choose a path outside the output folder (harness/core/paths.py)."""

from __future__ import annotations

from pathlib import Path

import pytest

from harness.core.paths import MAX_NAME_BYTES, UnsafePathError, safe_child, safe_name
from harness.core.runs import load_run
from harness.core.session import make_run_dir
from rig_models.schema import ConfigError

UNSAFE = ["../../etc/x", "/etc/passwd", "..", ".", "", "a/../../b", "..\\..\\win",
          ".hidden", "-rf", "x\x00y", "line\nbreak", "tab\there", " ", "...", "a" * 1000,
          "é" * 400, "名前/../..", "\u202e evil", "C:\\x"]


@pytest.mark.parametrize("text", UNSAFE)
def test_safe_name_is_one_safe_component(text: str, tmp_path: Path) -> None:
    name = safe_name(text)
    assert name and name not in (".", "..")
    assert "/" not in name and "\\" not in name and ".." not in name
    assert not name.startswith((".", "-"))
    assert all(ch.isprintable() for ch in name)
    assert len(name.encode()) <= MAX_NAME_BYTES
    p = safe_child(tmp_path, text)
    assert p.parent == tmp_path
    p.mkdir()  # the file system accepts it
    assert p.resolve().parent == tmp_path.resolve()


def test_safe_names_unchanged_and_distinct() -> None:
    for ok in ("slew-rw", "case-a-beta-0.8", "shaped_zvd+1", "β-0.8", "名前"):
        assert safe_name(ok) == ok
    # two unsafe names that clean up alike still get different directories
    assert safe_name("a/b") != safe_name("a:b")
    assert safe_name("../../etc/x").startswith("etc_x-")
    assert safe_name("") == "unnamed"


def test_safe_child_refuses_escape_through_a_symlink(tmp_path: Path) -> None:
    out = tmp_path / "out"
    out.mkdir()
    (out / "link").symlink_to(tmp_path)
    with pytest.raises(UnsafePathError) as err:
        safe_child(out, "link", "x")
    assert "link/x" in str(err.value) and "outside the output folder" in str(err.value)
    assert isinstance(err.value, ConfigError)


def test_run_name_cannot_leave_the_output_folder(tmp_path: Path) -> None:
    out = tmp_path / "logs"
    for name in ("../../etc/x", "/abs/path", "..", ""):
        run_dir = make_run_dir(out, name)
        assert run_dir.resolve().parent == out.resolve()
    assert not (tmp_path / "etc").exists()


def test_run_file_name_with_traversal_runs_inside_out(tmp_path: Path) -> None:
    from harness.core.session import execute_run

    run = load_run("slew-rw", {"name": "../../etc/x", "duration_s": 0.05})
    res = execute_run(run, out_dir=tmp_path / "logs", show_progress=False)
    assert res.run_dir.resolve().parent == (tmp_path / "logs").resolve()
    assert (res.run_dir / "run.rrd").exists()
    assert res.summary["run"] == "../../etc/x"  # the name itself is kept in the summary
