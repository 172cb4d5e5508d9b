"""A deploy's calls to modules: a BUSY answer (nothing done) is tried again after a pause, as a timeout is; any
other refusal ends the call at once."""

from __future__ import annotations

import time

import pytest

from asm_py.errors import RemoteError
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
