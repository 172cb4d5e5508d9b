"""``asm-robot``: one process that is the robot, reached over Zenoh like a real robot's computer.

Simulated (``--sim FILE``, the default: a gait file, whose robot is built): the robot's MuJoCo world stepped in
real time (paced to the wall clock), one module runtime per module whose joint driver is that module's actuator,
joint sensor and contact sensor in the physics (torque limited by the actuator, limp when ``servo.service`` stops,
holding on e-stop), the modules as ASM nodes on an in-process CAN bus that filters like CAN controllers
(``asm_sim``), and the CAN↔Zenoh bridge. It publishes its body poses at up to 60 Hz and its status once a second
(asm_module/feed.py, docs/protocol.md §10), with its real-time factor; when it cannot keep up it says so in the status
and in its log.

Real (``--can INTERFACE:CHANNEL``): no physics, only the bridge for the modules on that bus, and the status.

Started by ``asm-studio`` as a child process (``--parent-pid``): it ends when its parent does, even one killed with
SIGKILL (the kernel's parent-death signal, and a watch on the parent's process ID).
"""

from __future__ import annotations

import argparse
import ctypes
import ipaddress
import logging
import os
import signal
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from asm_module.board_batch import BoardBatch
from asm_module.feed import PoseFrame, RobotStatus, encode_poses
from asm_module.names import module_name
from asm_py.cli import (
    add_bus_arguments,
    can_channel,
    close_and_exit,
    input_file,
    module_selection,
    name,
    run,
    stop_requested,
    summary,
)
from asm_py.keys import DEFAULT_ROBOT
from asm_py.node import Node
from asm_py.transport.can import CanTransport
from gaits.model import LIBRARY, load
from gaits.sim import Simulation, select_modules
from gaits.terrain import FLAT, Terrain
from gaits.terrain import argument as terrain_argument

from .bridge import CanZenohBridge
from .commission_service import CommissionService
from .foxglove_live import FoxgloveLive
from .realtime import prefer_latency
from .rest import CHECK, REST_TICK, Rest
from .robot_feed import RobotFeed, RobotNameTaken
from .zenoh_args import ZenohOptions, add_zenoh_arguments, zenoh_options

log = logging.getLogger("asm_robot")
POSE_RATE = 60.0
MAX_LAG = 0.25
"""Seconds the simulation may fall behind the wall clock before it gives the time up (and says it is behind)."""


@dataclass
class RobotOptions:
    sim: Path | None = LIBRARY / "caterpillar.toml"
    """The gait file whose robot is simulated; None with ``can``."""
    can: dict[str, Any] | None = None
    """python-can options of a real bus."""
    name: str = DEFAULT_ROBOT
    """The robot's name: its namespace on the Zenoh network (asm_py.keys)."""
    network: ZenohOptions = field(default_factory=ZenohOptions)
    heartbeat_period: float = 0.5
    pose_rate: float = POSE_RATE
    node_id: int = 254
    """The bridge's own CAN node ID on the bus."""
    c_modules: tuple[int, ...] | str = ()
    """Simulated modules that run the C runtime (firmware/) instead of the Python one: IDs, or "odd", "even",
    "all"."""
    foxglove: int | None = None
    """Serve the robot to Foxglove over its WebSocket protocol on this port (0: a free one); None: no server."""
    foxglove_host: str = "127.0.0.1"
    terrain: Terrain = FLAT
    """The ground a simulated robot stands on (gaits.terrain): try a gait on the floor it will meet."""
    emulated_modules: tuple[int, ...] | str = ()
    """Simulated modules that run the board image (firmware/port/stm32f4_bxcan.c) in the emulator
    (asm_module.emulated): IDs, or "odd", "even", "all"."""
    board_flash: Path | None = None
    """Keep the emulated boards' flash and serials in this folder (asm_module.board_batch): new boards boot
    unconfigured, to be numbered (the commissioning service), and keep their IDs across restarts. None: each is
    flashed with its chain position as its ID, in memory (a batch numbered at the probe)."""


class RealTimeLoop:
    """Steps a Simulation at the wall clock's pace on its own thread and publishes what viewers need."""

    def __init__(self, sim: Simulation, feed: RobotFeed, pose_rate: float) -> None:
        self.sim = sim
        self.feed = feed
        self.status = feed.status
        self.pose_rate = pose_rate
        self.frames = 0
        self.rest = Rest(sim)
        self.resting = False
        """The robot stands still and the physics steps only every REST_TICK (server.rest)."""
        self.given_up = 0.0
        """Simulated seconds given up so far to keep up with the wall clock (each time more than MAX_LAG behind)."""
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="asm-robot-physics", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        sim = self.sim
        timestep = sim.model.opt.timestep
        wall0, sim0 = time.monotonic(), sim.data.time
        window_wall, window_sim = wall0, sim0
        next_pose = wall0
        posed = -1.0  # the simulated time of the last pose frame sent
        rest_tick = wall0  # when a resting robot steps its next period
        while not self._stop.is_set():
            now = time.monotonic()
            target = sim0 + (now - wall0)
            if target - sim.data.time > MAX_LAG:  # cannot keep up: give the time up rather than spiral
                self.given_up += target - sim.data.time
                wall0, sim0 = now, sim.data.time
                target = sim.data.time
                self._behind(True)
            moved = True
            try:
                if self.resting and (self.rest.disturbed() or not self.rest.still()):
                    self.resting = False  # woken: stepped from here on as usual
                elif not self.resting and self.rest.still():
                    if sim.steps_to_tick() != sim.steps_per_tick:
                        sim.step_tick()  # to the period's end (a little ahead of the wall clock): rest on the grid
                    self.resting = True
                    rest_tick = now + REST_TICK
                    self.rest.begin()
                if self.resting:  # time kept within a period of the wall clock; the modules tick every REST_TICK
                    periods = int((target - sim.data.time) / (sim.steps_per_tick * timestep) + 1e-6)
                    moved = periods > 0 and now >= rest_tick
                    if moved:
                        rest_tick = now + REST_TICK
                    sim.skip_periods(periods, tick=moved)
                else:  # to the wall clock by physics steps, not whole ticks: each 60 Hz pose frame is a new pose
                    steps = int((target - sim.data.time) / timestep + 1e-6)
                    if steps > 0:
                        sim.step_physics(steps)
            except Exception as exc:  # a diverged model, a stalled module: say so, and stop stepping
                log.error("the simulation stopped: %s", exc)
                self.status.behind = True
                return
            if now >= next_pose and sim.data.time > posed and moved:  # a frame per new pose: never a repeated one
                next_pose = max(next_pose + 1.0 / self.pose_rate, now)
                posed = sim.data.time
                self._send_poses()
            if now - window_wall >= 1.0:
                self.status.real_time_factor = round((sim.data.time - window_sim) / (now - window_wall), 3)
                if self.status.real_time_factor > 0.95 and self.status.behind:
                    self._behind(False)
                self.status.time = sim.data.time
                self.status.estop = sim.latched()
                self.feed.publish_status()
                window_wall, window_sim = now, sim.data.time
            if self.resting:
                self._stop.wait(CHECK)
                continue
            next_tick = sim.data.time + sim.steps_to_tick() * timestep  # a module tick is due then
            pose_due = next_pose if sim.data.time > posed else max(next_pose, wall0 + (sim.data.time + timestep - sim0))
            due = min(pose_due, wall0 + (next_tick - sim0))
            self._stop.wait(max(0.0, due - time.monotonic()))

    def _behind(self, behind: bool) -> None:
        if behind != self.status.behind:
            self.status.behind = behind
            if behind:
                log.warning("the simulation cannot keep up with real time (real-time factor %.2f)",
                            self.status.real_time_factor or 0.0)  # fmt: skip
            self.feed.publish_status()

    def _send_poses(self) -> None:
        sim = self.sim
        with sim.lock:
            frame = PoseFrame(self.frames, sim.data.time, sim.data.xpos[1:].copy(), sim.data.xquat[1:].copy())
        self.frames += 1
        self.feed.publish_poses(encode_poses(frame))

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=10)


class Robot:
    """The robot process's parts; see the module docstring. ``close`` stops all of them."""

    def __init__(self, options: RobotOptions, on_name_lost: Callable[[str], None] | None = None) -> None:
        """``on_name_lost(session)``: another robot process of this name kept it too and this one gave way (its feed
        withdrawn: server.robot_feed); asm-robot then ends."""
        self.options = options
        self.sim: Simulation | None = None
        self.bridge: CanZenohBridge | None = None
        self.feed: RobotFeed | None = None
        self.loop: RealTimeLoop | None = None
        self.foxglove: FoxgloveLive | None = None
        self.commission: CommissionService | None = None
        self._stop = threading.Event()
        self._status_timer: threading.Thread | None = None
        try:
            if options.can is None:
                gait = load(options.sim or LIBRARY / "caterpillar.toml")
                channel = f"asm-robot-{os.getpid()}-{id(self)}"
                can_options: dict[str, Any] = {"interface": "asm_sim", "channel": channel}

                def node_of(module_id: int) -> Node:
                    # no reader thread per module: the channel's dispatch thread hands each its frames (issue 31)
                    transport = CanTransport(module_id, heartbeat_period=options.heartbeat_period, watch_bus=False,
                                             receive_thread=False, **can_options)  # fmt: skip
                    return Node(module_name(module_id), transport)

                boards = BoardBatch(options.board_flash) if options.board_flash is not None else None
                self.sim = Simulation(gait, node_of=node_of, c_modules=select_modules(options.c_modules, gait),
                                      emulated_modules=select_modules(options.emulated_modules, gait),
                                      bus_options=can_options, terrain=options.terrain,
                                      board_flash=boards)  # fmt: skip
            else:
                can_options = dict(options.can)
            self.bridge = CanZenohBridge({**can_options, "heartbeat_period": options.heartbeat_period},
                                         robot=options.name, network=options.network,
                                         node_id=options.node_id)  # fmt: skip
            modules = self.sim.gait.robot.modules if self.sim is not None else 0
            self.status = RobotStatus(options.name, "simulated" if self.sim else "real", modules,
                                      estop=[] if self.sim else None)  # fmt: skip
            sim, bridge = self.sim, self.bridge

            def refresh(status: RobotStatus) -> None:
                status.traffic = dict(bridge.forwarded)
                if sim is not None:
                    status.estop = sim.latched()
                commission = getattr(self, "commission", None)  # made just after the feed
                status.commissioning_stopped = commission is not None and commission.stopped()

            self.feed = RobotFeed(self.bridge.session, self.status, sim.mjcf if sim else None, refresh,
                                  on_lost=on_name_lost)  # fmt: skip
            self.feed.publish_status()
            self._check_name()
            self.commission = CommissionService(self.bridge.session, options.name, can_options, self.bridge.node,
                                                tool_id=options.node_id,
                                                reserved=self.bridge.clients.alias_pool)  # fmt: skip
            if options.foxglove is not None:
                self.foxglove = FoxgloveLive(self.bridge.session, options.name, options.foxglove, self.mjcf,
                                             options.foxglove_host)  # fmt: skip
            if self.sim is not None:
                self.loop = RealTimeLoop(self.sim, self.feed, options.pose_rate)
            self._status_timer = threading.Thread(target=self._report, name="asm-robot-status", daemon=True)
            self._status_timer.start()
            if self.sim is not None:
                self._await_bridged(len(self._node_ids()))
            self._check_name()  # not READY under a name another process kept meanwhile
        except BaseException:
            self.close()
            raise

    def _check_name(self) -> None:
        """RobotNameTaken if the feed gave the robot's name way (another process of the name kept it too)."""
        if self.feed is not None and self.feed.lost is not None:
            raise RobotNameTaken(f"another robot process named {self.options.name!r} kept the name too (session "
                                 f"{self.feed.lost}): this one gives way")  # fmt: skip

    def _node_ids(self) -> set[int]:
        """The node IDs the simulated modules run under, each once: a board without an ID yet is not on the bus as a
        module, and two boards flashed with one ID are one node to the bridge (the commissioning service reports the
        clash). Counting modules instead, a robot with such a pair waited the whole timeout, then warned."""
        from asm_module.emulated import EmulatedModule  # here: Unicorn is loaded only when a board is emulated

        assert self.sim is not None
        ids: set[int] = set()
        for position, module in self.sim.modules.items():
            if not isinstance(module, EmulatedModule):
                ids.add(position)
            elif module.configured:
                ids.add(module.commissioned_id())
        return ids

    def _await_bridged(self, modules: int, timeout: float = 15.0) -> None:
        """Wait until the simulated modules are on Zenoh (so "READY" means a tool can reach every one); a robot
        that takes longer says so and goes on (the bridge keeps trying)."""
        deadline = time.monotonic() + timeout
        assert self.bridge is not None
        while len(self.bridge.bridged) < modules:
            if time.monotonic() > deadline:
                log.warning("only %d of %d modules are bridged after %g s", len(self.bridge.bridged), modules, timeout)
                return
            time.sleep(0.02)

    @property
    def mjcf(self) -> str | None:
        return self.sim.mjcf if self.sim is not None else None

    def _report(self) -> None:
        """What the bridge knows, in the status: a real robot's modules once a second, and on both kinds the tables
        not read yet (published at once when that changes)."""
        while not self._stop.wait(0.25):
            bridge, feed = self.bridge, self.feed
            if bridge is None or feed is None:
                return
            unread = bridge.unread_tables
            changed = unread != self.status.unread_tables
            self.status.unread_tables = unread
            if self.sim is None:
                modules = len(bridge.bridged)
                changed |= modules != self.status.modules
                self.status.modules = modules
            if changed or (self.sim is None and time.monotonic() % 1.0 < 0.25):
                feed.publish_status()

    def close(self) -> None:
        if self.commission is not None:
            self.commission.close()
            self.commission = None
        if self.loop is not None:
            self.loop.close()
            self.loop = None
        if self.foxglove is not None:
            self.foxglove.close()
            self.foxglove = None
        self._stop.set()
        if self._status_timer is not None:
            self._status_timer.join(5)
            self._status_timer = None
        if self.feed is not None:
            self.feed.close()
            self.feed = None
        if self.bridge is not None:
            self.bridge.close()
            self.bridge = None
        if self.sim is not None:
            self.sim.close()
            self.sim = None


ORPHAN_GRACE = 5.0
"""Seconds an orphaned robot process gets to close in order before it exits anyway."""


def die_with_parent(parent: int) -> None:
    """End this process when process ``parent`` ends, however it ends (SIGKILL included)."""
    try:  # Linux: the kernel sends SIGTERM when the parent thread dies
        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass
    if os.getppid() != parent:  # the parent died before the line above
        os.kill(os.getpid(), signal.SIGTERM)

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(0.5)
        os.kill(os.getpid(), signal.SIGTERM)  # an orderly close: modules stopped, sessions closed
        time.sleep(ORPHAN_GRACE)
        os._exit(1)  # a robot whose operator is gone must not linger, even if closing hangs

    threading.Thread(target=watch, name="parent-watch", daemon=True).start()


def ws_url(host: str, port: int) -> str:
    """The WebSocket URL a Foxglove user pastes: an IPv6 address in brackets (RFC 3986; ``ws://::1:8765`` is not
    a URL)."""
    return f"ws://[{host}]:{port}" if ":" in host else f"ws://{host}:{port}"


def main(argv: list[str] | None = None) -> int:
    cli = argparse.ArgumentParser(prog="asm-robot", description=summary(__doc__))
    where = cli.add_mutually_exclusive_group()
    where.add_argument("--sim", type=input_file, metavar="FILE", help="simulate the robot of this gait file (default: "
                       "the caterpillar)")  # fmt: skip
    where.add_argument("--can", type=can_channel, metavar="INTERFACE:CHANNEL", help="a real bus: bridge its modules")
    add_bus_arguments(cli)
    cli.add_argument(
        "--name", type=name, default=DEFAULT_ROBOT, help="the robot's namespace on Zenoh, unique there (default robot)"
    )
    add_zenoh_arguments(cli)
    cli.add_argument(
        "--c-modules",
        type=module_selection,
        default=(),
        metavar="IDS",
        help="simulated modules that run the C runtime (firmware/): IDs as 1,3,5, or odd, even, all",
    )
    cli.add_argument("--foxglove", type=int, metavar="PORT", help="serve the robot to Foxglove (WebSocket "
                     "protocol) on this port; 0 picks a free one, printed on the ready line")  # fmt: skip
    cli.add_argument(
        "--foxglove-host",
        default="127.0.0.1",
        metavar="HOST",
        help="where the Foxglove server "
        "listens (default 127.0.0.1; beyond loopback only with --insecure: it has no authentication)",
    )
    cli.add_argument("--terrain", type=terrain_argument, default=FLAT, metavar="SPEC",
                     help="the simulated ground: flat (default), slope:DEG, step:HEIGHT, rough:seed=N,roughness=M, "
                     "patches:friction=MU")  # fmt: skip
    cli.add_argument(
        "--emulated-modules",
        type=module_selection,
        default=(),
        metavar="IDS",
        help="simulated modules that run the STM32F4 board image in an instruction-level emulator: IDs or odd, even, "
        "all (needs arm-none-eabi-gcc)",
    )
    cli.add_argument("--board-flash", type=Path, metavar="DIR", help="keep the emulated boards' flash and serials "
                     "in DIR, one pair of files per chain position: new boards boot with no node ID, to be numbered "
                     "(the studio's Modules tab, the commissioning service), and keep their IDs across restarts "
                     "(default: each flashed with its chain position as ID, nothing kept)")  # fmt: skip
    cli.add_argument("--parent-pid", type=int, help=argparse.SUPPRESS)
    args = cli.parse_args(argv)
    if args.fd and args.can is None:
        cli.error("--fd describes a real bus: use it with --can")
    if args.c_modules and args.can is not None:
        cli.error("--c-modules chooses simulated modules: use it with --sim")
    if args.foxglove is not None and not 0 <= args.foxglove <= 65535:
        cli.error("--foxglove takes a port, 0-65535 (0: a free one)")
    if not _loopback(args.foxglove_host) and not args.insecure:
        cli.error(f"--foxglove-host {args.foxglove_host} is beyond loopback: the Foxglove server has no "
                  "authentication (add --insecure to serve it anyway)")  # fmt: skip
    if args.terrain != FLAT and args.can is not None:
        cli.error("--terrain is the simulated ground: use it with --sim")
    if args.emulated_modules and args.can is not None:
        cli.error("--emulated-modules chooses simulated modules: use it with --sim")
    if args.board_flash is not None and not args.emulated_modules:
        cli.error("--board-flash keeps emulated boards' flash: use it with --emulated-modules")
    if args.board_flash is not None and args.board_flash.exists() and not args.board_flash.is_dir():
        cli.error(f"--board-flash {args.board_flash}: not a folder")
    network = zenoh_options(cli, args)
    return run(cli.prog, lambda: _serve(args, network))


def _loopback(host: str) -> bool:
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return host == "localhost"


def _serve(args: argparse.Namespace, network: ZenohOptions) -> int:
    if args.parent_pid:
        die_with_parent(args.parent_pid)
    prefer_latency()
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s")
    can_options = None if args.can is None else {**args.can, "fd": args.fd,
                                                 **({"bitrate": args.bitrate} if args.bitrate else {})}  # fmt: skip
    options = RobotOptions(sim=None if args.can else (args.sim or RobotOptions.sim), can=can_options, name=args.name,
                           network=network, node_id=args.node_id, c_modules=args.c_modules,
                           foxglove=args.foxglove, foxglove_host=args.foxglove_host,
                           terrain=args.terrain, emulated_modules=args.emulated_modules,
                           board_flash=args.board_flash)  # fmt: skip
    done = stop_requested()
    lost: list[str] = []

    def name_lost(rival: str) -> None:  # on the feed's Zenoh thread: only say it and ask for the stop
        lost.append(rival)
        print(f"asm-robot: another robot process named {args.name!r} kept the name too (session {rival}; their "
              "tokens met late): this one gives way and ends", file=sys.stderr, flush=True)  # fmt: skip
        done.set()

    robot = Robot(options, on_name_lost=name_lost)  # a bad gait file, a busy port, a taken name: asm-robot: error: …
    kind = "simulated" if robot.sim is not None else f"CAN {args.can}"
    live = f"; foxglove {ws_url(args.foxglove_host, robot.foxglove.port)}" if robot.foxglove is not None else ""
    print(f"READY robot {args.name} ({kind}, {robot.status.modules} modules){live}", flush=True)
    done.wait()
    close_and_exit(robot.close, "asm-robot", code=1 if lost else 0)


if __name__ == "__main__":
    raise SystemExit(main())
