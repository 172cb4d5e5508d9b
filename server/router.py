"""``asm-router``: a Zenoh router for a lab's robots and studios — zenoh-python's own router mode, nothing more.

Robots (``asm-robot --zenoh-mode client --zenoh-connect ENDPOINT``) and studios (``asm-studio --robot ENDPOINT
--zenoh-mode client``) are clients of one router: they reach each other only through it, and each robot keeps its
keys under its own name (asm_py.keys), so robots with the same module IDs share the network. The router listens on
loopback unless told otherwise; beyond loopback only with TLS, mutual authentication and access control
(``--zenoh-config``, docs/security.md), or ``--insecure``. It prints ``READY router ENDPOINT`` once it listens.

    asm-router --listen tcp/127.0.0.1:7447
"""

from __future__ import annotations

import argparse
import logging

from asm_py.cli import close_and_exit, input_file, run, stop_requested, summary, zenoh_endpoint

from .realtime import prefer_latency
from .zenoh_args import ZenohOptions, zenoh_options


def main(argv: list[str] | None = None) -> int:
    cli = argparse.ArgumentParser(prog="asm-router", description=summary(__doc__))
    cli.add_argument("--listen", action="append", type=zenoh_endpoint, required=True, metavar="ENDPOINT",
                     help="where robots and studios connect, e.g. tcp/127.0.0.1:7447 (repeatable)")  # fmt: skip
    cli.add_argument("--connect", action="append", default=[], type=zenoh_endpoint, metavar="ENDPOINT",
                     help="another router to join (routers of several rooms form one network)")  # fmt: skip
    cli.add_argument("--zenoh-config", type=input_file, metavar="FILE", help="a Zenoh JSON5 configuration (TLS, "
                     "access control)")  # fmt: skip
    cli.add_argument("--insecure", action="store_true", help="allow listening beyond loopback without TLS and access "
                     "control (anyone who reaches the port can command every robot)")  # fmt: skip
    args = cli.parse_args(argv)
    args.zenoh_mode, args.zenoh_listen, args.zenoh_connect = "router", args.listen, args.connect
    network = zenoh_options(cli, args)
    return run(cli.prog, lambda: _serve(network))


def _serve(network: ZenohOptions) -> int:
    prefer_latency()
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s")
    done = stop_requested()
    session = network.open()
    print(f"READY router {' '.join(network.listen)}", flush=True)
    done.wait()
    close_and_exit(session.close, "asm-router")


if __name__ == "__main__":
    raise SystemExit(main())
