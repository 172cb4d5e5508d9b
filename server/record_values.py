"""The recorder's attribute values: each object's binary publications, decoded with its codec and written as the JSON
view the bridge would have put — the same bytes, ``t`` included (server/bridge_outlets.py).

Why not subscribe to the JSON views, as the recorder did: a view is formatted by the robot only while someone watches
it, so recording every view made the robot's bridge format about 6,000 of them a second (12-16 µs of its CPU each,
with the GIL the simulation needs); the binary publication is put whether anyone records or not. Decoding needs each
object's codec: an object named after a class of the module profile (``joint.angle``: contract/module.toml) is of
that class, and its codec is the profile's; any other is asked of its node once, by a LOOKUP (a Zenoh query to the
node's requests key, as any client's), its publications held meanwhile.

A publication that is not what its key says — not a publication, another class, a value its codec refuses — is
refused and counted, as a JSON view that did not parse was.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import zenoh

from asm_module._profile import PROFILE
from asm_py.codec import Codec
from asm_py.codec_parse import parse_codec
from asm_py.keys import RobotKeys, segment, split
from asm_py.lookup import parse_description
from asm_py.protocol import HEADER_SIZE, Kind, Message, Method, ObjectKind, Status, decode, encode, first_byte

from .bridge_outlets import value_json, view_prefix, view_text
from .foxglove_msgs import attribute_topic

PUBLICATION = first_byte(Kind.PUBLICATION, Method.PUBLISH)
"""Byte 0 of every publication."""
SEQUENCE = 0x7F
"""Byte 1 of a publication is its sequence number; its top bit (a timeout byte follows) is never set in one."""
SOURCE = segment("asm-record", tool=True)
"""The recorder's segment in the keys of its lookups."""
LOOKUP_TIMEOUT = 2.0
LOOKUP_RETRY = 5.0
"""Seconds before an object whose lookup failed is asked again (its publications meanwhile are refused)."""
GAP_BOUND = 64
"""A jump in an object's sequence numbers of this many or more is a new start (half the numbers: one behind is 127
ahead), not publications lost."""
FRESH_START = 1
"""Sequence numbers a publisher that has just started uses first (it counts from 0)."""
HELD_BOUND = 1_000
"""Publications of one object held while its lookup runs; beyond it they are dropped and counted."""
PROFILE_CODECS: dict[str, tuple[int, Codec]] = {
    name: (spec.id, parse_codec(spec.codec)) for name, spec in PROFILE.items() if spec.kind != "service"
}
"""The module profile's published classes: name → (class ID, codec)."""


class Publications:
    """One object's publications: its channel, and each one's JSON view."""

    __slots__ = ("class_id", "decode", "json", "last_seq", "object_id", "prefix", "topic")

    def __init__(self, node: str, name: str, class_name: str, class_id: int, codec: Codec, object_id: int = -1):
        self.topic = attribute_topic(node, name)
        self.prefix = view_prefix(node, name, class_name)
        self.class_id = class_id
        self.object_id = object_id
        """-1: any (an object of a profile class is known by its name, not its ID)."""
        self.decode = codec.decode
        self.json = value_json(codec)
        self.last_seq = -1
        """The sequence number of the last publication seen, written or refused (-1: none yet)."""

    def missed(self, seq: int) -> int:
        """Publications of this object missing before this one, numbered ``seq``: a publisher numbers its
        publications of an object one by one, modulo 128, and Zenoh delivers one publisher's in order, so a short
        gap is publications lost on the way (values are put with congestion control DROP) or dropped here. A number
        at or behind the last (a duplicate, a reordered sample, a publisher that restarted from 0) or GAP_BOUND and
        more ahead is taken as the sequence starting again, not counted: 64 lost in a row look like none. So is a
        gap that ends at a publisher's first numbers (0, or 1 when its first was not heard): a robot that restarted
        numbers every object from 0 again, and a review counted 209 "missing" publications across a restart (a
        loss that happens to end there is not counted: about 2 in 128)."""
        last, self.last_seq = self.last_seq, seq
        if last < 0:
            return 0
        gap = (seq - last - 1) % (SEQUENCE + 1)
        return gap if gap < GAP_BOUND and (gap == 0 or seq > FRESH_START) else 0

    def view(self, data: bytes, t: float) -> bytes:
        """The JSON view of ``data`` published at ``t``; ValueError if ``data`` is not a publication of this object."""
        if len(data) < HEADER_SIZE or data[0] != PUBLICATION or data[1] > SEQUENCE or data[2] != self.class_id:
            raise ValueError("not a publication of this object's class")
        if self.object_id >= 0 and data[3] != self.object_id:
            raise ValueError("not a publication of this object")
        return view_text(self.prefix, data[1], t, self.json(self.decode(data[HEADER_SIZE:]))).encode()


Write = Callable[[Publications, bytes, float, int], None]
"""Writes one publication (data, its time ``t`` in seconds, its arrival in ns) of an object now known."""


class _Held(list[tuple[bytes, float, int]]):
    """Publications of an object whose lookup is under way."""


class _Unknown:
    """An object whose lookup failed: asked again from ``retry`` (monotonic seconds) on."""

    __slots__ = ("retry",)

    def __init__(self) -> None:
        self.retry = time.monotonic() + LOOKUP_RETRY


class Objects:
    """The publishing objects of one robot, by their publication key; used by the recorder's writer thread only.

    ``post(function, *args)`` runs ``function(*args)`` on that thread later (a lookup's answer arrives on a Zenoh
    thread); ``write`` writes a publication once its object is known."""

    def __init__(self, session: zenoh.Session, robot: str, post: Callable[..., None], write: Write) -> None:
        self.session = session
        self.keys = RobotKeys(robot)
        self.post = post
        self.write = write
        self.dropped = 0
        """Publications refused because their object could not be looked up."""
        self._known: dict[str, Publications | _Held | _Unknown] = {}

    def resolve(self, key: str, data: bytes, t: float, ns: int) -> Publications | None:
        """The object ``key`` publishes, or None: its publication is held until a lookup says (or dropped)."""
        entry = self._known.get(key)
        if entry is None or (type(entry) is _Unknown and time.monotonic() >= entry.retry):
            node, name = _node_and_object(key)
            profile = PROFILE_CODECS.get(name)
            if profile is not None:
                entry = self._known[key] = Publications(node, name, name, *profile)
            else:
                entry = self._known[key] = _Held()
                self._look_up(key, node, name)
        if type(entry) is Publications:
            return entry
        if type(entry) is _Held and len(entry) < HELD_BOUND:
            entry.append((data, t, ns))
        else:
            self.dropped += 1
        return None

    def _look_up(self, key: str, node: str, name: str) -> None:
        replies: list[bytes] = []

        def reply(answer: zenoh.Reply) -> None:
            if answer.ok is not None:
                replies.append(answer.ok.payload.to_bytes())

        def done() -> None:
            self.post(self._answered, key, node, name, replies[0] if replies else b"")

        request = encode(Message(Kind.REQUEST_REPLY, Method.LOOKUP, data=name.encode()))
        try:
            self.session.get(self.keys.requests(node, SOURCE), zenoh.handlers.Callback(reply, done),
                             payload=request, timeout=LOOKUP_TIMEOUT)  # fmt: skip
        except zenoh.ZError:  # the session is closing
            done()

    def _answered(self, key: str, node: str, name: str, answer: bytes) -> None:
        held = self._known.get(key)
        try:
            message = decode(answer)
            if message.kind != Kind.REPLY or message.status != Status.OK:
                raise ValueError(f"lookup of {node}/{name} answered with status {message.status}")
            info = parse_description(message.data)
            if info.name != name or info.kind not in (ObjectKind.ATTRIBUTE, ObjectKind.EVENT):
                raise ValueError(f"{node}/{name} is not an attribute or event of that name")
            known = Publications(node, name, info.class_name, info.class_id, info.codec, info.object_id)
        except ValueError:  # no answer, an error, or not an object that publishes values
            self._known[key] = _Unknown()
            self.dropped += len(held) if isinstance(held, _Held) else 0
            return
        self._known[key] = known
        for data, t, ns in held if isinstance(held, _Held) else ():
            self.write(known, data, t, ns)


def _node_and_object(key: str) -> tuple[str, str]:
    chunks = split(key)  # asm/<robot>/<node>/pub/<object>
    return chunks[2], chunks[4]


def values_key(robot: str) -> str:
    """Every node's publications of ``robot``."""
    return RobotKeys(robot).publication("*", "*")
