"""The one table between exceptions and reply statuses, read both ways.

The server turns the exception a request raised into a status (the first row whose ``caught`` type matches: order
matters, UnicodeDecodeError is a ValueError); the client raises a reply's status as the exception the wire contract
names for it (contract/asm.toml ``raises``, bound to classes here), so code that catches TimeoutError, ValueError
or LookupError works on remote objects as on local ones (asm_py.errors). A status the contract maps to RemoteError
(UNSUPPORTED, BAD_MESSAGE, BUSY, INTERNAL) comes back as RemoteError carrying the code.
"""

from __future__ import annotations

import logging
from typing import NamedTuple

from ._contract import STATUS_RAISES
from .errors import AsmTimeout, EstopLatched, Locked, MessageTooLarge, ReadOnlyError, RemoteError, ServiceError
from .protocol import MAX_ERROR_TEXT, Message, Method, Status

log = logging.getLogger("asm_py.status")


class Busy(Exception):
    """The client, or the node in all, holds as many blocking requests as it may (BUSY)."""


class BadMessage(Exception):
    """The request's data cannot be decoded (BAD_MESSAGE)."""


class Row(NamedTuple):
    status: Status
    caught: type[BaseException]
    """What the server answers with ``status``."""


TABLE: tuple[Row, ...] = (
    Row(Status.TIMEOUT, TimeoutError),
    Row(Status.SERVICE_ERROR, ServiceError),
    Row(Status.BUSY, Busy),
    Row(Status.UNSUPPORTED, RemoteError),
    Row(Status.BAD_MESSAGE, BadMessage),
    Row(Status.BAD_MESSAGE, UnicodeDecodeError),
    Row(Status.BAD_MESSAGE, RecursionError),
    Row(Status.READ_ONLY, ReadOnlyError),
    Row(Status.ESTOP, EstopLatched),
    Row(Status.LOCKED, Locked),
    Row(Status.TOO_LARGE, MessageTooLarge),
    Row(Status.TYPE_ERROR, TypeError),
    Row(Status.VALUE_ERROR, ValueError),
    Row(Status.NOT_FOUND, LookupError),
)
_CLIENT_EXCEPTIONS: dict[str, type[Exception]] = {
    cls.__name__: cls
    for cls in (AsmTimeout, ServiceError, TypeError, ValueError, LookupError, ReadOnlyError, EstopLatched, Locked,
                MessageTooLarge, RemoteError)
}  # fmt: skip
"""The exceptions the contract's ``raises`` column may name; a name not here fails at import, not at a reply."""


def _client_exceptions() -> dict[int, type[Exception]]:
    unknown = sorted({name for name in STATUS_RAISES.values() if name not in _CLIENT_EXCEPTIONS})
    if unknown:
        raise ImportError(f"contract/asm.toml: a status raises {unknown[0]!r}, which asm_py/status.py does not know")
    return {status: _CLIENT_EXCEPTIONS[name] for status, name in STATUS_RAISES.items() if name != "RemoteError"}


_RAISED = _client_exceptions()


def status_of(exc: BaseException) -> tuple[int, bytes]:
    """The status and reply text for a request that raised ``exc`` (INTERNAL, logged, for anything unexpected)."""
    text = str(exc).encode("utf-8")[:MAX_ERROR_TEXT]
    for row in TABLE:
        if isinstance(exc, row.caught):
            return row.status, text
    log.error("request failed inside the node", exc_info=exc)
    return Status.INTERNAL, text


def raise_for_status(reply: Message, what: object) -> None:
    """Raise a failed reply's status as its local exception (``what`` names the call in the message)."""
    if reply.status == Status.OK:
        return
    said = reply.data.decode("utf-8", errors="replace")
    text = f"{what}: {said}"
    error = _RAISED.get(reply.status)
    if error is not None:
        exc: Exception = error(text)
    else:
        name = Status(reply.status).name if reply.status in Status._value2member_map_ else str(reply.status)
        exc = RemoteError(f"{text} (status {name})", reply.status)
    exc.asm_reply_text = said  # pyright: ignore[reportAttributeAccessIssue]  (kept apart from the call's name)
    raise exc


def reply_text(exc: BaseException) -> str | None:
    """What the failed reply behind ``exc`` said itself, without the call's name raise_for_status puts before it;
    None for an exception not raised from a reply. A board's refusal carries no text (C keeps no strings), a Python
    node's does: a caller that explains an empty one (the lease's holder) must tell the two apart."""
    return getattr(exc, "asm_reply_text", None)


class What:
    """Names a call in error messages; formatted only when an error is raised (off the hot path)."""

    __slots__ = ("method", "subject")

    def __init__(self, method: int, subject: str) -> None:
        self.method = method
        self.subject = subject

    def __str__(self) -> str:
        method = Method(self.method).name.lower() if self.method in Method._value2member_map_ else self.method
        return f"{method} on {self.subject}"
