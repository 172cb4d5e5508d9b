"""Zenoh beyond loopback: refused unless secured (TLS, mutual TLS, access control) or --insecure; the documented
secure configuration (docs/zenoh-secure.json5) works, tested on loopback with certificates made here."""

from __future__ import annotations

import logging
import subprocess
import sys
from pathlib import Path

import pytest

from asm_py import Attribute
from asm_py.node import Node
from asm_py.transport.zenoh import InsecureEndpoint, ZenohTransport, make_config

from ..certs import Authority, secure_config
from ..transports import free_port


def test_listening_beyond_loopback_needs_tls_mtls_and_access_control(tmp_path: Path, caplog) -> None:
    for endpoint in ("tcp/0.0.0.0:7447", "tcp/192.0.2.7:7447", "udp/[::]:0", "tls/0.0.0.0:7447"):
        with pytest.raises(InsecureEndpoint, match="--insecure"):
            make_config(listen=[endpoint])  # a configuration only: nothing is opened
    authority = Authority(tmp_path)
    secured = secure_config(tmp_path, authority, "robot")
    make_config(listen=["tls/192.0.2.7:7447"], config_file=secured)  # TLS + mTLS + ACL: allowed
    with pytest.raises(InsecureEndpoint, match="not a tls/"):
        make_config(listen=["tcp/192.0.2.7:7447"], config_file=secured)
    no_acl = tmp_path / "no-acl.json5"
    no_acl.write_text(Path(secured).read_text().replace("enabled: true", "enabled: false"))
    with pytest.raises(InsecureEndpoint, match="access control is off"):
        make_config(listen=["tls/192.0.2.7:7447"], config_file=str(no_acl))
    caplog.set_level(logging.WARNING)
    make_config(listen=["tcp/0.0.0.0:7447"], insecure=True)
    assert any("INSECURE" in r.message for r in caplog.records)
    for loopback in ("tcp/127.0.0.1:0", "tcp/[::1]:0", "tcp/localhost:0"):
        make_config(listen=[loopback])


def test_only_certified_and_allowed_peers_reach_the_robot_over_tls(tmp_path: Path) -> None:
    authority, rogue = Authority(tmp_path), Authority(tmp_path, "rogue-ca")
    endpoint = f"tls/localhost:{free_port()}"
    nodes: list[Node] = []
    try:
        robot = Node("m1", ZenohTransport(listen=[endpoint], role="module",
                                          config_file=secure_config(tmp_path, authority, "robot")))  # fmt: skip
        nodes.append(robot)
        robot.register(Attribute("joint.goal", 3.5, codec="float32"))
        operator = Node("op", ZenohTransport(connect=[endpoint],
                                             config_file=secure_config(tmp_path, authority, "operator")))  # fmt: skip
        nodes.append(operator)
        assert operator.lookup("m1", "joint.goal", timeout=10).peek() == 3.5
        for name, issuer in (("visitor", authority), ("intruder", rogue)):  # not allowed / not of our CA
            stranger = Node(name, ZenohTransport(connect=[endpoint],
                                                 config_file=secure_config(tmp_path, issuer, name)))  # fmt: skip
            nodes.append(stranger)
            with pytest.raises(TimeoutError):
                stranger.lookup("m1", "joint.goal", timeout=1.5)
    finally:
        for node in reversed(nodes):
            node.close()


def test_the_commands_refuse_an_insecure_listener_in_one_line() -> None:
    for command in (["-m", "server.bridge", "--can", "virtual:x"], ["-m", "server.studio", "--port", "0"]):
        result = subprocess.run([sys.executable, *command, "--zenoh-listen", "tcp/0.0.0.0:0"], capture_output=True,
                                text=True, timeout=60)  # fmt: skip
        assert result.returncode == 2, result.stderr
        assert "Traceback" not in result.stderr and "--insecure" in result.stderr
