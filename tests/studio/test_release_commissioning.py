"""The E-STOP's Release (web/robot_bar.py) releases the robot's commissioning service too, and says so even when a
module cannot be released (issue 28's fourth review: after an e-stop during a wiggle, the temporary ID's module was
gone, the release ended in an error, and that commissioning had been released was never said)."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from gaits.calls import DeployError
from web.robot_bar import RobotBar


class _Robot:
    def __init__(self, commissioning: bool, fails: bool) -> None:
        self.commissioning, self.fails = commissioning, fails
        self.order: list[str] = []

    def release_commissioning(self) -> bool:
        self.order.append("commissioning")
        return self.commissioning

    def release(self, modules: list[str]) -> list[str]:
        self.order.append("modules")
        if self.fails:
            raise DeployError(f"released 0 of {len(modules)} modules; module 1 (m199): m199 is not reachable now")
        return list(modules)


def _bar(robot: _Robot) -> tuple[SimpleNamespace, list[tuple[str, str]]]:
    said: list[tuple[str, str]] = []
    page = SimpleNamespace(robot=robot, notify=lambda title, text, **_: said.append((title, text)))
    return SimpleNamespace(page=page), said


def test_release_says_the_commissioning_was_released_even_when_a_module_was_not() -> None:
    robot = _Robot(commissioning=True, fails=True)
    bar, _ = _bar(robot)
    with pytest.raises(ValueError, match=r"m199 is not reachable now; released and the robot's commissioning"):
        RobotBar._release(bar, ["m199"])  # type: ignore[arg-type]
    assert robot.order == ["commissioning", "modules"]


def test_release_of_every_module_and_the_commissioning_is_said_in_one_line() -> None:
    bar, said = _bar(_Robot(commissioning=True, fails=False))
    RobotBar._release(bar, ["m1", "m2"])  # type: ignore[arg-type]
    assert said == [("E-STOP released", "released on 2 of 2 modules and the robot's commissioning (wiggles, node IDs)")]
    bar, said = _bar(_Robot(commissioning=False, fails=False))
    RobotBar._release(bar, ["m1"])  # type: ignore[arg-type]
    assert said == [("E-STOP released", "released on 1 of 1 modules")]
