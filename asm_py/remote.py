"""Client objects: remote attributes, events and services with the local interface (paper section 3).

A client object is made by ``Node.lookup`` and talks through a :class:`Port`, the client port to one remote node,
shared by every client object and thread of the node (transaction ids pair replies with requests, so any number of
calls may be in flight at once). Gets, lookups and status reads always wait for their reply; ``set``, ``reset``,
``start``, ``stop``, ``suspend`` and ``resume`` return at once unless the caller passes ``wait=True``.

Errors come back as status codes and are raised as the local types: TimeoutError (``AsmTimeout``), ServiceError,
TypeError, ValueError, LookupError; anything else as ``RemoteError``. A call whose peer is gone raises TimeoutError
when its deadline passes, or as soon as discovery reports that the peer left.

Location transparency has one price: ``valid``, ``started``, ``running`` and ``last_error`` are properties, as on
local objects, but on a client object each read is a round trip (and may raise TimeoutError).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from typing import Any

from .clock import Clock
from .codec import Codec
from .lookup import ObjectInfo, parse_description
from .port import Port
from .protocol import (
    HEADER_SIZE,
    TIMEOUT_FLAG,
    Kind,
    Method,
    ObjectKind,
    StatusFlag,
    encode_timeout,
    first_byte,
)
from .service import ServiceStatus

_GET = int(Method.GET)


def make_client(port: Port, description: bytes) -> RemoteObject:
    """The client object for the object a LOOKUP reply's data describes."""
    info = parse_description(description)
    cls = {ObjectKind.ATTRIBUTE: RemoteAttribute, ObjectKind.EVENT: RemoteEvent, ObjectKind.SERVICE: RemoteService}
    return cls[info.kind](port, info)


class RemoteObject:
    """What every client object has: identity, and the port it talks through."""

    def __init__(self, port: Port, info: ObjectInfo) -> None:
        self._port = port
        self.info = info
        self._subject = f"{port.remote}/{info.name}"

    @property
    def name(self) -> str:
        return self.info.name

    @property
    def node(self) -> str:
        """The name of the node the object lives on."""
        return self._port.remote

    @property
    def clock(self) -> Clock:
        """The local node's clock (what event-driven services built on this object run on)."""
        return self._port.node.clock

    def _call(
        self, method: Method, data: bytes = b"", *, timeout: float | None = None, blocking: bool = False
    ) -> bytes:
        info = self.info
        return self._port.call(method, info.class_id, info.object_id, data, timeout=timeout, blocking=blocking,
                               subject=self._subject).data  # fmt: skip

    def _request(self, method: Method, data: bytes, wait: bool, *, timeout: float | None = None, blocks: bool = False):
        """A request that replies only when the caller waits for it."""
        if wait:
            self._call(method, data, timeout=timeout, blocking=blocks)
            return
        code = encode_timeout(timeout) if blocks and timeout is not None else None
        self._port.send(method, self.info.class_id, self.info.object_id, data, timeout=code)

    def __repr__(self) -> str:
        return (
            f"<{type(self).__name__} {self.node}/{self.name} class={self.info.class_id:#04x} id={self.info.object_id}>"
        )


class RemoteAttribute(RemoteObject):
    """An attribute on another node, with the Attribute interface; see the module docstring."""

    @property
    def codec(self) -> Codec:
        return self.info.codec

    @property
    def sync_get(self) -> bool:
        return self.info.sync_get

    @property
    def sync_set(self) -> bool:
        return self.info.sync_set

    def get(self, timeout: float | None = None) -> Any:
        info = self.info  # the hot path of a remote get: no properties, no helper
        return info.codec.decode(self._port.call(_GET, info.class_id, info.object_id, timeout=timeout,
                                                 blocking=info.sync_get, subject=self._subject).data)  # fmt: skip

    def set(self, value: Any, timeout: float | None = None, *, wait: bool | None = None) -> None:
        """Set the remote value. Returns at once, unless ``wait`` — which a ``timeout`` implies: "up to this long"."""
        data = self.codec.encode(value)  # a bad value fails here, before anything is sent
        self._request(Method.SET, data, timeout is not None if wait is None else wait, timeout=timeout,
                      blocks=self.sync_set)  # fmt: skip

    def reset(self, *, wait: bool = False) -> None:
        self._request(Method.RESET, b"", wait)

    @property
    def valid(self) -> bool:
        """Whether the remote value is valid (a round trip)."""
        return bool(self._call(Method.STATUS)[0] & StatusFlag.VALID)

    def peek(self, timeout: float | None = None) -> Any:
        """The remote value without consuming it (``timeout``: how long to wait for the reply, at most)."""
        return self.codec.decode(self._call(Method.PEEK, timeout=timeout))

    def on_change(self, callback: Callable[[Any], None]) -> Callable[[], None]:
        """Call ``callback(value)`` for every publication of the remote attribute; returns a remover."""
        return self._subscribe(callback)

    def _subscribe(self, deliver: Callable[[Any], None]) -> Callable[[], None]:
        decode_value = self.codec.decode
        head0 = first_byte(Kind.PUBLICATION, Method.PUBLISH)

        def on_publication(data: bytes) -> None:
            # A publication never carries a timeout byte: header byte 0 says all, the value starts at byte 4.
            if len(data) >= HEADER_SIZE and data[0] == head0 and not data[1] & TIMEOUT_FLAG:
                try:
                    value = decode_value(data[HEADER_SIZE:])
                except ValueError:
                    return  # a malformed value is dropped, like any malformed message
                deliver(value)

        fixed = self.codec.plain_struct()
        if fixed is not None:  # a number: unpacked in place, no slice, no decode call (every publication; issue 31)
            number_size, unpack_from, general = HEADER_SIZE + fixed.size, fixed.unpack_from, on_publication

            def on_publication(data: bytes) -> None:
                if len(data) == number_size and data[0] == head0 and not data[1] & TIMEOUT_FLAG:
                    deliver(unpack_from(data, HEADER_SIZE)[0])
                else:
                    general(data)  # what the general path drops, it drops

        return self._port.node.transport.subscribe(self.node, self.name, on_publication, object_id=self.info.object_id)


class RemoteEvent(RemoteAttribute):
    """An event on another node: ``waiting`` blocks until its next firing; ``on_change`` sees every firing."""

    def waiting(self, timeout: float | None = None) -> Any:
        return self.codec.decode(self._call(Method.WAIT, timeout=timeout, blocking=True))


class RemoteService(RemoteObject):
    """A service on another node, with the Service interface; parameters travel as a JSON array."""

    def start(self, *params: Any, wait: bool = False) -> None:
        data = json.dumps(list(params)).encode("utf-8") if params else b""
        self._request(Method.START, data, wait)

    def stop(self, timeout: float | None = None, *, wait: bool = False) -> None:
        self._request(Method.STOP, b"", wait, timeout=timeout, blocks=True)

    def suspend(self, *, wait: bool = False) -> None:
        self._request(Method.SUSPEND, b"", wait)

    def resume(self, *, wait: bool = False) -> None:
        self._request(Method.RESUME, b"", wait)

    continue_ = resume

    def reset(self, *, wait: bool = False) -> None:
        self._request(Method.RESET, b"", wait)

    def status(self, timeout: float | None = None) -> ServiceStatus:
        """started, running and the last error in one round trip (``timeout``: how long to wait, at most)."""
        data = self._call(Method.STATUS, timeout=timeout)
        error = (data[1:].decode("utf-8", errors="replace") or None) if data[0] & StatusFlag.FAILED else None
        return ServiceStatus(bool(data[0] & StatusFlag.STARTED), bool(data[0] & StatusFlag.RUNNING), error)

    @property
    def started(self) -> bool:
        return self.status().started

    @property
    def running(self) -> bool:
        return self.status().running

    @property
    def last_error(self) -> str | None:
        """The remote service's last error, as text (the exception itself stays on its node)."""
        return self.status().error
