"""The Zenoh options every command shares, as python-can's ``add_bus_arguments`` gives every tool the same bus flags.

``add_zenoh_arguments(cli)`` adds ``--zenoh-mode``, ``--zenoh-listen``, ``--zenoh-connect``, ``--zenoh-config`` and
``--insecure``; ``zenoh_options(cli, args)`` checks them once parsed (a usage error, exit 2, for an endpoint that
would be insecure or a configuration file that is bad) and returns one :class:`ZenohOptions` that opens sessions,
makes transports and passes the same options on to a child process.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from dataclasses import dataclass

import zenoh

from asm_py.cli import describe, input_file, zenoh_endpoint
from asm_py.transport.zenoh import ZenohTransport
from asm_py.transport.zenoh_config import make_config


@dataclass(frozen=True)
class ZenohOptions:
    """Where a process's Zenoh sessions connect and listen, and how they are secured."""

    mode: str = "peer"
    """"peer", "client" (through a router) or "router" (asm-router only)."""
    listen: tuple[str, ...] = ()
    connect: tuple[str, ...] = ()
    config_file: str | None = None
    """A Zenoh JSON5 configuration (TLS, access control)."""
    insecure: bool = False
    """Allow listening beyond loopback without TLS and access control."""

    def config(self) -> zenoh.Config:
        return make_config(mode=self.mode, listen=self.listen, connect=self.connect, config_file=self.config_file,
                           insecure=self.insecure)  # fmt: skip

    def open(self) -> zenoh.Session:
        """A Zenoh session with these options."""
        return zenoh.open(self.config())

    def transport(self, *, robot: str, role: str = "tool") -> ZenohTransport:
        """An ASM transport of robot ``robot`` with these options (a tool unless ``role`` says "module")."""
        return ZenohTransport(robot=robot, role=role, mode=self.mode, listen=self.listen, connect=self.connect,
                              config_file=self.config_file, insecure=self.insecure)  # fmt: skip

    def with_(self, *, listen: Sequence[str] | None = None, connect: Sequence[str] | None = None) -> ZenohOptions:
        """The same options with other endpoints."""
        return ZenohOptions(self.mode, tuple(self.listen if listen is None else listen),
                            tuple(self.connect if connect is None else connect), self.config_file,
                            self.insecure)  # fmt: skip

    def args(self) -> list[str]:
        """These options as command-line arguments (for a child process of the same family)."""
        out = ["--zenoh-mode", self.mode]
        for endpoint in self.listen:
            out += ["--zenoh-listen", endpoint]
        for endpoint in self.connect:
            out += ["--zenoh-connect", endpoint]
        if self.config_file:
            out += ["--zenoh-config", self.config_file]
        if self.insecure:
            out.append("--insecure")
        return out


ONE_SHOT_MODE_HELP = (
    "client (default when it connects somewhere: the peer or router it connects to passes its messages on to every "
    "session there) or peer (its messages reach only the peers Zenoh's gossip has brought it when it sends)"
)


def add_zenoh_arguments(
    cli: argparse.ArgumentParser,
    *,
    listen_help: str | None = None,
    modes: Sequence[str] = ("peer", "client"),
    one_shot: bool = False,
) -> None:
    """The Zenoh options of a command (see the module docstring).

    ``one_shot``: the command sends the moment it has connected and leaves (asm-estop). As a peer it would be one
    of a mesh whose other peers it has not met yet — Zenoh's peers do not pass each other's messages on, and its
    gossip brings the rest only after a while — so its put would miss them (a recorder, a studio, a second robot
    connected to the first). As a client, the one it connects to routes its put to all of them. Its mode defaults
    to client when ``--zenoh-connect`` is given, peer otherwise."""
    if one_shot:
        cli.add_argument("--zenoh-mode", default=None, choices=list(modes), help=ONE_SHOT_MODE_HELP)
    else:
        modes_help = "peer (default: sessions meet directly), or client (through a router, asm-router)"
        cli.add_argument("--zenoh-mode", default=modes[0], choices=list(modes), help=modes_help)
    cli.add_argument("--zenoh-listen", action="append", default=[], type=zenoh_endpoint, metavar="ENDPOINT",
                     help=listen_help)  # fmt: skip
    cli.add_argument("--zenoh-connect", action="append", default=[], type=zenoh_endpoint, metavar="ENDPOINT",
                     help="a router or peer to connect to, e.g. tcp/127.0.0.1:7447")  # fmt: skip
    cli.add_argument("--zenoh-config", type=input_file, metavar="FILE",
                     help="a Zenoh JSON5 configuration (TLS, access control)")  # fmt: skip
    cli.add_argument("--insecure", action="store_true", help="allow Zenoh to listen beyond loopback without TLS "
                     "and access control (anyone who reaches the port can command the robot)")  # fmt: skip


def zenoh_options(cli: argparse.ArgumentParser, args: argparse.Namespace) -> ZenohOptions:
    """The parsed options, checked: a usage error (exit 2, one line) for endpoints that would be insecure or a
    configuration file that is bad; a client without a router to connect to is one too."""
    mode = args.zenoh_mode or ("client" if args.zenoh_connect else "peer")  # None: one_shot's default
    options = ZenohOptions(mode, tuple(args.zenoh_listen), tuple(args.zenoh_connect),
                           str(args.zenoh_config) if args.zenoh_config else None, args.insecure)  # fmt: skip
    if options.mode == "client" and not options.connect:
        cli.error("--zenoh-mode client needs --zenoh-connect ENDPOINT (the router)")
    try:
        options.config()
    except (ValueError, OSError, zenoh.ZError) as exc:
        cli.error(describe(exc))
    return options
