"""A JSON view is formatted only while someone watches it: the one piece (asm_py/transport/zenoh_watch.py) that the
node's Zenoh transport and the bridge's outlets share (issue 31), its listener on Zenoh's own threads."""

from __future__ import annotations

import json
import threading

import zenoh

from asm_py import Attribute
from asm_py.node import Node
from asm_py.transport.zenoh import MAX_VIEWS, ZenohTransport, make_config
from asm_py.transport.zenoh_watch import WatchedPublisher

from ..helpers import wait_until
from ..transports import free_port


def test_a_watched_publisher_follows_its_subscribers_without_a_thread_of_its_own() -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    publishing = zenoh.open(make_config(listen=[endpoint]))
    watching = zenoh.open(make_config(connect=[endpoint]))
    try:
        threads = threading.active_count()
        view = WatchedPublisher(publishing.declare_publisher("asm/test/watch/json/x"))
        assert not view.watched
        assert threading.active_count() == threads, "the matching listener runs on Zenoh's threads"
        seen: list[str] = []
        subscriber = watching.declare_subscriber("asm/test/watch/json/*", lambda s: seen.append(s.payload.to_string()))
        assert wait_until(lambda: view.watched, timeout=10)
        assert wait_until(lambda: (view.put('{"v":1}'), seen)[1], timeout=10)
        subscriber.undeclare()
        assert wait_until(lambda: not view.watched, timeout=10)
        view.close()
    finally:
        watching.close()
        publishing.close()


def test_the_transport_formats_a_view_only_while_it_is_watched() -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    transport = ZenohTransport(listen=[endpoint], role="module")
    node = Node("module", transport)
    watcher = zenoh.open(make_config(connect=[endpoint]))
    formatted: list[str] = []

    def view() -> str:
        formatted.append("x")
        return json.dumps({"value": len(formatted)})

    try:
        angle = Attribute("joint.angle", 0.0, codec="float32")
        node.register(angle)
        for _ in range(50):
            transport.publish("joint.angle", b"\x1f\x00\x01\x01\x00\x00\x00\x00", view)
        assert formatted == [], "nobody watches: nothing formatted"
        seen: list[dict] = []
        subscriber = watcher.declare_subscriber(
            "asm/robot/module/json/joint.angle", lambda sample: seen.append(json.loads(sample.payload.to_string()))
        )
        assert wait_until(
            lambda: (transport.publish("joint.angle", b"\x1f\x00\x01\x01\x00\x00\x00\x00", view), seen)[1], timeout=10
        )
        subscriber.undeclare()
        assert wait_until(lambda: not transport._views["asm/robot/module/json/joint.angle"].watched, timeout=10)
        before = len(formatted)
        for _ in range(50):
            transport.publish("joint.angle", b"\x1f\x00\x01\x01\x00\x00\x00\x00", view)
        assert len(formatted) == before, "unwatched again: nothing formatted"
    finally:
        watcher.close()
        node.close()


def test_closing_a_watched_publisher_while_another_thread_puts_on_it_never_raises() -> None:
    """A fresh clone's suite: the bridge closed a module's outlet while its reader thread was putting on it, and
    zenoh-python refused the undeclare ("Already borrowed"), which left the bridge's threads running; and the other
    way round (stop 41's last run), the put refused with "Already mutably borrowed" while the undeclare held it, a
    RuntimeError the reader did not expect: now a ``zenoh.ZError``, as for a put after the close."""
    session = zenoh.open(make_config(listen=[f"tcp/127.0.0.1:{free_port()}"]))
    try:
        for round_ in range(3):
            view = WatchedPublisher(session.declare_publisher(f"asm/test/watch/close/{round_}"))
            stop = threading.Event()

            def put_on(view: WatchedPublisher = view, stop: threading.Event = stop) -> None:
                while not stop.is_set():  # puts back to back: the undeclare finds one under way
                    try:
                        view.put(b"x" * 64)
                    except zenoh.ZError:
                        return  # undeclared under it: the put is refused, which the bridge's reader logs

            putter = threading.Thread(target=put_on)
            putter.start()
            try:
                view.close()
            finally:
                stop.set()
                putter.join(5)
    finally:
        session.close()


def test_a_published_attribute_goes_on_publishing_after_the_transport_forgets_old_request_publishers() -> None:
    """A node's publications go through one sender per object, its publisher declared once (issue 31: no lookup
    per publication); the transport's bounded set of request publishers, whose oldest it undeclares past 1,024
    destinations, must not hold it, or the sender would put on an undeclared publisher."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    transport = ZenohTransport(listen=[endpoint], role="module")
    node = Node("module", transport)
    listener = ZenohTransport(connect=[endpoint])
    reader = Node("reader", listener)
    try:
        angle = Attribute("joint.angle", 0.0, codec="float32")
        node.register(angle)
        angle.publish()
        copy = Attribute("copy", codec="float32")
        copy.subscribe(reader.lookup("module", "joint.angle", timeout=10))
        assert wait_until(lambda: (angle.set(1.0), copy.peek())[1] == 1.0, timeout=10)
        for k in range(1100):  # a message to each of 1,100 destinations: a publisher each, the oldest forgotten
            transport.send(f"nobody-{k}", b"\x3f\x00\x01\x01")
        angle.set(2.0)
        assert wait_until(lambda: copy.peek() == 2.0, timeout=10), "the publication after the forgetting arrived"
    finally:
        reader.close()
        node.close()


def test_publishing_under_any_number_of_names_declares_a_bounded_number_of_publishers() -> None:
    """``Transport.publish`` takes any object name; only a published attribute's sender keeps a publisher for good
    (a review of stop 47: 1,500 names left 3,000 declared entities, a publisher and a JSON view each)."""
    transport = ZenohTransport(listen=[f"tcp/127.0.0.1:{free_port()}"], role="module")
    node = Node("module", transport)
    try:
        angle = Attribute("joint.angle", 0.0, codec="float32")
        node.register(angle)
        angle.publish()  # its sender and view are kept whatever else is published
        for k in range(1500):
            transport.publish(f"obj{k}", b"\x1f\x00\x01\x01")
            transport.publish(f"viewed{k}", b"\x1f\x00\x01\x01", lambda: "{}")  # a JSON view each (a review)
        assert list(transport._senders) == ["joint.angle"]
        assert len(transport._views) <= 1025 and len(transport._publishers) <= 1025
        assert "asm/robot/module/json/joint.angle" in transport._views
        angle.set(1.0)  # its kept sender and view still work
    finally:
        node.close()


def test_concurrent_first_publications_of_one_object_declare_one_sender() -> None:
    transport = ZenohTransport(listen=[f"tcp/127.0.0.1:{free_port()}"], role="module")
    node = Node("module", transport)
    try:
        got: list[object] = []
        barrier = threading.Barrier(8)

        def first() -> None:
            barrier.wait()
            got.append(transport.publication_sender("joint.angle"))

        threads = [threading.Thread(target=first) for _ in range(8)]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join()
        assert len({id(s) for s in got}) == 1 and len(transport._senders) == 1 and len(transport._views) == 1
    finally:
        node.close()


def test_a_view_forgotten_while_publish_formats_it_drops_that_sample_and_raises_nothing() -> None:
    """A review of stop 47: ``publish`` under an arbitrary name formats its JSON view while another thread's
    publications past MAX_VIEWS forget (undeclare) that view; the put raised ``ZError: Undeclared publisher`` into
    the caller. The sample is dropped, as a congested one would be."""
    transport = ZenohTransport(listen=[f"tcp/127.0.0.1:{free_port()}"], role="module")
    node = Node("module", transport)
    try:
        key = transport.keys.json_view(transport.segment, "first")
        transport.publish("first", b"\x1f\x00\x01\x01", lambda: "{}")  # the oldest view
        subscriber = transport.session.declare_subscriber(key, lambda sample: None)
        assert wait_until(lambda: transport._views[key].watched, timeout=10)

        def meanwhile() -> str:  # another thread's publications under new names, while this one formats its view
            for k in range(MAX_VIEWS):
                transport.publish(f"other{k}", b"\x1f\x00\x01\x01", lambda: "{}")
            return "{}"

        transport.publish("first", b"\x1f\x00\x01\x01", meanwhile)
        assert key not in transport._views
        subscriber.undeclare()
    finally:
        node.close()
