"""ASM over CAN with python-can: 29-bit identifiers in the spirit of MDCN (asm_py/canbus/ids.py, docs/protocol.md).

Any python-can interface works (socketcan, pcan, kvaser, slcan, virtual, …), configured as python-can users expect:
``CanTransport(3, interface="socketcan", channel="can0", bitrate=1_000_000)``, or ``CanTransport(3)`` alone to use
python-can's configuration file / environment, or an already open ``bus=``. ``fd=True`` uses CAN FD frames of up to
64 bytes. Node IDs are 1..254; nodes learn each other's names from heartbeats, and a node not yet heard is
addressed as ``can.<id>`` (e.g. replies to a client that has not sent its first heartbeat).

One thread reads the bus (``asm-can:<name>``) — or, while a caller waits for its reply, that caller
(leader/follower, asm_py.transport.can_reader: a round trip wakes two threads instead of three): acceptance filters
pass frames to this node, its groups, broadcasts and system frames; fragments are reassembled with bounded memory;
requests go to the node, publications to subscribers (matched by source node and object ID), e-stops to the e-stop
handlers at once. With ``receive_thread=False`` on a bus that delivers frames itself (``asm_sim``'s ``push_to``),
there is no such thread: the channel's one dispatch thread calls this transport, so a process hosting 128 modules
does not run 128 readers. A deadline on the wall clock's shared timers (asm_py.timers) sends heartbeats, reports
nodes lost after ``missed_heartbeats`` silent periods (and found again when they return), and expires stale partial
messages. Sends are serialised per transport, so the fragments of one message are contiguous on the bus.

``record="session.blf"`` (or .asc, .log for candump, .csv, …) writes every frame sent and received with python-can's
``Logger``; replay it with ``python -m can.player``.
"""

from __future__ import annotations

import logging
import threading
import time
import zlib
from collections.abc import Callable, Mapping
from contextlib import AbstractContextManager, nullcontext
from pathlib import Path
from typing import Any

import can

from .._contract import KIND_MASK, KIND_SHIFT
from ..canbus.fragments import FD_SIZES, Reassembler
from ..canbus.ids import (
    FIELDS,
    Dest,
    FrameType,
    Priority,
    SystemCode,
    check_node_id,
    dest_filter,
    kind_filter,
    priority_filter,
)
from ..clock import WALL_CLOCK
from ..protocol import MAX_MESSAGE, Kind, kind_of
from ..speedups import COMPILED, speedups
from ..timers import TimerHandle, timers_of
from .base import BROADCAST, PublicationHandler, Transport
from .can_reader import BusReader
from .can_send import BY_REPLY, ID_CACHE_SIZE, FrameSender, message_priority

__all__ = ["ALIAS_PREFIX", "CanTransport", "group_id", "message_priority"]

log = logging.getLogger("asm_py.transport.can")

ALIAS_PREFIX = "can."
_PRIORITY_AT, _PRIORITY_BITS = FIELDS[0]  # (shift, mask) of the identifier's fields, as module globals: on_frame
_KIND_AT, _KIND_BITS = FIELDS[1]  # unpacks every received identifier without making a CanId
_DEST_AT, _DEST_BITS = FIELDS[2]
_SOURCE_AT, _SOURCE_BITS = FIELDS[3]
_FRAME_AT, _FRAME_BITS = FIELDS[4]
_COUNTER_BITS = FIELDS[5][1]
_PUBLICATIONS = (Priority.PUBLICATION, Priority.BULK_PUBLICATION)
_GO_ON = 2
"""What the C hot path returns when it counted a frame and leaves the rest to :meth:`CanTransport.on_frame`."""


def group_id(group: str, table: Mapping[str, int] | None = None) -> int:
    """The 8-bit CAN group ID of a group name: from ``table`` if it names it, else a CRC-32 of the name mod 256.

    Two names may hash alike; a bus with many groups should give every node the same explicit table.
    """
    if table and group in table:
        return table[group]
    return zlib.crc32(group.encode("utf-8")) & 0xFF


def _next_on_grid(now: float, step: float) -> float:
    """The first k·step after ``now``. Each transport of a process computes the same float for the same instant
    (k·period is k·(period/4)·4 to the last bit), so their timers fall due together and one wake serves them all;
    a sum of steps, or a quarter period counted from each node's own opening, drifted apart (issue 31)."""
    wake = (now // step + 1) * step
    return wake if wake > now else (now // step + 2) * step  # a product too, not a sum: on the grid to the last bit


class CanTransport(FrameSender, Transport):
    """A node's attachment to a CAN bus; see the module docstring."""

    def __init__(
        self,
        node_id: int,
        *,
        bus: can.BusABC | None = None,
        interface: str | None = None,
        channel: Any = None,
        bitrate: int | None = None,
        fd: bool = False,
        heartbeat_period: float = 0.5,
        missed_heartbeats: int = 3,
        groups: Mapping[str, int] | None = None,
        max_message: int = MAX_MESSAGE,
        max_partials: int = 64,
        reassembly_timeout: float = 1.0,
        record: str | Path | None = None,
        send_timeout: float = 0.1,
        watch_bus: bool = True,
        receive_thread: bool = True,
        compiled: bool | None = None,
        **bus_options: Any,
    ) -> None:
        super().__init__()
        if compiled is not None:
            self.compiled = compiled and COMPILED
        self.node_id = check_node_id(node_id)
        self.watch_bus = watch_bus
        """False: the acceptance filters pass only what this node must act on — frames to it and its groups,
        broadcast requests, e-stops — not the other nodes' publications and heartbeats (a module that neither
        subscribes nor discovers; on a bus of 128 modules each would otherwise handle every module's traffic).
        A subscription turns publications back on."""
        self._hear_publications = watch_bus
        self.receive_thread = receive_thread
        """False: frames are pushed by the bus (``asm_sim``) when it can, not read by a thread of this transport."""
        self.fd = fd
        self.frame_size = 64 if fd else 8
        self.heartbeat_period = heartbeat_period
        self.missed_heartbeats = missed_heartbeats
        self.group_table = dict(groups or {})
        self.send_timeout = send_timeout
        self.reassembler = Reassembler(max_message, max_partials, reassembly_timeout)
        self._bus = bus
        self._own_bus = bus is None
        self._bus_config = {"interface": interface, "channel": channel, "bitrate": bitrate, "fd": fd, **bus_options}
        self._record = record
        self._logger: can.Listener | None = None
        self._send_lock = threading.Lock()
        self._rx_lock = threading.Lock()
        self._log_lock = threading.Lock()
        self._names: dict[int, str] = {}
        self._ids: dict[str, int] = {}
        self._last_heard: dict[int, float] = {}
        self._alive: set[int] = set()
        self._subscriptions: dict[tuple[str, int], tuple[PublicationHandler, ...]] = {}
        self._accept_ids: set[int] = {self.node_id}
        self._group_ids: set[int] = set()
        self._stop = threading.Event()
        self._reader: BusReader | None = None
        self._fast: Callable[[can.Message], int] | None = None
        """The C hot path of :meth:`on_frame` (asm_py._speedups.Receiver), unless ``compiled`` is False."""
        self._single_ids: dict[tuple[int, int, int, int], int] = {}
        self._dest_ids: dict[str, tuple[int, ...]] = {}
        """Per node name, the identifiers of a single frame to it — a request, a reply — and of its reply to this
        node (``send``'s and ``wait_reply``'s hot path; cleared when a heartbeat changes what a name means)."""
        self._single_sizes = frozenset(FD_SIZES if fd else range(9))
        """Message lengths that travel as one frame."""
        self._publication_id: int | None = None
        """The identifier of this node's one-frame publications, once one was sent."""
        self._timer: TimerHandle | None = None
        self._next_beat = 0.0
        self._push_to: Callable[[Callable[[can.Message], None] | None], None] | None = None
        """The bus's ``push_to`` once it hands this transport its frames (``receive_thread=False``)."""
        self.frames_sent = 0
        self.frames_received = 0
        self.send_errors = 0

    @property
    def bus(self) -> can.BusABC:
        if self._bus is None:
            raise RuntimeError("CAN transport is not open")
        return self._bus

    # -- opening and closing --------------------------------------------------------------------------------------

    def _open(self, name: str) -> None:
        if self._bus is None:
            config = {k: v for k, v in self._bus_config.items() if v is not None and v is not False}
            self._bus = can.Bus(**config)
        if self._record is not None:
            self._logger = can.Logger(str(self._record))
        self._apply_filters()
        self._names[self.node_id] = name
        self._ids[name] = self.node_id
        if self.compiled and speedups is not None:
            overridden = type(self).on_message is not CanTransport.on_message  # a gateway forwards: it decides
            self._fast = speedups.Receiver(self, self.node_id, self._accept_ids, self._names, self._last_heard,
                                           self._alive, self.on_message if overridden else self._deliver,
                                           overridden)  # fmt: skip
        push_to = getattr(self._bus, "push_to", None)
        if not self.receive_thread and push_to is not None:
            push_to(self._on_pushed)
            self._push_to = push_to
        else:
            self._reader = BusReader(self._bus, self.on_frame, self._stop)
            self._reader.start(f"asm-can:{name}")
        now, period = time.monotonic(), self.heartbeat_period
        # Beats on the grid k·period: a process's transports beat in one batch, one wake for all of them (issue 31).
        self._next_beat = ((now + period / 2) // period + 1) * period
        self._timer = timers_of(WALL_CLOCK).call_at(now + period / 4, self._on_timer)
        self._send_heartbeat()

    def _join(self, group: str) -> None:
        if group != BROADCAST:
            self._group_ids.add(group_id(group, self.group_table))
            self._apply_filters()

    def accept_node_id(self, node_id: int) -> None:
        """Also receive frames addressed to ``node_id`` (a gateway answering for other node IDs)."""
        self._accept_ids.add(check_node_id(node_id))
        self._apply_filters()

    def _apply_filters(self) -> None:
        if self._bus is None:
            return
        filters = [dest_filter(Dest.NODE, i) for i in sorted(self._accept_ids)]
        filters += [dest_filter(Dest.GROUP, g) for g in sorted(self._group_ids)]
        if self.watch_bus:
            filters += [dest_filter(Dest.BROADCAST, 0), kind_filter(Dest.SYSTEM)]
        else:
            priorities = [Priority.REQUEST, Priority.BULK, *(_PUBLICATIONS if self._hear_publications else ())]
            filters += [priority_filter(p, Dest.BROADCAST, 0) for p in priorities]
            filters.append(dest_filter(Dest.SYSTEM, SystemCode.ESTOP))
        self._bus.set_filters(filters)

    def _close(self) -> None:
        if self._bus is None:
            return
        try:
            self._send_system(SystemCode.LEAVE, b"", Priority.HEARTBEAT)
        except Exception:
            log.debug("leave notice not sent", exc_info=True)
        self._stop.set()
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        if self._push_to is not None:
            self._push_to(None)
            self._push_to = None
        if self._reader is not None:
            self._reader.join(5)
            self._reader = None
        self._fast = None
        if self._own_bus:
            self._bus.shutdown()
        self._bus = None
        with self._log_lock:
            if self._logger is not None:
                self._logger.stop()
                self._logger = None

    # -- names ----------------------------------------------------------------------------------------------------

    def resolve(self, name: str) -> int | None:
        """The node ID of a node name (learned from heartbeats, or a ``can.<id>`` alias); None if unknown."""
        node_id = self._ids.get(name)
        if node_id is None and name.startswith(ALIAS_PREFIX) and name[len(ALIAS_PREFIX) :].isdigit():
            node_id = int(name[len(ALIAS_PREFIX) :])
        return node_id

    def name_of(self, node_id: int) -> str:
        return self._names.get(node_id) or f"{ALIAS_PREFIX}{node_id}"

    def peers(self) -> list[str]:
        return sorted({self.name, *(self.name_of(i) for i in self._alive.copy())})  # copied at once: the reader adds

    def last_heard(self, name: str) -> float | None:
        """``time.monotonic()`` when node ``name`` was last heard (any frame), or None if never."""
        node_id = self.resolve(name)
        return None if node_id is None else self._last_heard.get(node_id)

    # -- sending --------------------------------------------------------------------------------------------------

    def send(self, dest: str, data: bytes) -> None:
        if len(data) in self._single_sizes and data:  # most traffic: one frame, its identifier by name (issue 31)
            ids = self._dest_ids.get(dest)
            if ids is not None:
                self._send_single(ids[(data[0] >> KIND_SHIFT & KIND_MASK) == Kind.REPLY], data)
                return
        node_id = self.resolve(dest)
        if node_id is None:
            self.send_errors += 1
            log.debug("no CAN node named %r is known yet; message dropped", dest)
            return
        self.send_message(Dest.NODE, node_id, data, message_priority(data))
        if len(self._dest_ids) >= ID_CACHE_SIZE:
            self._dest_ids.clear()
        self._dest_ids[dest] = (*(self._single_id(p, Dest.NODE, node_id, self.node_id) for p in BY_REPLY),
                                self._single_id(Priority.REPLY, Dest.NODE, self.node_id, node_id))  # fmt: skip

    def send_group(self, group: str, data: bytes) -> None:
        if group == BROADCAST:
            self.send_message(Dest.BROADCAST, 0, data, Priority.REQUEST)
        else:
            self.send_message(Dest.GROUP, group_id(group, self.group_table), data, Priority.REQUEST)

    def publish(self, object_name: str, data: bytes, json_text: Callable[[], str] | None = None) -> None:
        if len(data) in self._single_sizes:  # a publication of one frame: its identifier made once (issue 31)
            ident = self._publication_id
            if ident is None:
                ident = self._publication_id = self._single_id(Priority.PUBLICATION, Dest.BROADCAST, 0, self.node_id)
            self._send_single(ident, data)
            return
        self.send_message(Dest.BROADCAST, 0, data, Priority.PUBLICATION)

    def _send_heartbeat(self) -> None:
        self._send_system(SystemCode.HEARTBEAT, self.name.encode("utf-8"), Priority.HEARTBEAT)

    def _send_system(self, code: int, data: bytes, priority: int) -> None:
        self.send_message(Dest.SYSTEM, code, data, priority)

    # -- receiving ------------------------------------------------------------------------------------------------

    def wait_reply(self, done: threading.Lock, wait: float | None, source: str, head: bytes) -> bool:
        """The caller reads the bus itself while nothing else does (asm_py.transport.can_reader)."""
        reader, ids = self._reader, self._dest_ids.get(source)
        if reader is None:
            return super().wait_reply(done, wait, source, head)
        if ids is None:  # (not sent to by name yet: a request to it fills the cache)
            source_id = self.resolve(source)
            if source_id is None:
                return super().wait_reply(done, wait, source, head)
            return reader.wait(done, wait, self._single_id(Priority.REPLY, Dest.NODE, self.node_id, source_id), head)
        return reader.wait(done, wait, ids[2], head)

    def waiting(self, done: threading.Lock) -> AbstractContextManager[None]:
        reader = self._reader
        return nullcontext() if reader is None else reader.following(done)

    def subscribe(
        self, node: str, object_name: str, callback: PublicationHandler, *, object_id: int | None = None
    ) -> Callable[[], None]:
        if object_id is None:
            raise ValueError("a CAN subscription needs the object ID (publications carry IDs, not names)")
        key = (node, object_id)
        with self._lock:
            self._subscriptions[key] = (*self._subscriptions.get(key, ()), callback)
        if not self._hear_publications:
            self._hear_publications = True
            self._apply_filters()

        def remove() -> None:
            with self._lock:
                left = tuple(c for c in self._subscriptions.get(key, ()) if c is not callback)
                if left:
                    self._subscriptions[key] = left
                else:
                    self._subscriptions.pop(key, None)

        return remove

    def _on_pushed(self, frame: can.Message) -> None:
        """A frame from the channel's dispatch thread (``receive_thread=False``)."""
        if not self._stop.is_set():
            self.on_frame(frame)

    def on_frame(self, frame: can.Message) -> None:
        """Handle one received frame (the read loop calls this; a replay or a test may too)."""
        fast = self._fast
        if fast is None:
            if not frame.is_extended_id or frame.is_error_frame or frame.is_remote_frame:
                return
            self.frames_received += 1
        elif fast(frame) != _GO_ON:  # the C hot path handled the frame, or it was not an ASM frame
            return
        if self._logger is not None:
            self._log(frame)
        a = frame.arbitration_id  # every received frame comes here: CanId.unpack's fields, without the tuple
        dest_kind = a >> _KIND_AT & _KIND_BITS
        dest, source = a >> _DEST_AT & _DEST_BITS, a >> _SOURCE_AT & _SOURCE_BITS
        if dest_kind == Dest.SYSTEM and dest == SystemCode.ESTOP:
            # an e-stop is honoured whoever sent it, even with this node's own ID or an invalid one: stopping twice
            # is harmless, ignoring a stop is not
            self._estop_received(self.name_of(source), bytes(frame.data).decode("utf-8", errors="replace"))
            return
        if source == self.node_id or not 1 <= source <= 254:
            return  # our own frame (a loopback interface), or a forged source
        if dest_kind == Dest.NODE:
            if dest not in self._accept_ids:
                return
        elif not self._accepts(dest_kind, dest, a >> _PRIORITY_AT & _PRIORITY_BITS):
            return
        frame_type = a >> _FRAME_AT & _FRAME_BITS
        if frame_type == FrameType.SINGLE:  # most traffic: no reassembly, no lock
            self.on_message(source, dest_kind, dest, bytes(frame.data))
            return
        with self._rx_lock:
            message = self.reassembler.feed((source, dest_kind, dest), frame_type, a & _COUNTER_BITS,
                                            bytes(frame.data), time.monotonic())  # fmt: skip
        if message is not None:
            self.on_message(source, dest_kind, dest, message)

    def _accepts(self, dest_kind: int, dest: int, priority: int) -> bool:
        """Software acceptance (interfaces without hardware filters, and replays): the same rules as the filters."""
        if dest_kind == Dest.NODE:
            return dest in self._accept_ids
        if dest_kind == Dest.GROUP:
            return dest in self._group_ids
        if self.watch_bus:
            return True
        if dest_kind == Dest.BROADCAST:
            return priority not in _PUBLICATIONS or self._hear_publications
        return dest == SystemCode.ESTOP

    def on_message(self, source_id: int, dest_kind: int, dest: int, data: bytes) -> None:
        """A complete message arrived: dispatch it (a gateway overrides this to forward)."""
        if dest_kind == Dest.SYSTEM:
            self._on_system(source_id, dest, data)
            return
        self._heard(source_id)
        if len(data) >= 4 and kind_of(data) == Kind.PUBLICATION:
            if not self._subscriptions:  # a bridge hears every publication of the bus and subscribes to none
                return
            source = self.name_of(source_id)
            callbacks = self._subscriptions.get((source, data[3]), ())
            alias = f"{ALIAS_PREFIX}{source_id}"
            if source != alias:  # a subscriber may name a publisher by its ID alone, whatever heartbeats say
                callbacks = (*callbacks, *self._subscriptions.get((alias, data[3]), ()))
            for callback in callbacks:
                try:
                    callback(data)
                except Exception:
                    log.exception("subscriber of %s/%d failed", source, data[3])
            return
        self._deliver(self.name_of(source_id), data)

    def _on_system(self, source_id: int, code: int, data: bytes) -> None:
        if code == SystemCode.HEARTBEAT:
            name = data.decode("utf-8", errors="replace")
            with self._lock:
                old = self._names.get(source_id)
                if old != name:
                    if old is not None:
                        self._ids.pop(old, None)
                    self._names[source_id] = name
                    self._ids[name] = source_id
                    self._dest_ids.clear()  # a name now means another node, or an alias a name
            self._heard(source_id)
        elif code == SystemCode.LEAVE:
            self._lost(source_id)

    def _heard(self, source_id: int) -> None:
        self._last_heard[source_id] = time.monotonic()
        if source_id not in self._alive and source_id in self._names:
            self._alive.add(source_id)
            self._peer_changed(self._names[source_id], True)

    def _lost(self, source_id: int) -> None:
        self._last_heard.pop(source_id, None)
        if source_id in self._alive:
            self._alive.discard(source_id)
            self._peer_changed(self.name_of(source_id), False)

    def _on_timer(self, due: float) -> float | None:
        """On the wall clock's shared timer thread: heartbeat, lost nodes, stale partial messages. Every quarter
        heartbeat period while a node is alive or a message partial (losses and expiries within a quarter period,
        without waking needlessly); otherwise at the next heartbeat alone — a module of a simulated robot hears no
        heartbeats, and 128 of them woke the timer 1,024 times a second for nothing (issue 31)."""
        if self._stop.is_set():
            return None
        now = time.monotonic()
        period = self.heartbeat_period
        if due >= self._next_beat:  # by the wake's due time, not the clock: a wake run late never takes the next
            self._next_beat = _next_on_grid(due, period)  # beat ahead of the other transports' (a CI run's did)
            try:
                self._send_heartbeat()
            except Exception:
                log.exception("heartbeat failed")
        limit = self.heartbeat_period * self.missed_heartbeats
        for source_id in [i for i in list(self._alive) if now - self._last_heard.get(i, 0.0) > limit]:
            self._lost(source_id)
        with self._rx_lock:
            self.reassembler.expire(now)
            partial = self.reassembler.partials > 0
        if self._alive or partial:
            wake = _next_on_grid(due, period / 4)  # the next quarter after this one, run at once if late: every
            return wake if now - wake <= period else _next_on_grid(now, period / 4)  # grid wake, unless long gone
        return max(self._next_beat, now)
