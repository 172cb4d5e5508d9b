"""The attribute: a shared value guarded as a monitor (paper section 2.1).

``set`` makes the value valid, ``get`` consumes it. ``sync_get`` makes ``get`` wait for a valid value ("wait for a
fresh value"); ``sync_set`` makes ``set`` wait until the last value was consumed ("wait until the last one was
used"); both make a one-slot rendezvous between producers and consumers; neither is a plain shared variable. All
three operations run in the caller's thread, under the attribute's single lock.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from .clock import Clock, Monitor
from .codec import Codec
from .codec_parse import parse_codec
from .errors import AsmTimeout

log = logging.getLogger("asm_py.attribute")

ChangeCallback = Callable[[Any], None]


@dataclass(frozen=True)
class PublishPolicy:
    """When a published attribute sends its value; see :meth:`Attribute.publish`."""

    rate: float | None = None
    """Publications per second of the node's clock (a fixed rate, or the minimum rate with a deadband)."""
    deadband: float | None = None
    """Only a change larger than this (from the last publication) is published at once."""
    limit: float | None = None
    """With a deadband: at most this many publications per second. A change that comes sooner is published with
    the next change after the gap, or by the refresh (``rate``) if none comes."""

    def __post_init__(self) -> None:
        if self.rate is not None and not (self.rate > 0 and math.isfinite(self.rate)):
            raise ValueError(f"publication rate must be a positive number per second, not {self.rate}")
        if self.deadband is not None and not (self.deadband >= 0 and math.isfinite(self.deadband)):
            raise ValueError(f"deadband must be a non-negative number, not {self.deadband}")
        if self.limit is not None and (self.deadband is None or not (self.limit > 0 and math.isfinite(self.limit))):
            raise ValueError(f"a publication limit is a positive number per second, with a deadband, not {self.limit}")


class Attribute:
    """A value shared among threads (and, through a node, among processors); see the module docstring."""

    __slots__ = ("__weakref__", "_changes", "_codec", "_initial", "_listeners", "_mon", "_name", "_policy",
                 "_policy_hooks", "_subscription", "_sync_get", "_sync_set", "_valid", "_value")  # fmt: skip

    def __init__(
        self,
        name: str,
        initial: Any = None,
        *,
        sync_get: bool = False,
        sync_set: bool = False,
        codec: Codec | str | None = None,
        clock: Clock | None = None,
    ) -> None:
        self._name = name
        self._codec = None if codec is None else parse_codec(codec)
        if initial is not None and self._codec is not None:
            initial = self._codec.normalize(initial)
        self._initial = initial
        self._value = initial
        self._valid = False
        self._changes = 0
        self._sync_get = bool(sync_get)
        self._sync_set = bool(sync_set)
        self._mon = Monitor(clock)
        self._listeners: tuple[ChangeCallback, ...] = ()
        self._policy: PublishPolicy | None = None
        self._policy_hooks: tuple[Callable[[PublishPolicy | None], None], ...] = ()
        self._subscription: Callable[[], None] | None = None

    @property
    def name(self) -> str:
        return self._name

    @property
    def valid(self) -> bool:
        """True between a ``set`` and the next ``get`` (or ``reset``)."""
        return self._valid

    @property
    def sync_get(self) -> bool:
        return self._sync_get

    @property
    def sync_set(self) -> bool:
        return self._sync_set

    @property
    def codec(self) -> Codec | None:
        return self._codec

    @property
    def clock(self) -> Clock:
        return self._mon.clock

    @property
    def initial(self) -> Any:
        return self._initial

    def set(self, value: Any, timeout: float | None = None, *, wait: bool = True) -> None:
        """Store ``value`` and make it valid; with sync_set, first wait until the previous value was consumed.

        ``wait`` exists for location transparency (a remote set may return before it is done); a local set has
        always completed when it returns.
        """
        if self._codec is not None:
            value = self._codec.normalize(value)
        self._put(value, timeout)

    def _put(self, value: Any, timeout: float | None, block: bool = True) -> None:
        """Store a normalized value under the lock — first, with ``block`` and sync_set, waiting until the last one
        was consumed — wake the waiters, then call the listeners: ``set`` and a publication's delivery, in one
        function (a 128-module robot sets 30,000 attributes a second; issue 31)."""
        mon = self._mon
        with mon.lock:
            if block and self._sync_set and self._valid and not mon.wait_for(self._consumed, timeout):
                raise AsmTimeout(f"set on attribute {self._name!r} timed out after {timeout}s (last value unread)")
            self._value = value
            self._valid = True
            self._changes += 1
            if mon._waiters:
                mon.notify_all()
        for callback in self._listeners:
            try:
                callback(value)
            except Exception:
                log.exception("change callback %r of attribute %r failed", callback, self._name)

    def get(self, timeout: float | None = None) -> Any:
        """Return the value and make it invalid; with sync_get, first wait until a value is valid."""
        mon = self._mon
        with mon.lock:
            if self._sync_get and not self._valid and not mon.wait_for(self._is_valid, timeout):
                raise AsmTimeout(f"get on attribute {self._name!r} timed out after {timeout}s (no valid value)")
            self._valid = False
            if self._sync_set and mon._waiters:
                mon.notify_all()
            return self._value

    def reset(self, *, wait: bool = True) -> None:
        """Restore the initial value, make it invalid and release setters blocked by sync_set."""
        mon = self._mon
        with mon.lock:
            self._value = self._initial
            self._valid = False
            mon.notify_all()

    def peek(self, timeout: float | None = None) -> Any:
        """The current value without consuming it: for monitors and displays, not for synchronization.
        (``timeout`` is the client object's, for the same interface: a local peek never waits.)"""
        return self._value

    def on_change(self, callback: ChangeCallback) -> Callable[[], None]:
        """Call ``callback(value)`` after every ``set`` (in the setter's thread, outside the lock).

        ``reset`` is not reported: it returns the attribute to its initial state rather than producing a value.
        Returns a function that removes the callback.
        """
        return self._add_to("_listeners", callback)

    # -- publish/subscribe (paper section 3): the server decides when to publish ---------------------------------

    def publish(self, rate: float | None = None, deadband: float | None = None, limit: float | None = None) -> None:
        """Publish this attribute through every node it is registered on.

        No argument: every ``set``. ``deadband``: a set that changes the value by more than ``deadband`` from the
        last publication. ``rate``: a fixed rate (``rate`` per second of the node's clock). Both: on a change larger
        than the deadband, and at least every ``1/rate`` seconds. ``limit`` (with a deadband): at most ``limit``
        publications per second however fast the value moves — a joint read at every control tick need not fill a
        bus at the tick rate.
        """
        policy = PublishPolicy(rate, deadband, limit)
        self._policy = policy
        for hook in self._policy_hooks:
            hook(policy)

    def unpublish(self) -> None:
        """Stop publishing."""
        self._policy = None
        for hook in self._policy_hooks:
            hook(None)

    @property
    def publish_policy(self) -> PublishPolicy | None:
        return self._policy

    def subscribe(self, source: Any) -> None:
        """Receive every publication of ``source`` (a remote attribute of the same type) into this attribute.

        Each publication is stored as a set that never blocks (the newest publication wins over an unread one) and
        wakes sync_get waiters and change callbacks. Replaces an earlier subscription of this attribute.
        """
        remote_codec = getattr(source, "codec", None)
        if self._codec is not None and remote_codec is not None and remote_codec != self._codec:
            raise TypeError(f"attribute {self._name!r} ({self._codec.spec}) cannot subscribe to {remote_codec.spec}")
        self.unsubscribe()
        if type(self)._deliver is Attribute._deliver and (self._codec is None or remote_codec is not None):
            # the source's codec is this one's (canonical values) and no subclass checks what arrives
            put = self._put

            def deliver(value: Any) -> None:  # one frame fewer than _deliver's, on every publication (issue 31)
                put(value, None, False)

        else:
            deliver = self._deliver
        self._subscription = source._subscribe(deliver)

    def unsubscribe(self) -> None:
        """End the subscription, if any."""
        remove, self._subscription = self._subscription, None
        if remove is not None:
            remove()

    def _deliver(self, value: Any, *, decoded_by: Codec | None = None) -> None:
        """Store a publication: like ``set``, but never blocking on sync_set.

        A value ``decoded_by`` this attribute's own codec is canonical already and is not checked again.
        """
        codec = self._codec
        if codec is not None and decoded_by is not codec and decoded_by != codec:  # identity first: no __eq__
            value = codec.normalize(value)
        self._put(value, None, block=False)

    def _add_policy_hook(self, hook: Callable[[PublishPolicy | None], None]) -> Callable[[], None]:
        return self._add_to("_policy_hooks", hook)

    def _add_to(self, field: str, item: Callable[..., None]) -> Callable[[], None]:
        """Append ``item`` to the copy-on-write tuple ``field`` (read without the lock); return its remover."""
        with self._mon.lock:
            setattr(self, field, (*getattr(self, field), item))

        def remove() -> None:
            with self._mon.lock:
                setattr(self, field, tuple(i for i in getattr(self, field) if i is not item))

        return remove

    def _consumed(self) -> bool:
        return not self._valid

    def _is_valid(self) -> bool:
        return self._valid

    def __repr__(self) -> str:
        flags = "".join(f for f, on in (("G", self._sync_get), ("S", self._sync_set)) if on) or "-"
        return f"<{type(self).__name__} {self._name!r} {flags} valid={self._valid} value={self._value!r}>"


class CheckedAttribute(Attribute):
    """An attribute whose every value, however it arrives (a local or remote set, a reset, a publication), passes
    ``check(value)`` first: the check may return the value to store (a goal clamped to its limits) or raise, and
    then nothing is stored. The domain of a value lives with the value, so no path around it exists.

    A reset goes through ``reset()`` when given — it returns the value to go back to, or raises to refuse — and
    otherwise through ``check`` with the initial value: a reset is a write like any other (a lease, a staged gait,
    a table are never emptied behind their rules)."""

    __slots__ = ("_check", "_reset_to")

    def __init__(
        self,
        name: str,
        initial: Any = None,
        *,
        check: Callable[[Any], Any],
        reset: Callable[[], Any] | None = None,
        **options: Any,
    ) -> None:
        super().__init__(name, initial, **options)
        self._check = check
        self._reset_to = reset

    def reset(self, *, wait: bool = True) -> None:
        value = self._reset_to() if self._reset_to is not None else self._check(self._initial)
        mon = self._mon
        with mon.lock:
            self._value = value
            self._valid = False
            mon.notify_all()

    def set(self, value: Any, timeout: float | None = None, *, wait: bool = True) -> None:
        codec = self._codec
        if codec is None:
            self._put(self._check(value), timeout)
            return
        value = codec.normalize(value)
        checked = self._check(value)
        self._put(checked if checked is value else codec.normalize(checked), timeout)  # the value itself: normalized

    def _deliver(self, value: Any, *, decoded_by: Codec | None = None) -> None:
        try:
            self.set(value)
        except Exception as exc:  # refused by the check: the publication is dropped, the next one still arrives
            log.info("a publication for attribute %r was refused: %s", self._name, exc)
