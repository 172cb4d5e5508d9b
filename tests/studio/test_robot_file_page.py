"""A gait that names a robot file round-trips through the page (issue 30's review, defect 7): a download uploads back
with its robot file, and the module size a robot file sets is not edited into a gait that would then be invalid."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import pytest

from gaits.model import LIBRARY, load
from web.document import GaitDocument

pytestmark = pytest.mark.timeout(120)
CATERPILLAR = (LIBRARY / "caterpillar.toml").read_text(encoding="utf-8")


def robot_gait(folder: Path, robot: str) -> Path:
    (folder / "robot.toml").write_text(robot, encoding="utf-8")
    path = folder / "mine.toml"
    path.write_text(CATERPILLAR.replace("module_size = 0.05\n", 'file = "robot.toml"\n', 1), encoding="utf-8")
    return path


def test_a_downloaded_gait_uploads_back_with_its_robot_file(tmp_path) -> None:
    path = robot_gait(tmp_path, "[robot.module]\nmass = 0.3\n")
    doc = GaitDocument(load(path), text=path.read_text(encoding="utf-8"), path=path)
    doc.set_state("wave", 0, "angle", 20.0)
    downloaded = doc.text()  # what Download .toml gives
    assert 'file = "robot.toml"' in downloaded
    assert doc.upload(downloaded.encode(), "mine (1).toml") == tmp_path
    assert not doc.problems and doc.gait().robot.file == "robot.toml" and doc.gait().robot.module.mass == 0.3
    assert doc.gait().automata["wave"].states[0].angle == 20.0
    lone = GaitDocument(load(LIBRARY / "caterpillar.toml"))  # a page whose gait has no file: nowhere to look
    with pytest.raises(Exception, match=r"robot\.file: this gait has no folder to find 'robot\.toml'"):
        lone.upload(downloaded.encode(), "mine.toml")


def test_the_module_size_a_robot_file_sets_is_not_edited_into_an_invalid_gait(tmp_path, studio) -> None:
    path = robot_gait(tmp_path, '[robot]\ntype = "t"\n[robot.types.t]\nlength = 0.06\n')
    doc = GaitDocument(load(path), text=path.read_text(encoding="utf-8"), path=path)
    assert doc.sized_by_robot_file() == "robot.types.t.length in robot.toml"
    with pytest.raises(ValueError, match=r"the module size is the robot file's \(robot\.types\.t\.length in robot"):
        doc.set_robot("module_size", 0.07)
    assert not doc.problems and doc.gait().robot.module_size == 0.06
    editor = studio.app.editor
    editor.open_file(path)
    assert editor.module_size.disabled and editor.module_size.value == 0.06
    assert "robot.types.t.length in robot.toml" in editor.module_size.hint
    upload = SimpleNamespace(target=SimpleNamespace(value=SimpleNamespace(content=CATERPILLAR.encode(), name="c.toml")))
    editor._on_upload(upload)  # a gait describing no module: its size is its own again
    assert not editor.module_size.disabled and studio.app.doc.gait().robot.file is None
