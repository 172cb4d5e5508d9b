"""The same test bodies run against local objects and against remote ones (memory and Zenoh transports).

This is the proof of the paper's location transparency: code written against an Attribute, an Event or a Service
runs unchanged on a RemoteAttribute, RemoteEvent or RemoteService.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager

import pytest

from asm_py import Attribute, Event, EventDrivenService, Service, ServiceError, Trigger
from asm_py.node import Node

from ..helpers import wait_until
from ..transports import FACTORIES


class Worker(Service):
    """A software service that counts while running."""

    def __init__(self, name: str = "worker") -> None:
        super().__init__(name)
        self.count = 0

    def run(self, step: int = 1) -> None:
        while self.sleep(0.002):
            self.count += step


@contextmanager
def local_world() -> Iterator[Callable]:
    def expose(obj):
        return obj

    yield expose


@contextmanager
def remote_world(kind: str) -> Iterator[Callable]:
    with FACTORIES[kind]() as make:
        server = Node("server", make())
        client = Node("client", make())
        assert wait_until(lambda: {"server", "client"} <= set(client.discover()), timeout=10)

        def expose(obj):
            server.register(obj)
            return client.lookup("server", obj.name, timeout=5)

        try:
            yield expose
        finally:
            client.close()
            server.close()
            for entry in server.entries:
                if isinstance(entry.obj, Service):
                    entry.obj.stop(timeout=5)


@pytest.fixture(params=["local", *sorted(FACTORIES)])
def expose(request) -> Iterator[Callable]:
    world = local_world() if request.param == "local" else remote_world(request.param)
    with world as expose:
        yield expose


def test_plain_attribute(expose) -> None:
    attr = expose(Attribute("goal", 1.5, codec="float32"))
    assert attr.get() == 1.5
    assert not attr.valid
    attr.set(2.25)
    assert attr.valid
    assert attr.get() == 2.25
    assert attr.get() == 2.25, "a plain attribute never blocks"
    assert attr.name == "goal" and not attr.sync_get and not attr.sync_set


def test_sync_get_waits_and_times_out(expose) -> None:
    attr = expose(Attribute("fresh", sync_get=True, codec="int32"))
    with pytest.raises(TimeoutError):
        attr.get(timeout=0.1)
    box: list[int] = []
    reader = threading.Thread(target=lambda: box.append(attr.get(timeout=10)))
    reader.start()
    assert not wait_until(lambda: box, timeout=0.2)
    attr.set(42, timeout=5)
    reader.join(10)
    assert box == [42]


def test_sync_set_waits_and_times_out(expose) -> None:
    attr = expose(Attribute("used", sync_set=True, codec="int32"))
    attr.set(1, timeout=5)
    with pytest.raises(TimeoutError):
        attr.set(2, timeout=0.1)
    assert attr.get() == 1
    attr.set(3, timeout=5)
    assert attr.get() == 3


def test_rendezvous(expose) -> None:
    attr = expose(Attribute("slot", sync_get=True, sync_set=True, codec="uint16"))
    received: list[int] = []
    consumer = threading.Thread(target=lambda: [received.append(attr.get(timeout=10)) for _ in range(30)])
    consumer.start()
    for i in range(30):
        attr.set(i, timeout=10)
    consumer.join(20)
    assert received == list(range(30))


def test_reset_and_codec_errors(expose) -> None:
    attr = expose(Attribute("limits", 7, codec="int8"))
    attr.set(1, wait=True)
    attr.reset(wait=True)
    assert attr.get() == 7 and not attr.valid
    with pytest.raises(TypeError):
        attr.set("seven")
    with pytest.raises(ValueError):
        attr.set(300)
    assert attr.get() == 7


def test_event_waiting(expose) -> None:
    source = Event("contact", codec="bool")
    trigger = Trigger()
    source.add_trigger(trigger)
    event = expose(source)
    with pytest.raises(TimeoutError):
        event.waiting(timeout=0.1)
    box: list[bool] = []
    waiter = threading.Thread(target=lambda: box.append(event.waiting(timeout=10)))
    waiter.start()
    # the waiter's request must have reached the event before the firing: fire until it wakes
    assert wait_until(lambda: (trigger.fire(True), box)[1], timeout=10)
    waiter.join(10)
    assert box == [True]


def test_service_lifecycle(expose) -> None:
    worker = Worker()
    service = expose(worker)
    assert not service.started and not service.running
    service.start(2, wait=True)
    assert service.started and service.running
    with pytest.raises(ServiceError):
        service.start(wait=True)
    assert wait_until(lambda: worker.count > 0)
    with pytest.raises(ServiceError):
        service.reset(wait=True)
    service.suspend(wait=True)
    assert service.started and not service.running
    service.continue_(wait=True)
    assert service.running
    service.stop(timeout=5, wait=True)
    assert not service.started
    service.reset(wait=True)
    assert worker.count % 2 == 0


def test_service_failure_is_reported(expose) -> None:
    class Faulty(Service):
        def run(self) -> None:
            raise RuntimeError("motor stalled")

    service = expose(Faulty("faulty"))
    service.start(wait=True)
    assert wait_until(lambda: not service.started)
    assert "motor stalled" in str(service.last_error)


def test_event_drives_an_event_driven_service(expose) -> None:
    source = Event("tick", codec="uint32")
    event = expose(source)
    handled: list[int] = []
    service = EventDrivenService("consumer", event, handler=handled.append)
    service.start()
    try:
        # subscriptions propagate asynchronously: fire until the first firing arrives, then count exactly
        assert wait_until(lambda: (source.set(0), handled)[1], timeout=10)
        for i in range(1, 21):
            source.set(i)
        assert wait_until(lambda: handled[-1] == 20)
        assert [v for v in handled if v != 0] == list(range(1, 21)), "every firing once, in order"
    finally:
        service.stop(timeout=5)
