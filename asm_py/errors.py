"""Every exception asm_py raises, in one tree.

The paper gives blocking calls a timeout and services a small state machine; those map onto Python's own
exception types wherever a caller would naturally catch them, so code written against ``TimeoutError`` or
``ValueError`` works unchanged on ASM objects, local or remote:

- ``AsmError`` — base of everything specific to ASM.
- ``AsmTimeout(AsmError, TimeoutError)`` — a blocking ``get``/``set``/``waiting``/``stop``, or a remote call,
  did not complete within its deadline. Nothing changed on the object.
- ``ServiceError(AsmError)`` — a service operation that its current state forbids: ``start`` while started,
  ``reset`` while running, ``suspend`` while not started.
- ``SimulationStalled(AsmTimeout)`` — a :class:`~asm_py.clock.SimClock` could not advance because a service
  thread stayed busy (blocked outside ASM, or looping) longer than the clock's settle timeout.
- Codec failures are plain ``TypeError`` (wrong kind of value) and ``ValueError`` (right kind, out of range or
  malformed bytes), as the paper's "the attribute is left untouched" semantics only need the built-ins.
- Lookups of unknown names or IDs raise ``LookupError``.
- ``RemoteError(AsmError)`` — a remote node answered with a status that has no built-in equivalent: the method is
  unsupported for that object, the message was malformed, the node is busy, or it failed internally. ``.status``
  holds the protocol status code. Remote timeouts, service errors, TypeError, ValueError and LookupError are raised
  as the same types as locally.

- ``Refused(AsmError, PermissionError)`` — the node would not do it in its present state: ``ReadOnlyError`` (only the
  node writes that attribute), ``EstopLatched`` (the emergency stop is latched and the request would move a joint),
  ``Locked`` (another client holds the lease). ``MessageTooLarge(AsmError, ValueError)`` — a message over
  ``protocol.MAX_MESSAGE`` bytes, refused before it was sent or at the first edge that saw it.

``ServiceStopped`` is deliberately *not* an ``Exception``: it unwinds a service's ``run`` when ``stop()`` interrupts
a blocking call inside it, and must not be swallowed by a routine's ``except Exception`` (the same reasoning that
made ``asyncio.CancelledError`` a ``BaseException``). The service thread catches it; user code never needs to.
"""

from __future__ import annotations


class AsmError(Exception):
    """Base class of all ASM-specific errors."""


class AsmTimeout(AsmError, TimeoutError):
    """A blocking ASM call ran out of time; the object it was called on is unchanged."""


class ServiceError(AsmError):
    """A service was asked to do something its current state forbids."""


class SimulationStalled(AsmTimeout):
    """A simulation clock could not settle: some service thread did not return to an ASM wait in time."""


class RemoteError(AsmError):
    """A remote node answered with a failure status that maps to no built-in exception (see ``status``)."""

    def __init__(self, message: str, status: int) -> None:
        super().__init__(message)
        self.status = status


class Refused(AsmError, PermissionError):
    """The node refused the request in its present state (nothing changed)."""


class ReadOnlyError(Refused):
    """A write from outside the node to an attribute only the node itself writes."""


class EstopLatched(Refused):
    """The node's emergency stop is latched: it holds its joint and refuses what would move it."""


class Locked(Refused):
    """Another client holds the lease the request needs."""


class MessageTooLarge(AsmError, ValueError):
    """A message longer than the protocol's maximum message size."""


class ServiceStopped(BaseException):
    """Raised inside a service thread when ``stop()`` interrupts a blocking ASM call; ends ``run`` quietly."""


__all__ = [
    "AsmError",
    "AsmTimeout",
    "EstopLatched",
    "Locked",
    "MessageTooLarge",
    "ReadOnlyError",
    "Refused",
    "RemoteError",
    "ServiceError",
    "ServiceStopped",
    "SimulationStalled",
]
