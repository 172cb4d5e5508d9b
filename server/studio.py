"""``asm-studio``: the modules, the bridge and the dashboard, started with one command.

By default everything runs in this process on loopback: one module runtime per module of the opened gait's robot,
each an ASM node on an in-process CAN bus that filters like a CAN controller (asm_py.canbus.simbus; what
``asm-module`` runs on a real module), a CAN↔Zenoh
bridge (a Zenoh peer listening on a free loopback port, or the endpoints given), and the dashboard at
http://127.0.0.1:8080. ``--can INTERFACE:CHANNEL`` attaches to a real bus instead of starting simulated modules.

The dashboard is an ordinary ASM node on the bus (node ID 250, named ``studio``): it reaches the modules only by
lookup, get/set, services and subscriptions, like any client.
"""

from __future__ import annotations

import argparse
import logging
import os
import signal
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from asm_py import Event, Node
from asm_py.codec import FLOAT64
from asm_py.event import TimerTrigger
from asm_py.transport.can import CanTransport
from gaits.deploy import module_name
from gaits.model import LIBRARY, Gait, load

from .bridge import CanZenohBridge, check_zenoh_arguments, parse_can
from .module import FakeDriver, ModuleRuntime
from .realtime import prefer_latency

log = logging.getLogger("asm_studio")
STUDIO_NODE_ID = 250
CONTROL_RATE = 50.0
"""Ticks per second of the simulated modules (a module runtime's default)."""
MODULE_IDS = range(1, 200)
"""Node IDs simulated modules may take: 200-253 are the bridge's aliases for Zenoh clients, 254 the bridge."""


@dataclass
class StudioOptions:
    gait: Path = LIBRARY / "caterpillar.toml"
    """The gait opened at start; its robot sets how many simulated modules run."""
    can: dict[str, Any] | None = None
    """python-can options of a real bus; None: simulated modules on an in-process virtual bus."""
    bitrate: int | None = None
    zenoh_listen: tuple[str, ...] = ()
    zenoh_connect: tuple[str, ...] = ()
    zenoh: bool = True
    """Bridge the bus to Zenoh (so tools on other machines see the modules)."""
    zenoh_config: str | None = None
    """A Zenoh JSON5 configuration file (TLS, access control) for the bridge."""
    insecure: bool = False
    """Allow the bridge to listen beyond loopback without TLS and access control."""
    host: str = "127.0.0.1"
    port: int = 8080
    token: str | None = None
    """The page's access token; None: none on loopback, a new random one when served beyond it."""
    heartbeat_period: float = 0.5


class Studio:
    """The backend: modules (simulated or on a real bus), the bridge, the dashboard's node and the web app."""

    def __init__(self, options: StudioOptions) -> None:
        self.options = options
        self.gait: Gait = load(options.gait)
        self.simulated = options.can is None
        channel = f"asm-studio-{os.getpid()}-{id(self)}"
        self.can_options: dict[str, Any] = dict(options.can) if options.can else {"interface": "asm_sim",
                                                                                "channel": channel}  # fmt: skip
        if options.bitrate:
            self.can_options["bitrate"] = options.bitrate
        self._tick: Event | None = None
        self._tick_timer: TimerTrigger | None = None
        self.modules: dict[int, ModuleRuntime] = {}
        self.bridge: CanZenohBridge | None = None
        self.node: Node | None = None
        self.app: Any = None
        self.token: str | None = None
        try:
            if self.simulated:
                self.start_modules(self.gait.robot.modules)
            self.node = Node("studio", self._transport(STUDIO_NODE_ID))
            if options.zenoh:
                aliases = [a for a in range(200, 254) if a != STUDIO_NODE_ID]  # 250 is the dashboard's own ID
                self.bridge = CanZenohBridge(self.can_options, aliases=aliases, zenoh_listen=options.zenoh_listen,
                                             zenoh_connect=options.zenoh_connect, zenoh_config=options.zenoh_config,
                                             insecure=options.insecure)  # fmt: skip
            from web.app import Dashboard  # viser loads only for the studio
            from web.guard import is_loopback, new_token

            self.token = options.token or (None if is_loopback(options.host) else new_token())
            self.app = Dashboard(self, host=options.host, port=options.port, token=self.token)
        except BaseException:
            self.close()
            raise

    def _transport(self, node_id: int) -> CanTransport:
        return CanTransport(node_id, heartbeat_period=self.options.heartbeat_period, **self.can_options)

    def _shared_tick(self) -> Event:
        """One 50 Hz tick for every simulated module, as if their clocks were synchronised: 32 modules each waking
        their own timer thread 50 times a second crowd out the dashboard's threads (Python runs one at a time)."""
        if self._tick is None:
            self._tick = Event("gait.tick", codec=FLOAT64)  # published as a module's own tick is (ModuleRuntime)
            self._tick_timer = TimerTrigger(1.0 / CONTROL_RATE, name="studio.tick")
            self._tick.add_trigger(self._tick_timer)
            self._tick_timer.start()
        return self._tick

    def start_modules(self, count: int) -> list[str]:
        """Run simulated modules m1..m<count> (node IDs 1..count): start the missing ones, close those beyond.

        Modules that stay keep running untouched. Returns the names of the modules closed, so the dashboard can
        tell a module it removed from one that was lost."""
        if count not in MODULE_IDS:
            raise ValueError(f"the studio simulates 1..{MODULE_IDS[-1]} modules, not {count}")
        closed = [self._close_module(module_id) for module_id in sorted(set(self.modules) - set(range(1, count + 1)))]
        for module_id in range(1, count + 1):
            if module_id not in self.modules:
                node = Node(module_name(module_id), self._transport(module_id))
                self.modules[module_id] = ModuleRuntime(FakeDriver(), node=node, tick=self._shared_tick(),
                                                        inline=True)  # fmt: skip
        return closed

    def _close_module(self, module_id: int) -> str:
        """Close simulated module ``module_id``, its runtime then its node; returns the node's name."""
        runtime = self.modules.pop(module_id)
        runtime.close()
        assert runtime.node is not None  # the studio's modules always have one
        runtime.node.close()
        return runtime.node.name

    def stop_modules(self) -> None:
        for module_id in sorted(self.modules):
            self._close_module(module_id)

    @property
    def port(self) -> int:
        return self.app.port if self.app is not None else self.options.port

    def close(self) -> None:
        if self.app is not None:
            self.app.close()
            self.app = None
        if self.bridge is not None:
            self.bridge.close()
            self.bridge = None
        if self.node is not None:
            self.node.close()
            self.node = None
        if self._tick_timer is not None:
            self._tick_timer.stop(timeout=5)
            self._tick_timer = None
        self.stop_modules()


def main(argv: list[str] | None = None) -> int:
    cli = argparse.ArgumentParser(prog="asm-studio", description=__doc__.splitlines()[0] if __doc__ else "")
    cli.add_argument("--gait", type=Path, default=StudioOptions.gait, help="gait file to open (default: caterpillar)")
    cli.add_argument("--can", type=parse_can, metavar="INTERFACE:CHANNEL", help="a real CAN bus instead of simulated "
                     "modules, e.g. socketcan:can0")  # fmt: skip
    cli.add_argument("--bitrate", type=int)
    cli.add_argument("--zenoh-listen", action="append", default=[], metavar="ENDPOINT")
    cli.add_argument("--zenoh-connect", action="append", default=[], metavar="ENDPOINT")
    cli.add_argument("--zenoh-config", metavar="FILE", help="a Zenoh JSON5 configuration (TLS, access control)")
    cli.add_argument("--insecure", action="store_true", help="allow Zenoh to listen beyond loopback without TLS "
                     "and access control (anyone who reaches the port can command the robot)")  # fmt: skip
    cli.add_argument("--no-zenoh", action="store_true", help="do not bridge the bus to Zenoh")
    cli.add_argument("--host", default="127.0.0.1", help="address to serve on (default 127.0.0.1, this machine only)")
    cli.add_argument("--port", type=int, default=8080, help="HTTP port (default 8080; 0 picks a free one)")
    args = cli.parse_args(argv)
    if not args.no_zenoh:
        check_zenoh_arguments(cli, args)
    prefer_latency()
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s")
    options = StudioOptions(gait=args.gait, can=args.can, bitrate=args.bitrate,
                            zenoh_listen=tuple(args.zenoh_listen), zenoh_connect=tuple(args.zenoh_connect),
                            zenoh=not args.no_zenoh, zenoh_config=args.zenoh_config, insecure=args.insecure,
                            host=args.host, port=args.port)  # fmt: skip
    studio = Studio(options)
    done = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: done.set())
    signal.signal(signal.SIGINT, lambda *_: done.set())
    where = "simulated modules" if studio.simulated else f"CAN {args.can}"
    query = f"/?token={studio.token}" if studio.token else ""
    print(f"READY studio http://{args.host}:{studio.port}{query} ({where})", flush=True)
    if studio.token:
        print("The page is served beyond this machine: open it with the token above (it is asked once, then kept "
              "in a cookie).", flush=True)  # fmt: skip
    done.wait()
    studio.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
