"""How the commissioning service watches a wiggled joint (server/commission_service.py's ``_wiggle``), against joints
whose motion the test sets: one that pauses on its way (an emulated board on a loaded machine), one a limit holds
short, one that hardly moves. The service's answer is what a person numbering modules reads."""

from __future__ import annotations

import threading
import time

import pytest

from server import commission_service
from server.commission_service import CommissionService


class Joint:
    """A joint's goal and angle: the angle follows the goal at ``speed`` degrees a second, stops at ``limit``
    degrees from the start, and stands still for ``pause`` seconds once it has moved ``pause_at`` degrees."""

    def __init__(self, speed: float = 60.0, limit: float = 90.0, pause_at: float = 1e9, pause: float = 0.0) -> None:
        self.speed, self.limit, self.pause_at, self.pause = speed, limit, pause_at, pause
        self._lock = threading.Lock()
        self._goal = 0.0
        self._angle = 0.0
        self._since = time.monotonic()
        self._paused_until = 0.0
        self.goal = _Attribute(lambda: self._goal, self._set_goal)
        self.angle = _Attribute(self._read_angle, None)

    def _set_goal(self, value: float) -> None:
        with self._lock:
            self._advance()
            self._goal = value

    def _advance(self) -> None:
        now = time.monotonic()
        dt, self._since = now - self._since, now
        if now < self._paused_until:
            return
        step = min(self.speed * dt, abs(self._goal - self._angle))
        angle = self._angle + (step if self._goal > self._angle else -step)
        angle = max(-self.limit, min(self.limit, angle))
        if abs(self._angle) < self.pause_at <= abs(angle):
            self._paused_until = now + self.pause
        self._angle = angle

    def _read_angle(self) -> float:
        with self._lock:
            self._advance()
            return self._angle


class _Attribute:
    def __init__(self, read, write) -> None:
        self._read, self._write = read, write

    def get(self, timeout: float | None = None) -> float:
        return self._read()

    def set(self, value: float, wait: bool = False, timeout: float | None = None) -> None:
        self._write(value)


def _service(joint: Joint) -> CommissionService:
    """The service's wiggle alone: no bus, no Zenoh (only ``_wiggle`` and what it reads are used)."""
    service = object.__new__(CommissionService)
    service._heard = None  # type: ignore[attr-defined]  # no e-stop heard
    service._joint = lambda name: (joint.goal, joint.angle)  # type: ignore[method-assign]  # the test's joint
    return service


def test_a_joint_that_pauses_on_its_way_is_watched_until_it_is_there() -> None:
    """A fresh-clone run with four test workers answered 12.48° for a 15° wiggle of an emulated board: the service
    took 0.4 s without progress for a joint held short, and the board had only been starved of the CPU."""
    joint = Joint(speed=60.0, pause_at=10.0, pause=0.7)
    moved = _service(joint)._wiggle(3, 15.0)
    assert moved >= 15.0 - commission_service.ARRIVED, moved
    assert abs(joint.angle.get()) <= 1.0, "the joint is back before the answer"


def test_a_joint_stalled_longer_than_a_second_on_its_way_is_watched_until_it_is_there() -> None:
    """A three-worker run of the suite (stop 54) answered 13.27° for a 15° wiggle: the robot's real-time physics,
    starved of the CPU, held the joint still for more than the second the service then allowed a joint past halfway."""
    joint = Joint(speed=60.0, pause_at=11.0, pause=1.5)
    moved = _service(joint)._wiggle(3, 15.0)
    assert moved >= 15.0 - commission_service.ARRIVED, moved


def test_a_joint_a_limit_holds_short_answers_what_it_moved_after_it_settles() -> None:
    joint = Joint(speed=60.0, limit=10.0)
    began = time.monotonic()
    moved = _service(joint)._wiggle(3, 15.0)
    took = time.monotonic() - began
    assert 9.8 <= moved <= 10.0, moved
    assert took < commission_service.FULL_MOVE_TIMEOUT, f"waited {took:.1f} s for a joint that had stopped"


def test_a_joint_that_never_gets_halfway_is_an_error(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(commission_service, "MOVE_TIMEOUT", 0.5)
    joint = Joint(speed=60.0, limit=5.0)
    with pytest.raises(TimeoutError, match=r"moved 5\.0° of 15°"):
        _service(joint)._wiggle(3, 15.0)
