"""A deploy's calls to modules: a BUSY answer (nothing done) is tried again after a pause, as a timeout is; any
other refusal ends the call at once."""

from __future__ import annotations

import time

import pytest

from asm_py.errors import AsmTimeout, RemoteError
from asm_py.protocol import Status
from gaits import calls
from gaits.calls import DeployError, ModuleCalls


class _Node:
    """Stands for the client node: ModuleCalls only keys its lookups by it."""


def _answering(*answers: object):
    made: list[float] = []

    def operation(timeout: float) -> object:
        made.append(time.monotonic())
        answer = answers[len(made) - 1]
        if isinstance(answer, Exception):
            raise answer
        return answer

    return operation, made


def test_a_busy_bridge_is_asked_again_after_a_growing_pause(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(calls, "BUSY_PAUSE", 0.02)
    busy = RemoteError("too many requests in flight through the bridge (32 of yours)", Status.BUSY)
    operation, made = _answering(busy, busy, "staged")
    assert ModuleCalls(_Node(), {3: "m3"}).call(3, "stage", operation) == "staged"  # type: ignore[arg-type]
    assert len(made) == 3
    assert made[1] - made[0] >= 0.02 and made[2] - made[1] >= 0.04


def test_busy_to_the_last_attempt_fails_the_call_naming_module_and_step(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(calls, "BUSY_PAUSE", 0.001)
    busy = RemoteError("busy", Status.BUSY)
    operation, made = _answering(*[busy] * 6)
    with pytest.raises(DeployError, match=r"module 3 \(m3\), stage: busy"):
        ModuleCalls(_Node(), {3: "m3"}, attempts=6).call(3, "stage", operation)  # type: ignore[arg-type]
    assert len(made) == 6


def test_another_refusal_is_not_tried_again() -> None:
    operation, made = _answering(RemoteError("malformed", Status.BAD_MESSAGE), "never")
    with pytest.raises(DeployError, match="malformed"):
        ModuleCalls(_Node(), {3: "m3"}).call(3, "stage", operation)  # type: ignore[arg-type]
    assert len(made) == 1


def test_a_request_of_many_frames_gets_more_attempts_on_timeouts_but_not_on_busy(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A gait table of 22 CAN frames is lost whenever any of its frames is: it is tried 5 + 2 times, not 5."""
    lost = AsmTimeout("no reply")
    operation, made = _answering(*[lost] * 6, "staged")
    calls_ = ModuleCalls(_Node(), {3: "m3"}, timeout=0.01, attempts=5)  # type: ignore[arg-type]
    assert calls_.call(3, "stage", operation, size=165) == "staged"
    assert len(made) == 7
    operation, made = _answering(*[lost] * 8)
    with pytest.raises(DeployError, match="no reply"):
        calls_.call(3, "stage", operation, size=165)
    assert len(made) == 7
    operation, made = _answering(*[lost] * 5, "never")  # one frame: the attempts asked for
    with pytest.raises(DeployError):
        calls_.call(3, "stage", operation, size=4)
    assert len(made) == 5
    monkeypatch.setattr(calls, "BUSY_PAUSE", 0.001)
    busy = RemoteError("busy", Status.BUSY)
    operation, made = _answering(*[busy] * 7)
    with pytest.raises(DeployError, match="busy"):
        calls_.call(3, "stage", operation, size=165)
    assert len(made) == 5


def test_the_extra_attempts_are_capped_and_a_busy_after_timeouts_keeps_them(monkeypatch: pytest.MonkeyPatch) -> None:
    """A module that never answers a 4 kB request is tried 6 + 2 times, not 68; a BUSY answer after timeouts (the
    bridge still holds the lost requests) does not end a call that has tries left."""
    lost = AsmTimeout("no reply")
    calls_ = ModuleCalls(_Node(), {3: "m3"}, timeout=0.01, attempts=6)  # type: ignore[arg-type]
    operation, made = _answering(*[lost] * 70)
    with pytest.raises(DeployError):
        calls_.call(3, "stage", operation, size=4000)
    assert len(made) == 8
    monkeypatch.setattr(calls, "BUSY_PAUSE", 0.001)
    operation, made = _answering(*[lost] * 5, RemoteError("busy", Status.BUSY), "staged")
    assert calls_.call(3, "stage", operation, size=165) == "staged"
    assert len(made) == 7
