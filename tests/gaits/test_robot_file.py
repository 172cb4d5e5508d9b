"""A robot file's problems are its own, and the loader's gaps around module types are closed (issue 30's review,
defects 5, 6 and 11): the ``gaits`` command and the studio name the robot file a problem is in, a symbolic link
loop is a GaitError like any other bytes, and the descriptions the README says are refused are."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from gaits.cli import main
from gaits.model import LIBRARY, GaitError, load, loads

pytestmark = pytest.mark.timeout(120)
CATERPILLAR = (LIBRARY / "caterpillar.toml").read_text(encoding="utf-8")


def gait_file(folder: Path, robot: bytes | None, name: str = "robot.toml", gait: str = "gait.toml") -> Path:
    """A caterpillar in ``folder`` naming robot file ``name`` (written with ``robot`` unless None)."""
    if robot is not None:
        (folder / name).write_bytes(robot)
    path = folder / gait
    path.write_text(CATERPILLAR.replace("module_size = 0.05\n", f'module_size = 0.05\nfile = "{name}"\n', 1),
                    encoding="utf-8")  # fmt: skip
    return path


BAD_ROBOT = b'[robot]\ntype = "a"\n[robot.types.a]\nmass = 0.3\n[robot.types.b]\nids = [1]\nmass = -1\n'


@pytest.mark.parametrize(
    ("content", "words"),
    [
        (BAD_ROBOT, "robot.toml, line 7: robot.types.b.mass: must be in [0.001, 1000] kg, not -1"),
        (b"[robot.module]\nmass = 0.3\n\xff\n", "robot.toml, line 3: (file): not UTF-8 text"),
        (b"#" * (3 * 1024 * 1024), "robot.toml, line 1: (file): larger than 2 MiB: not a robot file"),
    ],
)
def test_the_gaits_command_names_the_robot_file_a_problem_is_in(tmp_path, capsys, content: bytes, words: str) -> None:
    path = gait_file(tmp_path, content)
    good = tmp_path / "good.toml"
    good.write_text(CATERPILLAR, encoding="utf-8")
    assert main(["validate", str(path), str(good)]) == 1
    err = capsys.readouterr().err
    assert err.startswith(f"{path}: INVALID\n  {tmp_path / words}"), err
    for command in (["simulate", str(path)], ["tune", str(path), "--free", "amplitude=20:80"]):
        assert main(command) == 1
        err = capsys.readouterr().err
        assert str(tmp_path / words) in err, err


def test_the_studio_names_the_robot_file_a_problem_is_in(tmp_path) -> None:
    from web.document import GaitDocument
    from web.editor import page_label

    path = gait_file(tmp_path, b"[robot.module]\nmass = 0.3\n")
    doc = GaitDocument(load(path), text=path.read_text(encoding="utf-8"), path=path)
    (tmp_path / "robot.toml").write_bytes(BAD_ROBOT)  # changed on disk meanwhile: the next edit reads it again
    doc.set_robot("friction", 0.9)
    assert [page_label(p) for p in doc.problems] == [
        f"{tmp_path / 'robot.toml'}, line 7: robot.types.b.mass: must be in [0.001, 1000] kg, not -1"
    ]


@pytest.mark.parametrize("links", [{"a.toml": "b.toml", "b.toml": "a.toml"}, {"a.toml": "a.toml"}])
def test_a_loop_of_symbolic_links_is_a_problem_at_robot_file(tmp_path, capsys, links: dict[str, str]) -> None:
    for link, target in links.items():
        os.symlink(target, tmp_path / link)
    path = gait_file(tmp_path, None, name="a.toml")
    with pytest.raises(GaitError, match=r"robot\.file: 'a\.toml' cannot be read: its symbolic links form a loop"):
        load(path)
    good = tmp_path / "good.toml"
    good.write_text(CATERPILLAR, encoding="utf-8")
    assert main(["validate", str(path), str(good)]) == 1  # and the files after it are checked
    out, err = capsys.readouterr()
    assert f"{good}: ok" in out and "symbolic links form a loop" in err and "Traceback" not in err


@pytest.mark.parametrize(
    ("description", "problems"),
    [  # every module is of a named type: the default type describes none of them
        ('type = "a"\n[robot.types.a]\nmass = 5\n[robot.types.b]\nids = [1, 2, 3, 4, 5, 6, 7, 8]\n', ["robot.type"]),
        ("[robot.module]\nmass = 0.3\n[robot.types.b]\nids = [1, 2, 3, 4, 5, 6, 7, 8]\n", ["robot.module"]),
        ("[robot.types.a]\nids = [1.0]\n", ["robot.types.a.ids[0]"]),  # an ID is an integer, never 1.0
        (
            'type = "a"\n[robot.types.a]\nids = [1]\nmass = 0.3\n[robot.types.b]\nids = [2]\n',
            ["robot.types.a.ids"],
        ),  # the default type has no IDs of its own
        ('type = "a"\n[robot.module]\nmass = 1\n[robot.types.a]\n', ["robot.type"]),  # one problem, no follow-on
    ],
)
def test_the_loader_refuses_what_the_readme_says_it_refuses(description: str, problems: list[str]) -> None:
    text = CATERPILLAR.replace("module_size = 0.05\n", "module_size = 0.05\n" + description, 1)
    with pytest.raises(GaitError) as refused:
        loads(text)
    assert [p.path for p in refused.value.problems] == problems, refused.value


def test_a_robot_file_name_ending_in_a_slash_is_no_file(tmp_path) -> None:
    path = gait_file(tmp_path, b"[robot.module]\nmass = 0.3\n")
    path.write_text(path.read_text(encoding="utf-8").replace('"robot.toml"', '"robot.toml/"'), encoding="utf-8")
    with pytest.raises(GaitError, match=r"robot\.file: 'robot\.toml/' is not a regular file"):
        load(path)


def test_a_robot_file_name_with_a_nul_says_why_it_cannot_be_read(tmp_path) -> None:
    """A second review: 'a\\x00b' "cannot be read: ValueError" (an exception's class name, not a reason)."""
    path = gait_file(tmp_path, b"[robot.module]\nmass = 0.3\n")
    path.write_text(path.read_text(encoding="utf-8").replace('"robot.toml"', '"a\\u0000b"'), encoding="utf-8")
    with pytest.raises(GaitError, match=r"robot\.file: 'a\\x00b' cannot be read: a file name cannot hold a NUL"):
        load(path)


def test_an_inertia_of_the_wrong_size_says_how_many_numbers() -> None:
    text = CATERPILLAR.replace("module_size = 0.05\n", "module_size = 0.05\n[robot.module]\ninertia = [1, 1]\n", 1)
    with pytest.raises(GaitError, match=r"robot\.module\.inertia: must have 3 items, not 2"):
        loads(text)
