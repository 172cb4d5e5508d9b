"""gaits.lease: who holds a module's lease is read from the lease only when the module's LOCKED reply said nothing
(a board's), told by the reply's own text kept on the exception, not guessed from how the message ends."""

from __future__ import annotations

from typing import Any

import pytest

from asm_py.errors import Locked
from asm_py.protocol import Message, Status
from asm_py.status import raise_for_status, reply_text
from gaits.calls import DeployError
from gaits.lease import Lease


def _locked(text: bytes) -> Locked:
    reply = Message(kind=2, method=0, txn=0, status=int(Status.LOCKED), object_id=0, data=text)
    with pytest.raises(Locked) as caught:
        raise_for_status(reply, "m1 set gait.lease")
    return caught.value


class _Calls:
    """ModuleCalls' part a Lease uses: every set refused LOCKED with ``text``; gets answer the lease record."""

    def __init__(self, text: bytes) -> None:
        self.text = text
        self.names = {1: "m1"}
        self.gets: list[tuple[int, str]] = []

    def set(self, module: int, name: str, value: Any, step: str) -> None:
        raise DeployError(f"module {module} (m1), {step}: refused") from _locked(self.text)

    def get(self, module: int, name: str, step: str) -> Any:
        self.gets.append((module, name))
        return {"holder": "other@lab:42", "token": 7, "seconds": 4.5}


def test_a_reply_s_own_text_is_kept_on_the_exception_it_raises() -> None:
    assert reply_text(_locked(b"")) == ""
    assert reply_text(_locked(b"held: ")) == "held: "
    assert str(_locked(b"")) == "m1 set gait.lease: "
    assert reply_text(Locked("raised here")) is None  # not from a reply


def test_a_text_less_locked_reply_names_the_holder_read_from_the_lease() -> None:
    calls = _Calls(b"")
    with pytest.raises(DeployError, match=r"held by 'other@lab:42'"):
        Lease(calls, [1], "me", 1).take()  # type: ignore[arg-type]  (a stand-in for ModuleCalls)
    assert calls.gets == [(1, "gait.lease")]


def test_a_locked_reply_whose_text_ends_in_a_colon_is_passed_on_as_it_is() -> None:
    """A Python module's refusal ending in ": " was taken for a board's empty one and answered with the lease's
    holder instead of what the module said."""
    calls = _Calls(b"the robot is being deployed by: ")
    with pytest.raises(DeployError, match="refused") as caught:
        Lease(calls, [1], "me", 1).take()  # type: ignore[arg-type]
    assert calls.gets == []
    assert "held by" not in str(caught.value)


class _ClosingCalls:
    """A node that grants the lease, then closes (a studio closed while its staged deployment held the robot)."""

    def __init__(self) -> None:
        self.names = {1: "m1"}
        self.closed = False

    def set(self, module: int, name: str, value: Any, step: str) -> None:
        if self.closed:
            raise RuntimeError("zenoh transport is not open")  # what a closed ZenohTransport says


def test_a_lease_whose_node_closed_stops_renewing_without_an_exception_in_its_thread(monkeypatch) -> None:
    """A fresh-clone run: "Exception in thread asm-lease: RuntimeError: zenoh transport is not open" after the
    studio that staged closed; the lease lapses by itself on the modules."""
    import threading

    from gaits import lease as lease_module

    from ..helpers import wait_until

    monkeypatch.setattr(lease_module, "RENEW_EVERY", 0.01)
    raised: list[BaseException | None] = []
    monkeypatch.setattr(threading, "excepthook", lambda args: raised.append(args.exc_value))
    calls = _ClosingCalls()
    lease = Lease(calls, [1], "me", 1)  # type: ignore[arg-type]
    lease.take()
    calls.closed = True
    renewer = lease._renewer  # pyright: ignore[reportPrivateUsage]
    assert renewer is not None
    assert wait_until(lambda: not renewer.is_alive(), 10)
    assert raised == []
