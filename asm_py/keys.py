"""The Zenoh key space of ASM: every key a session declares, puts or queries is built here and nowhere else.

A **robot is a namespace**: everything a robot's nodes say lives under ``asm/<robot>/``, so two robots whose
modules have the same names share one Zenoh network without a message ever reaching the wrong one
(docs/protocol.md §6)::

    asm/<robot>/<node>/req/<source>          queryable of <node>: its requests (the query's reply is the reply)
    asm/<robot>/<node>/msg/<source>          subscriber of <node>: requests that want no reply
    asm/<robot>/<node>/pub/<object>          publications of <node>'s <object>
    asm/<robot>/<node>/json/<object>         the same publication as JSON
    asm/<robot>/@group/<group>/msg/<source>  one-to-many requests inside the robot ("all": every node of it)
    asm/<robot>/@alive/<node>/<session>      liveliness token of <node>, one per Zenoh session that kept the name
    asm/<robot>/@claim/<node>/<session>      liveliness token of a session still claiming <node>
    asm/<robot>/@estop/<source>              the robot's emergency stop: every node of that robot, no other
    asm/@lab/estop/<source>                  the lab-wide emergency stop: every node of every robot
    asm/<robot>/@robot/status|poses|mjcf     the robot process's feed for viewers (asm_module.feed)
    asm/<robot>/@robot/commission            the robot process's commissioning service (asm_module.commission_link)
    asm/<robot>/@robot/alive/<session>       liveliness token of the robot process

``<node>`` is a node's *segment*: a module's name (``m3``), or a tool's name behind a tilde (``~studio``). Modules and
tools are separate name spaces: a tool named ``m3`` is ``~m3`` on the network and can never answer a request for
module ``m3``. Names are unique inside a robot and a role: a session refuses to start when its segment is already
alive there (asm_py.transport.zenoh).

Chunks that start with ``@`` are Zenoh *verbatim* chunks: no wildcard matches them, so ``asm/a/*/req/*`` never
reaches a group, an e-stop or a liveliness key, and ``asm/*/...`` never reaches ``asm/@lab``.

An **address** names a node from a client's point of view: ``m3`` (module m3 of the client's own robot), ``~studio``
(a tool of it), ``b/m3`` (module m3 of robot b). Every ``Node`` call that takes a node name takes an address.
"""

from __future__ import annotations

import re
from typing import NamedTuple

from ._contract import ZENOH_KEYS

ROOT = "asm"
DEFAULT_ROBOT = "robot"
"""The robot a session belongs to unless told otherwise."""
TOOL = "~"
"""Marks a tool's segment: tools and modules never share a name on the network."""
LAB = "@lab"
_NAME = re.compile(r"[A-Za-z0-9_.\-]{1,64}")


def check_name(name: str, what: str = "node name") -> str:
    """``name`` if it is a valid node, robot, group or object name (it becomes a chunk of keys and of logs)."""
    if not isinstance(name, str) or not _NAME.fullmatch(name):
        raise ValueError(f"{what} {name!r} must be 1-64 characters of letters, digits, '_', '.', '-'")
    return name


class Address(NamedTuple):
    """A node as a client names it: its robot (None: the client's own), its name, and whether it is a tool."""

    robot: str | None
    name: str
    tool: bool = False

    @property
    def segment(self) -> str:
        """The node's chunk in keys: ``m3`` or ``~studio``."""
        return f"{TOOL}{self.name}" if self.tool else self.name

    def __str__(self) -> str:
        return self.segment if self.robot is None else f"{self.robot}/{self.segment}"


def parse_address(text: str) -> Address:
    """``m3``, ``~studio``, ``b/m3`` or ``b/~studio`` as an Address; ValueError for anything else."""
    if not isinstance(text, str):
        raise ValueError(f"a node address is text, not {type(text).__name__}")
    robot, slash, rest = text.rpartition("/")
    if slash and "/" in robot:
        raise ValueError(f"node address {text!r}: at most one '/' (robot/node)")
    tool = rest.startswith(TOOL)
    name = check_name(rest[1:] if tool else rest, "node name")
    return Address(check_name(robot, "robot name") if slash else None, name, tool)


def segment(name: str, *, tool: bool) -> str:
    """The key chunk of node ``name`` of the given role."""
    return f"{TOOL}{check_name(name)}" if tool else check_name(name)


class RobotKeys:
    """The keys of one robot's namespace (see the module docstring)."""

    __slots__ = ("_patterns", "prefix", "robot")

    def __init__(self, robot: str = DEFAULT_ROBOT) -> None:
        self._set(check_name(robot, "robot name"))

    def _set(self, robot: str) -> None:
        self.robot = robot
        self.prefix = f"{ROOT}/{robot}"
        self._patterns = {name: pattern.replace("{robot}", robot) for name, pattern in ZENOH_KEYS.items()}
        """The contract's key patterns (contract/asm.toml ``zenoh_key``) with this robot filled in."""

    # -- nodes ----------------------------------------------------------------------------------------------------

    def requests(self, node: str, source: str = "*") -> str:
        """``asm/<robot>/<node>/req/<source>`` (``*``: the queryable of every source)."""
        return self._patterns["requests"].format(node=node, source=source)

    def messages(self, node: str, source: str = "*") -> str:
        return self._patterns["messages"].format(node=node, source=source)

    def publication(self, node: str, object_name: str = "*") -> str:
        return self._patterns["publication"].format(node=node, object=object_name)

    def json_view(self, node: str, object_name: str = "*") -> str:
        return self._patterns["json_view"].format(node=node, object=object_name)

    def group(self, group: str, source: str = "*") -> str:
        """``asm/<robot>/@group/<group>/msg/<source>`` (``*`` for group: every group of the robot)."""
        return self._patterns["group"].format(group=group, source=source)

    def alive(self, node: str = "*", session: str = "*") -> str:
        """The liveliness token of ``node`` held by ``session`` (``*``: any)."""
        return self._patterns["alive"].format(node=node, session=session)

    def claim(self, node: str = "*", session: str = "*") -> str:
        """The liveliness token of ``session`` while it claims ``node`` (``*``: any): asm_py.transport.zenoh_claim."""
        return self._patterns["claim"].format(node=node, session=session)

    def estop(self, source: str = "*") -> str:
        return self._patterns["estop"].format(source=source)

    # -- the robot process ----------------------------------------------------------------------------------------

    def robot_key(self, what: str) -> str:
        """``asm/<robot>/@robot/<what>``: ``status``, ``poses``, ``mjcf``, ``commission``."""
        return self._patterns["robot_key"].format(what=what)

    def commission(self) -> str:
        """``asm/<robot>/@robot/commission``: the robot process's commissioning service (a queryable)."""
        return self.robot_key("commission")

    def robot_alive(self, session: str = "*") -> str:
        return self._patterns["robot_alive"].format(session=session)

    def robot_claim(self, session: str = "*") -> str:
        """The robot process's token while it claims the robot's name (server.robot_feed)."""
        return self._patterns["robot_claim"].format(session=session)


def lab_estop(source: str = "*") -> str:
    """``asm/@lab/estop/<source>``: the e-stop of every robot on the network."""
    return ZENOH_KEYS["lab_estop"].format(source=source)


ALL_ROBOTS = RobotKeys.__new__(RobotKeys)
"""Wildcard keys over every robot (``asm/*/...``), for tools that list robots."""
ALL_ROBOTS._set("*")


def split(key: object) -> list[str]:
    """A key's chunks (of a str or a zenoh.KeyExpr)."""
    return str(key).split("/")


def robot_of(key: str) -> str:
    """The robot a key of the ASM key space belongs to (its second chunk)."""
    return split(key)[1]


def last(key: object) -> str:
    """A key's last chunk (of a str or a zenoh.KeyExpr): the source of a request or an e-stop, the object of a
    publication."""
    return str(key).rsplit("/", 1)[-1]


ANY_SOURCE = "any"
"""The source chunk of a reply's key when the query named no single source (it asked with a wildcard)."""


def concrete(chunk: str) -> str:
    """``chunk``, or ANY_SOURCE when it is a wildcard: a reply always carries a concrete key (its replier's own)."""
    return ANY_SOURCE if "*" in chunk or "$" in chunk else chunk


class Route:
    """Where messages to one address go: its robot's keys and its segment (resolved once per address)."""

    __slots__ = ("keys", "segment")

    def __init__(self, keys: RobotKeys, segment: str) -> None:
        self.keys = keys
        self.segment = segment
