"""The one table between exceptions and reply statuses, read both ways.

The server turns the exception a request raised into a status (the first row whose ``caught`` type matches: order
matters, UnicodeDecodeError is a ValueError); the client raises a reply's status as that row's ``raised`` type, so
code that catches TimeoutError, ValueError or LookupError works on remote objects as on local ones
(asm_py.errors). A status with no ``raised`` type (UNSUPPORTED, BAD_MESSAGE, BUSY, INTERNAL) comes back as
RemoteError carrying the code.
"""

from __future__ import annotations

import logging
from typing import NamedTuple

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
    raised: type[Exception] | None
    """What the client raises for ``status`` (None: RemoteError with the code)."""


TABLE: tuple[Row, ...] = (
    Row(Status.TIMEOUT, TimeoutError, AsmTimeout),
    Row(Status.SERVICE_ERROR, ServiceError, ServiceError),
    Row(Status.BUSY, Busy, None),
    Row(Status.UNSUPPORTED, RemoteError, None),
    Row(Status.BAD_MESSAGE, BadMessage, None),
    Row(Status.BAD_MESSAGE, UnicodeDecodeError, None),
    Row(Status.BAD_MESSAGE, RecursionError, None),
    Row(Status.READ_ONLY, ReadOnlyError, ReadOnlyError),
    Row(Status.ESTOP, EstopLatched, EstopLatched),
    Row(Status.LOCKED, Locked, Locked),
    Row(Status.TOO_LARGE, MessageTooLarge, MessageTooLarge),
    Row(Status.TYPE_ERROR, TypeError, TypeError),
    Row(Status.VALUE_ERROR, ValueError, ValueError),
    Row(Status.NOT_FOUND, LookupError, LookupError),
)
_RAISED: dict[int, type[Exception]] = {row.status: row.raised for row in TABLE if row.raised is not None}


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
    text = f"{what}: {reply.data.decode('utf-8', errors='replace')}"
    error = _RAISED.get(reply.status)
    if error is not None:
        raise error(text)
    name = Status(reply.status).name if reply.status in Status._value2member_map_ else str(reply.status)
    raise RemoteError(f"{text} (status {name})", reply.status)


class What:
    """Names a call in error messages; formatted only when an error is raised (off the hot path)."""

    __slots__ = ("method", "subject")

    def __init__(self, method: int, subject: str) -> None:
        self.method = method
        self.subject = subject

    def __str__(self) -> str:
        method = Method(self.method).name.lower() if self.method in Method._value2member_map_ else self.method
        return f"{method} on {self.subject}"
