"""Publication of one attribute by its policy (paper section 3: "the rate of the publication is set by the server").

- no rate, no deadband: every ``set`` is published;
- deadband only: a ``set`` that moves the value by more than the deadband from the last publication;
- rate only: the current value at a fixed rate, on the grid start + k/rate of the node's clock;
- both: on a change larger than the deadband, and at least every 1/rate after the last publication;
- a limit (with a deadband): no two publications of changes closer than 1/limit; a change that comes sooner waits for
  the next change after the gap, or for the refresh.

Distance between two values: the absolute difference for numbers, the largest one for arrays and records of
numbers; any other change counts as infinitely large.
"""

from __future__ import annotations

import itertools
import json
import math
import struct
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from .attribute import Attribute, PublishPolicy
from .codec import to_json
from .protocol import MAX_TXN, Kind, Method, first_byte
from .timers import TimerHandle, timers_of

if TYPE_CHECKING:
    from .node import Entry, Node

_NOTHING = object()
_SCALARS = (float, int)
"""Types whose distance is the absolute difference (bool is not one of them: ``type(True) is not int``)."""


def distance(a: Any, b: Any) -> float:
    """How far apart two values of one codec are, for deadbands."""
    if a is _NOTHING:
        return math.inf
    if isinstance(a, int | float) and isinstance(b, int | float) and not isinstance(a, bool):
        return (
            abs(a - b)
            if not (math.isnan(a) or math.isnan(b))
            else (0.0 if math.isnan(a) and math.isnan(b) else math.inf)
        )
    if isinstance(a, tuple | list) and isinstance(b, tuple | list) and len(a) == len(b):
        return max((distance(x, y) for x, y in zip(a, b, strict=True)), default=0.0)
    if isinstance(a, dict) and isinstance(b, dict) and a.keys() == b.keys():
        return max((distance(a[k], b[k]) for k in a), default=0.0)
    return 0.0 if a == b else math.inf


class Publisher:
    """Publishes one registered attribute through its node; see the module docstring.

    A rate is met by a deadline on the clock's shared :class:`~asm_py.timers.Timers`, not a thread per publisher:
    a process of 128 modules publishes on one timer thread."""

    def __init__(self, node: Node, entry: Entry, policy: PublishPolicy) -> None:
        self.clock = node.clock
        self.node = node
        self.entry = entry
        self.policy = policy
        self._counter = itertools.count()  # next() on it is atomic: concurrent setters get distinct numbers
        self._timed = policy.rate is not None or policy.limit is not None
        self._gap = 1.0 / policy.limit if policy.limit is not None else 0.0
        self._deadband = policy.deadband
        self._reached = self.clock.reached
        self._name = entry.name
        self._last_value: Any = _NOTHING
        self._last_time = -math.inf
        self._not_before: float | None = None
        """With a limit: the clock time before which no change is published (None: nothing published yet)."""
        names = {"node": node.name, "object": entry.name, "class": entry.class_name}
        self._json_prefix = json.dumps(names, separators=(",", ":"))[:-1] + ","  # the JSON view, less seq/t/value
        self._head0 = first_byte(Kind.PUBLICATION, Method.PUBLISH)
        self._class_id = entry.class_id
        self._object_id = entry.object_id
        self._encode = entry.codec.encode_canonical
        fixed = entry.codec.plain_struct()
        self._pack_number = None if fixed is None else struct.Struct("<4B" + fixed.format.lstrip("<")).pack
        """A number's whole message, header and value, in one pack (every set of a published number; issue 31)."""
        self._send = node.transport.publication_sender(entry.name)
        attribute = entry.obj
        assert isinstance(attribute, Attribute)
        self._attribute = attribute
        self._unlisten = None
        if policy.rate is None or policy.deadband is not None:
            every_set = policy.deadband is None and not self._gap  # every set publishes: no check in between
            if not every_set:
                listener = self._on_change
            elif self._pack_number is not None:  # (every set publishes only with no rate and no limit: untimed)
                listener = self._every_set_number(self._pack_number)
            else:
                listener = self.publish
            self._unlisten = attribute.on_change(listener)
        self._timer: TimerHandle | None = None
        if policy.rate is not None:
            self._period = 1.0 / policy.rate
            self._origin = self.clock.now()
            self._tick = 1
            self._timer = timers_of(self.clock).call_at(self._origin + self._period, self._refresh)

    @property
    def published(self) -> int:
        """How many publications were sent: the next sequence number before it wraps (every publication takes one
        from ``_counter``, whose repr is ``count(N)``: read without taking one, and no count kept per publication)."""
        return int(repr(self._counter)[6:-1])

    def _every_set_number(self, pack: Callable[..., bytes]) -> Callable[[Any], None]:
        """``publish`` for a number published on every set, as one closure over what it needs: no attribute looked
        up and no state written per set, where ``publish`` also keeps what a deadband, a limit or a rate needs
        (a published joint is set at every control tick; issue 31's publish_rate_vs_raw_zenoh)."""
        next_seq, send, view = self._counter.__next__, self._send, self._view
        head0, class_id, object_id = self._head0, self._class_id, self._object_id

        def publish(value: Any) -> None:
            seq = next_seq() & MAX_TXN
            send(pack(head0, seq, class_id, object_id, value), lambda: view(seq, value))

        return publish

    def _view(self, seq: int, value: Any) -> str:
        """The publication's JSON view (formatted only when someone watches it)."""
        now = self.clock.now()
        return f'{self._json_prefix}"seq":{seq},"t":{now!r},"value":{json.dumps(to_json(value))}}}'

    def close(self) -> None:
        """Publish nothing more (a refresh running on the timers' thread finishes first)."""
        if self._unlisten is not None:
            self._unlisten()
            self._unlisten = None
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None

    def _on_change(self, value: Any) -> None:
        """Every set of a deadband or limited attribute: both tests are pure, so the cheaper one goes first (a
        joint at a 50 Hz tick with a 25 Hz limit is too soon every other set)."""
        not_before = self._not_before
        if not_before is not None and not self._reached(not_before):
            return  # too soon: the next change after the gap, or the refresh, publishes the value then
        deadband = self._deadband
        if deadband is not None:
            last = self._last_value
            if type(value) is type(last) and type(value) in _SCALARS:  # distance() of two numbers, without its tests
                apart = abs(value - last)
                if apart == apart:  # (NaN: distance() says how far apart NaNs are)
                    if apart <= deadband:
                        return
                    self.publish(value)
                    return
            if distance(last, value) <= deadband:
                return
        self.publish(value)

    def _refresh(self, due: float) -> float:
        """The rate's deadline (on the timers' thread); returns the next one."""
        period = self._period
        value = self._attribute.peek()  # None: never set (an event before its first firing), nothing to publish
        if self.policy.deadband is None:  # fixed rate, on the grid origin + k·period
            if value is not None:
                self.publish(value)
            self._tick += 1
            return self._origin + self._tick * period
        # refresh when nothing was published for a period (a change may have been published meanwhile)
        if self._last_time == -math.inf or self.clock.reached(self._last_time + period):  # (a SimClock has no -inf)
            if value is None:
                return self.clock.now() + period
            self.publish(value)
        return self._last_time + period

    def publish(self, value: Any) -> None:
        """Send ``value`` (canonical: the attribute's own) now as a publication, binary and JSON on the parallel key.

        The hot path of every-set publishing: the header is four bytes built in place (docs/protocol.md), the
        sequence number comes from an atomic counter, and the JSON view is formatted only if the transport says
        someone watches it.
        """
        seq = next(self._counter) & MAX_TXN
        self._last_value = value
        if self._timed:
            self._last_time = self.clock.now()
            if self._gap:
                self._not_before = self._last_time + self._gap
        pack = self._pack_number
        if pack is not None:
            data = pack(self._head0, seq, self._class_id, self._object_id, value)
        else:
            data = bytes((self._head0, seq, self._class_id, self._object_id)) + self._encode(value)
        self._send(data, lambda: self._view(seq, value))
