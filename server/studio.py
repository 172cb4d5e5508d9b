"""``asm-studio``: the dashboard, as a client of a robot — one command for everything.

By default the studio starts a simulated robot, ``asm-robot --sim GAIT`` (server/robot.py: the opened gait's robot
in real-time MuJoCo physics, its modules on a CAN bus, the CAN↔Zenoh bridge), as a child process on a private
loopback Zenoh link, and serves the page at http://127.0.0.1:8080. The child ends with the studio, even when the
studio is killed. ``--can INTERFACE:CHANNEL`` starts ``asm-robot --can`` for a real bus instead; ``--robot
ENDPOINT`` attaches to a robot process already running elsewhere (a robot's computer, or another machine's
simulation) and starts nothing.

The dashboard is an ordinary Zenoh ASM node named ``studio``: it reaches the modules only through the bridge, by
lookup, get/set, services and subscriptions, like any tool. It hosts no module runtime.
"""

from __future__ import annotations

import argparse
import logging
import os
import queue
import socket
import subprocess
import sys
import tempfile
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import zenoh

from asm_py import Node
from asm_py.cli import (
    bitrate,
    can_channel,
    input_file,
    module_selection,
    name,
    port,
    run,
    stop_requested,
    zenoh_endpoint,
)
from asm_py.feed import RobotStatus, status_key
from asm_py.transport.zenoh import ZenohTransport
from gaits.model import LIBRARY, Gait, dumps, loads
from gaits.validate import read

from .bridge import add_zenoh_arguments, check_zenoh_arguments
from .realtime import prefer_latency

log = logging.getLogger("asm_studio")
ROBOT_START_TIMEOUT = 60.0


@dataclass
class StudioOptions:
    gait: Path = LIBRARY / "caterpillar.toml"
    """The gait opened at start; a simulated robot is built from its robot."""
    can: dict[str, Any] | None = None
    """python-can options of a real bus (``asm-robot --can``); None: a simulated robot."""
    robot: str | None = None
    """A Zenoh endpoint of a robot process already running: attach to it, start none."""
    robot_name: str = "robot"
    bitrate: int | None = None
    zenoh_listen: tuple[str, ...] = ()
    """More endpoints the robot listens on (so tools elsewhere reach the modules)."""
    zenoh_connect: tuple[str, ...] = ()
    zenoh_config: str | None = None
    """A Zenoh JSON5 configuration file (TLS, access control) for the robot and the studio's own session."""
    insecure: bool = False
    """Allow the robot to listen beyond loopback without TLS and access control."""
    host: str = "127.0.0.1"
    port: int = 8080
    view: str = "preview"
    """What the 3D view shows at start: "preview" (the edited gait) or "live" (the robot)."""
    token: str | None = None
    """The page's access token; None: none on loopback, a new random one when served beyond it."""
    c_modules: str | None = None
    """Simulated modules that run the C runtime (``asm-robot --c-modules``): "odd", "even", "all" or "1,3,5"."""


def free_loopback_port() -> int:
    """A TCP port free on 127.0.0.1 now (bound and released: the child binds it a moment later)."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


class RobotChild:
    """An ``asm-robot`` child process on a private loopback endpoint; it dies with this process."""

    def __init__(self, args: list[str], endpoint: str) -> None:
        self.endpoint = endpoint
        env = {**os.environ, "PYTHONUNBUFFERED": "1"}
        self.popen = subprocess.Popen([sys.executable, "-m", "server.robot", "--zenoh-listen", endpoint,
                                       "--parent-pid", str(os.getpid()), *args], stdout=subprocess.PIPE,
                                      stderr=subprocess.STDOUT, text=True, env=env)  # fmt: skip
        self.output: list[str] = []
        self._lines: queue.Queue[str | None] = queue.Queue()
        self._reader = threading.Thread(target=self._read, name="robot-output", daemon=True)
        self._reader.start()
        self._wait_ready()

    def _read(self) -> None:
        assert self.popen.stdout is not None
        for line in self.popen.stdout:
            self.output.append(line)
            del self.output[:-200]
            self._lines.put(line)
            log.debug("robot: %s", line.rstrip())
        self._lines.put(None)

    def _wait_ready(self) -> None:
        while True:
            try:
                line = self._lines.get(timeout=ROBOT_START_TIMEOUT)
            except queue.Empty:
                line = None
            if line is None:
                self.stop()
                raise RuntimeError("the robot process did not start: " + "".join(self.output[-5:]).strip())
            if line.startswith("READY robot"):
                return

    def stop(self) -> None:
        if self.popen.poll() is None:
            self.popen.terminate()
            try:
                self.popen.wait(15)
            except subprocess.TimeoutExpired:
                self.popen.kill()
                self.popen.wait(5)
        self._reader.join(5)


class Studio:
    """The backend: the robot (a child process, or one attached to), the dashboard's node and the web app."""

    def __init__(self, options: StudioOptions) -> None:
        self.options = options
        self.robot_name = options.robot_name
        self.c_modules = options.c_modules
        raw = read(options.gait)  # once: the gait, and its text for a download that keeps its comments
        self.gait: Gait = loads(raw, source=str(options.gait))
        self.gait_text: str | None = raw.decode("utf-8-sig")  # it decoded as the gait above
        self.child: RobotChild | None = None
        self.node: Node | None = None
        self.app: Any = None
        self.token: str | None = None
        self.robot_gait: Gait | None = None
        """The gait whose robot the simulated child runs (None when the robot is not ours to rebuild)."""
        self._gait_file: Path | None = None
        try:
            endpoint = options.robot or self._start_robot(self.gait)
            self.node = Node("studio", ZenohTransport(connect=[endpoint], config_file=options.zenoh_config))
            self.status = self.read_status(timeout=10.0)
            self.simulated = self.status.mode == "simulated"
            from web.app import Dashboard  # viser loads only for the studio
            from web.guard import is_loopback, new_token

            self.token = options.token or (None if is_loopback(options.host) else new_token())
            self.app = Dashboard(self, host=options.host, port=options.port, token=self.token)
            self.app.show(options.view)
        except BaseException:
            self.close()
            raise

    def _robot_args(self, gait: Gait) -> list[str]:
        options = self.options
        args = ["--name", options.robot_name]
        if options.can is not None:
            args += ["--can", f"{options.can['interface']}:{options.can['channel']}"]
            if options.bitrate:
                args += ["--bitrate", str(options.bitrate)]
        else:
            if self._gait_file is None:
                handle, name = tempfile.mkstemp(prefix="asm-studio-robot-", suffix=".toml")
                os.close(handle)
                self._gait_file = Path(name)
            self._gait_file.write_text(dumps(gait))
            args += ["--sim", str(self._gait_file)]
            if options.c_modules:
                args += ["--c-modules", options.c_modules]
            self.robot_gait = gait
        for endpoint in options.zenoh_listen:
            args += ["--zenoh-listen", endpoint]
        for endpoint in options.zenoh_connect:
            args += ["--zenoh-connect", endpoint]
        if options.zenoh_config:
            args += ["--zenoh-config", options.zenoh_config]
        if options.insecure:
            args.append("--insecure")
        return args

    def _start_robot(self, gait: Gait) -> str:
        endpoint = f"tcp/127.0.0.1:{free_loopback_port()}"
        self.child = RobotChild(self._robot_args(gait), endpoint)
        return endpoint

    def read_status(self, timeout: float = 5.0) -> RobotStatus:
        """The robot's status, as it publishes it (waits for the next publication)."""
        assert self.node is not None
        session: zenoh.Session = self.node.transport.session  # type: ignore[attr-defined]
        box: queue.Queue[bytes] = queue.Queue()
        subscriber = session.declare_subscriber(status_key(self.options.robot_name),
                                                lambda sample: box.put(sample.payload.to_bytes()))  # fmt: skip
        try:
            return RobotStatus.from_json(box.get(timeout=timeout))
        except queue.Empty:
            raise RuntimeError(f"no status from robot {self.options.robot_name!r} within {timeout:g} s") from None
        finally:
            subscriber.undeclare()

    def ensure_robot(self, gait: Gait) -> str | None:
        """Make the simulated robot the one ``gait`` describes (a new child when it differs); a message saying what
        changed, or None. On a robot that is not ours to rebuild, ValueError when the module counts differ."""
        if self.robot_gait is None:
            modules = self.read_status().modules
            if modules and modules != gait.robot.modules:
                raise ValueError(f"the robot has {modules} modules; this gait needs {gait.robot.modules}")
            return None
        running = self.robot_gait
        if (gait.robot, gait.ground, gait.limits) == (running.robot, running.ground, running.limits):
            return None
        before = running.robot.modules
        assert self.child is not None
        self.child.stop()
        self.child = RobotChild(self._robot_args(gait), self.child.endpoint)
        return f"simulated robot rebuilt: {before} → {gait.robot.modules} modules"

    @property
    def port(self) -> int:
        return self.app.port if self.app is not None else self.options.port

    def close(self) -> None:
        if self.app is not None:
            self.app.close()
            self.app = None
        if self.node is not None:
            self.node.close()
            self.node = None
        if self.child is not None:
            self.child.stop()
            self.child = None
        if self._gait_file is not None:
            self._gait_file.unlink(missing_ok=True)
            self._gait_file = None


def main(argv: list[str] | None = None) -> int:
    cli = argparse.ArgumentParser(prog="asm-studio", description=__doc__.splitlines()[0] if __doc__ else "")
    cli.add_argument("--gait", type=input_file, default=StudioOptions.gait,
                     help="gait file to open (default: caterpillar)")  # fmt: skip
    where = cli.add_mutually_exclusive_group()
    where.add_argument("--can", type=can_channel, metavar="INTERFACE:CHANNEL", help="a real CAN bus instead of a "
                       "simulated robot, e.g. socketcan:can0 (starts asm-robot --can)")  # fmt: skip
    where.add_argument("--robot", type=zenoh_endpoint, metavar="ENDPOINT", help="attach to a robot process already "
                       "running, e.g. tcp/192.0.2.5:7447 (with --zenoh-config for TLS); starts none")  # fmt: skip
    cli.add_argument("--robot-name", type=name, default="robot",
                     help="the robot's name in its Zenoh keys (default robot)")  # fmt: skip
    cli.add_argument("--bitrate", type=bitrate)
    add_zenoh_arguments(cli, listen_help="more endpoints the robot listens on, for tools elsewhere")
    cli.add_argument("--no-zenoh", action="store_true", help="accepted for compatibility: the robot's Zenoh link "
                     "is on loopback only unless --zenoh-listen says otherwise")  # fmt: skip
    cli.add_argument("--host", default="127.0.0.1", help="address to serve on (default 127.0.0.1, this machine only)")
    cli.add_argument("--port", type=port, default=8080, help="HTTP port (default 8080; 0 picks a free one)")
    cli.add_argument("--view", choices=["preview", "live"], default="preview",
                     help="what the 3D view shows at start (default: the preview of the edited gait)")  # fmt: skip
    cli.add_argument("--c-modules", type=module_selection, metavar="IDS", help="simulated modules that run the C "
                     "runtime (firmware/), in the robot and the preview: IDs as 1,3,5, or odd, even, all")  # fmt: skip
    args = cli.parse_args(argv)
    check_zenoh_arguments(cli, args)
    if args.c_modules and (args.can or args.robot):
        cli.error("--c-modules chooses simulated modules of the studio's own robot: not with --can or --robot")
    return run(cli.prog, lambda: _serve(args))


def _selection_text(selection: tuple[int, ...] | str | None) -> str | None:
    if not selection:
        return None
    return selection if isinstance(selection, str) else ",".join(map(str, selection))


def _serve(args: argparse.Namespace) -> int:
    prefer_latency()
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s")
    options = StudioOptions(gait=args.gait, can=args.can, robot=args.robot, robot_name=args.robot_name,
                            bitrate=args.bitrate, zenoh_listen=tuple(args.zenoh_listen),
                            zenoh_connect=tuple(args.zenoh_connect), zenoh_config=args.zenoh_config,
                            insecure=args.insecure, host=args.host, port=args.port, view=args.view,
                            c_modules=_selection_text(args.c_modules))  # fmt: skip
    done = stop_requested()
    studio = Studio(options)  # a bad gait file, a busy port, no robot: asm-studio: error: … (asm_py.cli.run)
    where = "simulated robot" if studio.simulated else f"robot {args.robot or args.can}"
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
