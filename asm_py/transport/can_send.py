"""Frames out: how a CAN transport puts one message on the bus (asm_py.transport.can).

A message of one frame — most traffic — goes out with an identifier packed once and cached; a longer one as its
fragments (asm_py.canbus.fragments), contiguous under the send lock and at BULK priority at best. An e-stop skips
the lock. Every frame sent and received can be written to python-can's ``Logger``.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Iterable
from copy import deepcopy
from typing import Any, ClassVar

import can

from ..canbus.fragments import FD_SIZES, Reassembler, fragment
from ..canbus.ids import CanId, Dest, FrameType, Priority, SystemCode, frame_priority
from ..errors import MessageTooLarge
from ..protocol import Kind, kind_of

log = logging.getLogger("asm_py.transport.can")

BY_REPLY = (Priority.REQUEST, Priority.REPLY)
"""A message's priority by whether it is a reply (:func:`message_priority`), indexed by that bool."""
ID_CACHE_SIZE = 4096
"""Identifiers of SINGLE frames a transport keeps packed (one per (priority, destination, source) it sends to)."""


def message_priority(data: bytes) -> int:
    """The priority an ASM message goes out at: replies before new requests (publications and system frames have
    their own)."""
    return Priority.REPLY if kind_of(data) == Kind.REPLY else Priority.REQUEST


class Frame(can.Message):
    """A frame this transport sends: a python-can ``Message`` whose deep copy — python-can's ``virtual`` bus makes
    one for every receiver of every frame — copies its fields directly. ``Message.__deepcopy__`` runs
    ``copy.deepcopy`` over its bytearray and channel, 6 µs a frame: more than the rest of a send (issue 31). The
    copy is as deep (a new bytearray; an immutable channel is shared, any other deep-copied)."""

    __slots__ = ()
    owned_by_bus: ClassVar[bool] = True
    """Its sender makes one for each send and never touches it again (what it logs is a copy): a bus may deliver
    this very object to its receivers instead of a copy of it (``asm_sim`` does; issue 31)."""

    def __deepcopy__(self, memo: dict[int, Any] | None) -> Frame:
        channel = self.channel
        return Frame(timestamp=self.timestamp, arbitration_id=self.arbitration_id, is_extended_id=self.is_extended_id,
                     is_remote_frame=self.is_remote_frame, is_error_frame=self.is_error_frame,
                     channel=channel if channel is None or type(channel) in _IMMUTABLE else deepcopy(channel, memo),
                     dlc=self.dlc, data=bytearray(self.data), is_fd=self.is_fd, is_rx=self.is_rx,
                     bitrate_switch=self.bitrate_switch, error_state_indicator=self.error_state_indicator)  # fmt: skip


_IMMUTABLE = (str, int, bytes, tuple)


class FrameSender:
    """The sending half of :class:`asm_py.transport.can.CanTransport` (a mixin: the transport holds the state)."""

    node_id: int
    fd: bool
    frame_size: int
    send_timeout: float
    reassembler: Reassembler
    frames_sent: int
    send_errors: int
    _send_lock: threading.Lock
    _log_lock: threading.Lock
    _logger: can.Listener | None
    _single_ids: dict[tuple[int, int, int, int], int]
    _bus: can.BusABC | None

    @property
    def bus(self) -> can.BusABC:
        raise NotImplementedError

    def _send_estop(self, reason: str, lab: bool) -> None:
        """One priority-0 system frame, sent without waiting for the send lock: a long fragmented message being
        sent by another thread never holds back a stop (the e-stop's identifier is its own reassembly key, so it
        cannot tear that message's fragments apart)."""
        cid = CanId(Priority.ESTOP, Dest.SYSTEM, SystemCode.ESTOP, self.node_id, FrameType.SINGLE).pack()
        frame = Frame(arbitration_id=cid, is_extended_id=True, data=reason.encode("utf-8")[: self.frame_size],
                            is_fd=self.fd, bitrate_switch=self.fd)  # fmt: skip
        try:
            self.bus.send(frame, timeout=self.send_timeout)
        except (can.CanError, RuntimeError) as exc:
            self.send_errors += 1
            log.error("CAN e-stop send failed: %s", exc)
            raise
        self.frames_sent += 1
        if self._logger is not None:
            self._log_sent(frame)

    def send_message(self, dest_kind: int, dest: int, data: bytes, priority: int, *, source: int | None = None) -> int:
        """Send one message as its frames (fragmented if long: at BULK priority unless more urgent); the frame count.

        ``source`` other than this node's ID is for gateways sending on behalf of a node they represent.
        """
        src = self.node_id if source is None else source
        length = len(data)
        if length > self.reassembler.max_message and dest_kind != Dest.SYSTEM:
            raise MessageTooLarge(f"message of {length} bytes exceeds the {self.reassembler.max_message}-byte "
                                  "maximum")  # fmt: skip
        if length <= self.frame_size and (not self.fd or length in FD_SIZES):
            # Most traffic is one frame: no fragment generator, and the identifier from the cache (issue 31).
            base = self._single_ids.get((priority, dest_kind, dest, src))
            if base is None:
                base = self._single_id(priority, dest_kind, dest, src)
            return self._send_single(base, data)
        frames = list(fragment(data, frame_size=self.frame_size))
        # Packing validates every field once; each frame then only adds its type and counter.
        base = CanId(frame_priority(priority, len(frames)), dest_kind, dest, src, FrameType.SINGLE).pack()
        return self._send_frames(frames, base, length)

    def _single_id(self, priority: int, dest_kind: int, dest: int, src: int) -> int:
        """The identifier of a SINGLE frame, validated once by packing and then cached (bounded: cleared when full,
        as a gateway speaking for many sources may fill it)."""
        base = CanId(frame_priority(priority, 1), dest_kind, dest, src, FrameType.SINGLE).pack()
        if len(self._single_ids) >= ID_CACHE_SIZE:
            self._single_ids.clear()
        self._single_ids[(priority, dest_kind, dest, src)] = base
        return base

    def _send_single(self, ident: int, data: bytes) -> int:
        """Send a message of one frame with identifier ``ident``: 1, or 0 when it failed."""
        fd = self.fd
        message = Frame(arbitration_id=ident, is_extended_id=True, data=data, is_fd=fd, bitrate_switch=fd)
        bus = self._bus
        if bus is None:
            bus = self.bus  # raises: not open
        with self._send_lock:
            try:
                bus.send(message, timeout=self.send_timeout)
            except (can.CanError, RuntimeError) as exc:
                self.send_errors += 1
                log.warning("CAN send failed (%s); message of %d bytes dropped", exc, len(data))
                return 0
            self.frames_sent += 1
        if self._logger is not None:
            self._log_sent(message)
        return 1

    def _send_frames(self, frames: Iterable[tuple[int, int, bytes]], base: int, length: int) -> int:
        """Send the frames of one message contiguously (under the send lock); the count, or 0 when one failed."""
        fd, bus, timeout = self.fd, self.bus, self.send_timeout
        count = 0
        with self._send_lock:
            for frame_type, counter, chunk in frames:
                message = Frame(arbitration_id=base | frame_type << 6 | counter, is_extended_id=True,
                                      data=chunk, is_fd=fd, bitrate_switch=fd)  # fmt: skip
                try:
                    bus.send(message, timeout=timeout)
                except (can.CanError, RuntimeError) as exc:
                    self.send_errors += 1
                    log.warning("CAN send failed (%s); message of %d bytes dropped", exc, length)
                    return 0
                self.frames_sent += 1
                count += 1
                if self._logger is not None:
                    self._log_sent(message)
        return count

    def _log_sent(self, frame: Frame) -> None:
        """Log a frame just sent, as sent now: a copy (the bus may have handed ``frame`` itself to its receivers)."""
        sent = deepcopy(frame)
        sent.timestamp = time.time()
        sent.is_rx = False
        self._log(sent)

    def _log(self, frame: can.Message) -> None:
        with self._log_lock:
            if self._logger is not None:
                self._logger.on_message_received(frame)
