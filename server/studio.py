"""``asm-studio``: the dashboard, as a client of robots — one command for everything.

By default the studio starts a simulated robot, ``asm-robot --sim GAIT --name robot`` (server/robot.py: the opened
gait's robot in real-time MuJoCo physics, its modules on a CAN bus, the CAN↔Zenoh bridge), as a child process on a
private loopback Zenoh link, and serves the page at http://127.0.0.1:8080. The child ends with the studio, even when
the studio is killed; should the child die, the studio says so at once and starts it again. ``--can
INTERFACE:CHANNEL`` starts ``asm-robot --can`` for a real bus instead; ``--robot ENDPOINT`` joins a Zenoh network
(a router, or a robot's own endpoint) and starts nothing.

On a network the studio lists every robot (its name, simulated or real, module count, real-time factor, e-stop),
attaches to one — ``--robot-name``, else its own, else the only one, else the first — and switches between them from
the page. It is a *tool* of the robot it is attached to (asm_py.keys): node ``studio``, or ``studio-2``, … when
another studio already watches that robot; ``--name`` insists on one name, and the studio refuses to start when it
is taken. It reaches the modules only through ASM, like any tool; it hosts no module runtime.
"""

from __future__ import annotations

import argparse
import logging
import os
import tempfile
import threading
from collections.abc import Callable, Collection
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import zenoh

from asm_module.feed import RobotStatus, read_statuses
from asm_py import Node
from asm_py.cli import (
    bitrate,
    can_channel,
    close_and_exit,
    frame_rate,
    input_file,
    module_selection,
    name,
    port,
    run,
    stop_requested,
    summary,
    zenoh_endpoint,
)
from asm_py.keys import DEFAULT_ROBOT
from asm_py.transport.zenoh import NameTaken
from gaits.model import LIBRARY, Gait, dumps, loads
from gaits.terrain import FLAT, Terrain
from gaits.validate import read

from .child import RobotChild, free_port
from .realtime import prefer_latency
from .studio_record import StudioRecording
from .zenoh_args import ZenohOptions, add_zenoh_arguments, zenoh_options

LAYOUT_FILE = "studio-layout.json"
"""The page's last layout in the recordings directory unless ``--layout`` says elsewhere (web/layout_store.py keeps
it; the backend names the path)."""

log = logging.getLogger("asm_studio")
STUDIO_NAME = "studio"
FIND_ROBOT_TIMEOUT = 10.0


@dataclass
class StudioOptions:
    gait: Path = LIBRARY / "caterpillar.toml"
    """The gait opened at start; a simulated robot is built from its robot."""
    can: dict[str, Any] | None = None
    """python-can options of a real bus (``asm-robot --can``); None: a simulated robot."""
    robot: str | None = None
    """A Zenoh endpoint (a router, or a robot process): join that network, start no robot."""
    robot_name: str | None = None
    """The robot to attach to (and the name of the studio's own robot, default ``robot``)."""
    name: str | None = None
    """The studio's node name; None: ``studio``, or the first of ``studio-2``, ``studio-3``, … that is free."""
    bitrate: int | None = None
    network: ZenohOptions = field(default_factory=ZenohOptions)
    """The Zenoh options: with ``robot``, the studio's own; else its robot's (more endpoints, a router, TLS)."""
    host: str = "127.0.0.1"
    port: int = 8080
    view: str = "preview"
    """What the 3D view shows at start: "preview" (the edited gait) or "live" (the robot)."""
    token: str | None = None
    """The page's access token; None: none on loopback, a new random one when served beyond it."""
    c_modules: str | None = None
    """Simulated modules that run the C runtime (``asm-robot --c-modules``): "odd", "even", "all" or "1,3,5"."""
    emulated_modules: str | None = None
    """Simulated modules that run the board image in the emulator (``asm-robot --emulated-modules``), in the robot
    only: the preview runs the same modules as Python (the emulator runs in real time, not as fast as a preview)."""
    board_flash: Path | None = None
    """Where the emulated boards keep their flash (``asm-robot --board-flash``): a fresh batch with no IDs the first
    time, numbered on the Modules tab, kept across the robot's restarts. None: flashed with their chain positions
    as IDs, nothing kept. ``asm-studio`` keeps them in ``<recordings>/boards`` unless told ``--board-flash``."""
    recordings: Path = Path("recordings")
    """Where the page's Record button writes its MCAP files."""
    layout: Path | None = None
    """Where the page keeps its last layout across restarts (web/layout_store.py); None: nowhere. ``asm-studio``
    keeps it in ``<recordings>/studio-layout.json`` unless told ``--layout``."""
    max_fps: float | None = None
    """Frames a second the 3D view is drawn and sent at most, and the page's own frame cap (``--max-fps``, for a
    browser without a GPU); None: as many as the robot moves (60)."""


def layout_file(text: str) -> Path:
    """``--layout``: a file's name, not a directory's (the studio writes a file beside it and renames it over it: a
    directory left a stray ``DIR.tmp`` and kept nothing). A file there that is not a layout is refused later, with
    the reason, and never written over (web/layout_store.py)."""
    if not text:
        raise argparse.ArgumentTypeError("an empty file name")
    path = Path(text)
    if path.is_dir():
        raise argparse.ArgumentTypeError(f"{text} is a directory, not a file name")
    return path


def free_loopback_port(avoid: Collection[int] = ()) -> int:
    """A TCP port free on 127.0.0.1 now (bound and released: the child binds it a moment later), none of
    ``avoid``: the studio's own web port, which it binds only after starting its robot (a port a test had just
    bound and released to pass as --port came back here, the robot took it, and the page could not start)."""
    for _ in range(16):
        port = free_port()
        if port not in avoid:
            return port
    raise OSError("no free loopback port apart from the studio's own")


class Studio:
    """The backend: the robots (a child process of its own, or a network's), the page's links and the web app."""

    def __init__(self, options: StudioOptions) -> None:
        self.options = options
        self.c_modules = options.c_modules
        raw = read(options.gait)  # once: the gait, and its text for a download that keeps its comments
        self.gait: Gait = loads(raw, source=str(options.gait), path=options.gait)
        self.gait_text: str | None = raw.decode("utf-8-sig")  # it decoded as the gait above
        self.gait_path: Path | None = options.gait
        self.child: RobotChild | None = None
        self.own_robot: str | None = None
        """The name of the robot this studio started (and restarts should it die); None when attached."""
        self.robot_gait: Gait | None = None
        self.robot_terrain: Terrain = FLAT
        """The ground the simulated robot stands on (the preview's, taken at a deploy)."""
        """The gait whose robot the simulated child runs (None when the robot is not ours to rebuild)."""
        self.session: zenoh.Session | None = None
        self.app: Any = None
        self.token: str | None = None
        self._gait_file: Path | None = None
        self._gait_fd: int | None = None
        """The robot child's gait while it starts (``_gait_for_child``): a file, or a file in memory."""
        self._child_endpoint: str | None = None
        self._notices: list[Callable[[str, str, bool], None]] = []
        self._stop = threading.Event()
        self._child_lock = threading.Lock()
        self._watcher: threading.Thread | None = None
        self._link: Any = None
        self.recording: StudioRecording | None = None
        self.layout_file: Path | None = options.layout
        """The page's last layout, restored when the studio starts again (web/layout_store.py)."""
        try:
            self.network = self._start_robot(self.gait) if options.robot is None else self._join(options.robot)
            self.session = self.network.open()
            self.recording = StudioRecording(self.session, options.recordings)
            robot = options.robot_name or self.own_robot or self._find_robot()
            from web.app import Dashboard  # viser loads only for the studio
            from web.guard import is_loopback, new_token

            self._link = self.connect(robot)  # the page's, once it is built; closed here if it cannot be
            self.status = self._wait_status(self._link.feed, timeout=10.0)
            self.token = options.token or (None if is_loopback(options.host) else new_token())
            self.app = Dashboard(
                self, self._link, host=options.host, port=options.port, token=self.token, max_fps=options.max_fps
            )
            self._link = None
            self.app.show(options.view)
            if self.child is not None:
                self._watcher = threading.Thread(target=self._watch_child, name="studio-robot-watch", daemon=True)
                self._watcher.start()
        except BaseException:
            self.close()
            raise

    # -- the robots -----------------------------------------------------------------------------------------------

    def _join(self, endpoint: str) -> ZenohOptions:
        network = self.options.network
        return network if endpoint in network.connect else network.with_(connect=(endpoint, *network.connect))

    def _robot_args(self, gait: Gait) -> list[str]:
        options = self.options
        args = ["--name", self.own_robot or DEFAULT_ROBOT]
        if options.can is not None:
            args += ["--can", f"{options.can['interface']}:{options.can['channel']}"]
            if options.bitrate:
                args += ["--bitrate", str(options.bitrate)]
        else:
            args += ["--sim", self._gait_for_child(gait)]
            if options.c_modules:
                args += ["--c-modules", options.c_modules]
            if options.emulated_modules:
                args += ["--emulated-modules", options.emulated_modules]
                if options.board_flash is not None:
                    args += ["--board-flash", str(options.board_flash)]
            if self.robot_terrain != FLAT:
                args += ["--terrain", self.robot_terrain.spec]
            self.robot_gait = gait
        network = options.network
        if network.mode == "peer":  # a private loopback endpoint for this studio, beside any the user gave
            assert self._child_endpoint is not None
            network = network.with_(listen=(self._child_endpoint, *network.listen))
        return args + network.args()

    def _gait_for_child(self, gait: Gait) -> str:
        """Where the robot child reads ``gait`` (its robot inline: no robot file beside it). On Linux, a file in
        memory (memfd) that the child inherits: nothing on disk, so a studio killed at any moment, even while its
        robot starts, leaves nothing behind. Elsewhere, or where the call is refused, a temporary file, removed once
        the child is up."""
        text = dumps(gait, inline=True).encode("utf-8")
        try:  # close-on-exec (the default): only the robot child is given it (pass_fds), no other child inherits it
            self._gait_fd = os.memfd_create("asm-studio-robot.toml")
            os.write(self._gait_fd, text)
            return f"/dev/fd/{self._gait_fd}"
        except (AttributeError, OSError):  # no memfd here (not Linux, or a sandbox refusing the call: ENOSYS, EPERM)
            self._forget_gait_for_child()
        handle, path = tempfile.mkstemp(prefix="asm-studio-robot-", suffix=".toml")
        os.close(handle)
        self._gait_file = Path(path)
        self._gait_file.write_bytes(text)
        return path

    def _forget_gait_for_child(self) -> None:
        if self._gait_fd is not None:
            os.close(self._gait_fd)
            self._gait_fd = None
        if self._gait_file is not None:
            self._gait_file.unlink(missing_ok=True)
            self._gait_file = None

    def _spawn_robot(self, gait: Gait) -> RobotChild:
        """The robot child for ``gait``, up. It reads its gait once, at start; a restart writes it anew."""
        try:
            args = self._robot_args(gait)
            return RobotChild(args, pass_fds=() if self._gait_fd is None else (self._gait_fd,))
        finally:
            self._forget_gait_for_child()

    def _start_robot(self, gait: Gait) -> ZenohOptions:
        """Start the studio's own robot; the Zenoh options that reach it."""
        self.own_robot = self.options.robot_name or DEFAULT_ROBOT
        network = self.options.network
        if network.mode == "peer":
            ours = {
                self.options.port,
                *(int(e.rsplit(":", 1)[1]) for e in network.listen if e.rsplit(":", 1)[-1].isdigit()),
            }
            self._child_endpoint = f"tcp/127.0.0.1:{free_loopback_port(avoid=ours)}"
            network = network.with_(listen=(), connect=(self._child_endpoint, *network.connect))
        self.child = self._spawn_robot(gait)
        return network

    def robots(self, timeout: float = 1.0) -> list[RobotStatus]:
        """The robots on the network, by name, as their processes answer now."""
        assert self.session is not None
        found = read_statuses(self.session, timeout=timeout)
        return [found[n] for n in sorted(found)]

    def _find_robot(self) -> str:
        """The robot to attach to when none was named: the only one on the network, else the first by name."""
        deadline = threading.Event()
        for _ in range(int(FIND_ROBOT_TIMEOUT / 0.5)):
            robots = self.robots()
            if robots:
                return robots[0].robot
            deadline.wait(0.5)
        raise RuntimeError(f"no robot answered on this network within {FIND_ROBOT_TIMEOUT:g} s")

    def connect(self, robot: str) -> Any:
        """A new link to robot ``robot``: the page's own node, a tool of that robot (web/link.py)."""
        from web.link import RobotLink

        names = [self.options.name] if self.options.name else [STUDIO_NAME, *(f"{STUDIO_NAME}-{k}" for k in
                                                                              range(2, 100))]  # fmt: skip
        for candidate in names:
            try:
                node = Node(candidate, self.network.transport(robot=robot, role="tool"))
            except NameTaken:
                if self.options.name:
                    raise
                continue
            return RobotLink(node)
        raise RuntimeError(f"no free studio name in robot {robot!r}")

    @staticmethod
    def _wait_status(feed: Any, timeout: float) -> RobotStatus:
        waited = threading.Event()
        for _ in range(int(timeout / 0.05)):
            if feed.status is not None:
                return feed.status
            waited.wait(0.05)
        raise RuntimeError(f"no status from robot {feed.name!r} within {timeout:g} s")

    def on_notice(self, callback: Callable[[str, str, bool], None]) -> None:
        """Call ``callback(title, text, error)`` with what the backend has to say (its robot died, restarted)."""
        self._notices.append(callback)

    def _notice(self, title: str, text: str, error: bool = False) -> None:
        log.warning("%s: %s", title, text) if error else log.info("%s: %s", title, text)
        for callback in list(self._notices):
            try:
                callback(title, text, error)
            except Exception:
                log.exception("a notice could not be shown")

    def _watch_child(self) -> None:
        """Start the studio's own robot again should it die (a notice at once, and when it is back)."""
        while not self._stop.wait(0.1):
            with self._child_lock:
                child = self.child
                code = child.exit_code() if child is not None else None
                if child is None or code is None:
                    continue
                tail = "".join(child.output[-3:]).strip().replace("\n", " / ")
                self._notice("Robot lost", f"the simulated robot process ended (exit code {code}); restarting it"
                             + (f" — its last words: {tail[-200:]}" if tail else ""), True)  # fmt: skip
                try:
                    gait = self.robot_gait  # a simulated robot's gait file went once it was up: written anew
                    self.child = self._spawn_robot(gait) if gait is not None else RobotChild(child.args)
                except Exception as exc:
                    self.child = None
                    self._notice("Robot lost", f"the simulated robot could not be restarted: {exc}", True)
                    return
            self._notice("Robot restarted", "the simulated robot is back, its modules at rest (no gait runs): "
                         "deploy a gait to run one")  # fmt: skip

    def ensure_robot(self, gait: Gait, terrain: Terrain = FLAT) -> str | None:
        """Make the simulated robot the one ``gait`` describes, on ``terrain`` (the preview's ground: a new child
        when either differs); a message saying what changed, or None. On a robot that is not ours to rebuild,
        ValueError when the module counts differ."""
        running = self.robot_gait
        if running is None or self.app is None or self.app.link.robot != self.own_robot:
            status = self.app.link.status if self.app is not None else None
            modules = status.modules if status is not None else 0
            if modules and modules != gait.robot.modules:
                raise ValueError(f"the robot has {modules} modules; this gait needs {gait.robot.modules}")
            return None
        same = (gait.robot, gait.ground, gait.limits) == (running.robot, running.ground, running.limits)
        if same and terrain == self.robot_terrain:
            return None
        before, ground = running.robot.modules, self.robot_terrain
        with self._child_lock:
            assert self.child is not None
            self.child.stop()
            self.robot_terrain = terrain
            self.child = self._spawn_robot(gait)
        if same:
            return f"simulated robot rebuilt on {terrain.spec} (was {ground.spec})"
        return f"simulated robot rebuilt: {before} → {gait.robot.modules} modules on {terrain.spec}"

    @property
    def simulated(self) -> bool:
        status = self.app.link.status if self.app is not None else self.status
        return status is not None and status.mode == "simulated"

    @property
    def recordings_folder(self) -> Path:
        return self.options.recordings

    def start_recording(self, robot: str, gait_name: str, gait_text: str, said: Callable[[str, bool], None]) -> None:
        if self.recording is None:
            raise RuntimeError("the studio is closing: nothing can be recorded")
        self.recording.request_start(robot, gait_name, gait_text, said)

    def stop_recording(self, said: Callable[[str, bool], None]) -> None:
        if self.recording is not None:
            self.recording.request_stop(said)

    @property
    def port(self) -> int:
        return self.app.port if self.app is not None else self.options.port

    def close(self) -> None:
        self._stop.set()
        if self._watcher is not None:
            self._watcher.join(5)
        if self.app is not None:
            self.app.close()
            self.app = None
        if self._link is not None:
            self._link.close()
            self._link = None
        if self.recording is not None:  # a recording still running is finished, before its session goes
            self.recording.close()
            self.recording = None
        if self.session is not None:
            self.session.close()
            self.session = None
        with self._child_lock:
            if self.child is not None:
                self.child.stop()
                self.child = None
        self._forget_gait_for_child()


def main(argv: list[str] | None = None) -> int:
    cli = argparse.ArgumentParser(prog="asm-studio", description=summary(__doc__))
    cli.add_argument("--gait", type=input_file, default=StudioOptions.gait,
                     help="gait file to open (default: caterpillar)")  # fmt: skip
    where = cli.add_mutually_exclusive_group()
    where.add_argument("--can", type=can_channel, metavar="INTERFACE:CHANNEL", help="a real CAN bus instead of a "
                       "simulated robot, e.g. socketcan:can0 (starts asm-robot --can)")  # fmt: skip
    where.add_argument("--robot", type=zenoh_endpoint, metavar="ENDPOINT", help="join the Zenoh network of this "
                       "router or robot, e.g. tcp/192.0.2.5:7447 (TLS: --zenoh-config); starts no robot")  # fmt: skip
    cli.add_argument("--robot-name", type=name, help="the robot to attach to (default: the studio's own, named "
                     "robot; with --robot, the only or first one on the network)")  # fmt: skip
    cli.add_argument("--name", type=name, help="the studio's node name (default studio, or studio-2, … if taken)")
    cli.add_argument("--bitrate", type=bitrate)
    add_zenoh_arguments(cli, listen_help="more endpoints the robot listens on, for tools elsewhere")
    cli.add_argument("--no-zenoh", action="store_true", help="accepted for compatibility: the robot's Zenoh link "
                     "is on loopback only unless --zenoh-listen says otherwise")  # fmt: skip
    cli.add_argument("--host", default="127.0.0.1", help="address to serve on (default 127.0.0.1, this machine only)")
    cli.add_argument("--port", type=port, default=8080, help="HTTP port (default 8080; 0 picks a free one)")
    cli.add_argument("--recordings", type=Path, default=StudioOptions.recordings, metavar="DIR",
                     help="where the page's Record button writes MCAP files (default: recordings)")  # fmt: skip
    cli.add_argument("--replay", type=input_file, metavar="FILE", help="open this MCAP recording in the Replay tab "
                     "at start (the 3D view plays it)")  # fmt: skip
    cli.add_argument("--layout", type=layout_file, metavar="FILE", help="where the page keeps its last layout (the "
                     "live plots and their window), restored when the studio starts again (default: "
                     f"RECORDINGS/{LAYOUT_FILE})")  # fmt: skip
    cli.add_argument("--max-fps", type=frame_rate, metavar="N", help="draw the 3D view at most N frames a second, "
                     "in the studio and in the page (1-60; default 60): a browser without a GPU draws in software, "
                     "and 20 takes about half the CPU (a page's ?maxFps=N overrides it for that page)")  # fmt: skip
    cli.add_argument("--view", choices=["preview", "live"], default="preview",
                     help="what the 3D view shows at start (default: the preview of the edited gait)")  # fmt: skip
    cli.add_argument("--c-modules", type=module_selection, metavar="IDS", help="simulated modules that run the C "
                     "runtime (firmware/), in the robot and the preview: IDs as 1,3,5, or odd, even, all")  # fmt: skip
    cli.add_argument("--emulated-modules", type=module_selection, metavar="IDS", help="simulated modules that run "
                     "the STM32F4 board image in an instruction-level emulator, in the robot (the preview runs them "
                     "as Python): IDs or odd, even, all (needs arm-none-eabi-gcc)")  # fmt: skip
    cli.add_argument("--board-flash", metavar="DIR", help="where the emulated boards keep their flash: a fresh "
                     "batch with no IDs the first time, numbered on the Modules tab (default: RECORDINGS/boards); "
                     "'none': each flashed with its chain position as ID, nothing kept")  # fmt: skip
    args = cli.parse_args(argv)
    if args.robot:  # the network to join is the robot's (or its router's): every session of the studio connects
        args.zenoh_connect = [args.robot, *args.zenoh_connect]
    network = zenoh_options(cli, args)
    if args.c_modules and (args.can or args.robot):
        cli.error("--c-modules chooses simulated modules of the studio's own robot: not with --can or --robot")
    if args.emulated_modules and (args.can or args.robot):
        cli.error("--emulated-modules chooses simulated modules of the studio's own robot: not with --can or --robot")
    if args.layout is None and (args.recordings / LAYOUT_FILE).is_dir():
        cli.error(f"{args.recordings / LAYOUT_FILE} is a directory: the layout file goes there (or give --layout)")
    return run(cli.prog, lambda: _serve(args, network))


def _selection_text(selection: tuple[int, ...] | str | None) -> str | None:
    if not selection:
        return None
    return selection if isinstance(selection, str) else ",".join(map(str, selection))


def _serve(args: argparse.Namespace, network: ZenohOptions) -> int:
    prefer_latency()
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s")
    options = StudioOptions(gait=args.gait, can=args.can, robot=args.robot, robot_name=args.robot_name,
                            name=args.name, bitrate=args.bitrate, network=network, host=args.host, port=args.port,
                            view=args.view, c_modules=_selection_text(args.c_modules),
                            emulated_modules=_selection_text(args.emulated_modules),
                            board_flash=None if args.board_flash == "none" else
                            Path(args.board_flash or args.recordings / "boards"),
                            recordings=args.recordings, max_fps=args.max_fps,
                            layout=args.layout or args.recordings / LAYOUT_FILE)  # fmt: skip
    done = stop_requested()
    studio = Studio(options)  # a bad gait file, a busy port, no robot: asm-studio: error: … (asm_py.cli.run)
    if args.replay is not None:  # read on the Replay tab's thread: a file that cannot be replayed is said there
        studio.app.replay.open_path(args.replay)
    link = studio.app.link
    where = f"simulated robot {link.robot}" if studio.child else f"robot {link.robot} via {args.robot or args.can}"
    query = f"/?token={studio.token}" if studio.token else ""
    print(f"READY studio http://{args.host}:{studio.port}{query} ({where})", flush=True)
    if studio.token:
        print("The page is served beyond this machine: open it with the token above (it is asked once, then kept "
              "in a cookie).", flush=True)  # fmt: skip
    done.wait()
    close_and_exit(studio.close, "asm-studio")


if __name__ == "__main__":
    raise SystemExit(main())
