"""Zenoh session configuration for ASM: safe defaults, explicit endpoints, and the rules for leaving loopback.

Defaults are safe: peer mode, multicast scouting off, and a peer or router listens on a free loopback port
(``tcp/127.0.0.1:0``) unless endpoints are given — never on every interface; ``connect`` lists the peers or router
to reach. Listening beyond loopback lets other machines command the robot, so :func:`make_config` allows it only with
a Zenoh configuration file that secures it — TLS (or QUIC) endpoints, mutual TLS (every peer shows a certificate of
the robot's CA) and access control enabled — or with ``insecure=True`` (the ``--insecure`` flag of the commands),
which logs a warning. docs/security.md shows a secured two-machine setup.
"""

from __future__ import annotations

import ipaddress
import json
import logging
from collections.abc import Sequence

import zenoh

from ..protocol import MAX_MESSAGE

log = logging.getLogger("asm_py.transport.zenoh")
BOUNDED_KEYS = (
    "**",
    "asm/*/@group/**",
    "asm/*/@estop/**",
    "asm/*/@alive/**",
    "asm/*/@claim/**",
    "asm/*/@robot/**",
    "asm/@lab/**",
)
"""Key expressions whose messages are held to MAX_LINK_MESSAGE at every session's ingress."""

MAX_LINK_MESSAGE = 16 * MAX_MESSAGE
"""The largest Zenoh message a session accepts from its links (the rest is dropped by Zenoh, never buffered)."""


class InsecureEndpoint(ValueError):
    """A listening endpoint beyond loopback without TLS, mutual authentication and access control."""


def endpoint_host(endpoint: str) -> str:
    """The host of a Zenoh endpoint such as ``tcp/127.0.0.1:7447`` or ``tls/[::1]:7447#iface=lo``."""
    address = endpoint.split("#", 1)[0].split("?", 1)[0].partition("/")[2]
    return address.rpartition(":")[0].strip("[]") if ":" in address else address


def is_loopback_endpoint(endpoint: str) -> bool:
    host = endpoint_host(endpoint)
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def security_problems(config: zenoh.Config, endpoints: Sequence[str]) -> list[str]:
    """What keeps ``endpoints`` (listening beyond loopback) from being secured by ``config``; empty when secured."""
    problems = [f"{e} is not a tls/ or quic/ endpoint" for e in endpoints if not e.startswith(("tls/", "quic/"))]
    if json.loads(config.get_json("transport/link/tls/enable_mtls") or "null") is not True:
        problems.append("mutual TLS is off (transport/link/tls/enable_mtls)")
    if json.loads(config.get_json("access_control/enabled") or "false") is not True:
        problems.append("access control is off (access_control/enabled)")
    return problems


def make_config(
    *,
    mode: str = "peer",
    listen: Sequence[str] = (),
    connect: Sequence[str] = (),
    config_file: str | None = None,
    insecure: bool = False,
) -> zenoh.Config:
    """A Zenoh configuration: ``mode`` peer/client/router, explicit endpoints, multicast scouting off.

    ``config_file`` (JSON5) gives everything else — TLS certificates, access control; the endpoints always come
    from ``listen`` and ``connect`` (no listen: a free loopback port, whatever the file says).

    InsecureEndpoint when a listening endpoint is beyond loopback and not secured (see the module docstring), unless
    ``insecure``.
    """
    if mode not in ("peer", "client", "router"):
        raise ValueError(f"zenoh mode must be 'peer', 'client' or 'router', not {mode!r}")
    config = zenoh.Config.from_file(config_file) if config_file else zenoh.Config()
    config.insert_json5("mode", json.dumps(mode))
    config.insert_json5("scouting/multicast/enabled", "false")
    # Never Zenoh's default listener (all interfaces): a peer or router listens on loopback unless told otherwise.
    if not listen and mode != "client":
        listen = ["tcp/127.0.0.1:0"]
    exposed = [e for e in listen if not is_loopback_endpoint(e)]
    if exposed:
        problems = security_problems(config, exposed)
        if problems and not insecure:
            raise InsecureEndpoint(f"refusing to listen on {', '.join(exposed)} beyond this machine: "
                                   f"{'; '.join(problems)}. Give a Zenoh config with TLS, mutual TLS and access "
                                   "control (docs/security.md), or --insecure")  # fmt: skip
        if problems:
            log.warning("INSECURE: listening on %s without %s: anyone who can reach it can command the robot",
                        ", ".join(exposed), "; ".join(problems))  # fmt: skip
    config.insert_json5("listen/endpoints", json.dumps(list(listen)))
    # Zenoh buffers a message whole before anything sees it: bound that at the link (ASM messages are at most
    # MAX_MESSAGE bytes; between that and this bound a node answers TOO_LARGE, beyond it the message is dropped)
    config.insert_json5("transport/link/rx/max_message_size", str(MAX_LINK_MESSAGE))
    # Zenoh's shared-memory transport carries any message over 3 KiB as a reference into the sender's 16 MiB pool:
    # it bypasses the link limit above (a 10 MB query arrives whole) and lets every local client make this process
    # map its pool. ASM messages are at most MAX_MESSAGE bytes, so shared memory buys nothing here: off.
    config.insert_json5("transport/shared_memory/enabled", "false")
    # and drop what is larger before it reaches any callback ("**" matches no verbatim chunk such as @group: those
    # keys are listed, so the bound holds on every key of the ASM key space)
    config.insert_json5("low_pass_filter", json.dumps([{"flows": ["ingress"], "messages": ["put", "delete", "query",
                        "reply"], "key_exprs": list(BOUNDED_KEYS), "size_limit": MAX_LINK_MESSAGE}]))  # fmt: skip
    if connect:
        config.insert_json5("connect/endpoints", json.dumps(list(connect)))
    return config
