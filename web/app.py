"""The dashboard: one viser page to edit a gait, preview it in MuJoCo, deploy it to modules and watch them.

Layout: the side panel (docked right) starts with the robot bar — E-STOP, its release, the status line, the robots
of the network and what the 3D view shows (web/robot_bar.py) — then tabs: Gait (web/editor.py), Preview
(web/preview_panel.py), Deploy (web/deploy_panel.py), Drive (web/drive.py), Monitor (web/monitor_panel.py). A
second panel over the 3D view's lower left shows the plots and the gait control table. No dialog ever covers the
E-STOP: confirmations are rows of the panel (web/confirm.py), and Escape presses E-STOP from anywhere
(web/page_script.py).

Everything the page does to a robot goes through its link (web/link.py), which the page swaps when the user picks
another robot. Every callback either takes the document's lock or queues a request to the preview loop, and is
wrapped so that an exception becomes a notification in the page, never a dead server.
"""

from __future__ import annotations

import contextlib
import functools
import logging
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any, Protocol

from asm_module.feed import RobotStatus
from gaits.model import Gait

from .deploy_panel import DeployPanel
from .document import GaitDocument
from .drive import DrivePanel
from .editor import GaitEditor
from .guard import AccessGuard, guarded_server
from .link import RobotLink
from .live import KinematicTwin
from .monitor_panel import MonitorPanel
from .preview import PreviewLoop, SceneView
from .preview_panel import PreviewPanel
from .robot_bar import RobotBar

log = logging.getLogger("asm_studio.web")
TOAST_SECONDS = 6.0
PANEL_WIDTH, PANEL_HEIGHT = 560, 330
"""The table-and-plots panel, floating over the 3D view's lower left (it fits a 1366×768 screen beside the side
panel)."""
MIN_DRAW_INTERVAL = 1 / 100


class Backend(Protocol):
    """What the page needs of the backend that builds it (server.studio.Studio is one): the page imports nothing
    of server/, so the two never import each other."""

    gait: Gait
    """The gait opened at start."""
    gait_text: str | None
    """The text of its file (a download keeps its comments)."""
    c_modules: str | None
    """The simulated modules that run the C runtime ("odd", "even", "all", "1,3,5"), in the robot and the preview."""

    @property
    def simulated(self) -> bool:
        """The robot shown is simulated (it publishes poses); else a real bus."""

    def connect(self, robot: str) -> RobotLink:
        """A new link to robot ``robot``."""

    def robots(self) -> list[RobotStatus]:
        """The robots on the network now."""

    def ensure_robot(self, gait: Gait) -> str | None:
        """Make a simulated robot the one ``gait`` describes; a message when it was rebuilt."""

    def on_notice(self, callback: Callable[[str, str, bool], None]) -> None:
        """Call ``callback(title, text, error)`` with what the backend has to say."""


class Dashboard:
    """The viser app of a Backend, attached to one robot by ``link``; see the module docstring."""

    def __init__(
        self, studio: Backend, link: RobotLink, *, host: str = "127.0.0.1", port: int = 8080, token: str | None = None
    ) -> None:
        self.studio = studio
        self.link = link
        self.guard = AccessGuard(host, token)
        self.server = guarded_server(self.guard, host=host, port=port, label="ASM Studio", verbose=False)
        self.port = self.server.get_port()
        self.doc = GaitDocument(studio.gait, text=studio.gait_text)
        self.loop = PreviewLoop(studio.gait, c_modules=studio.c_modules)
        self.view = SceneView(self.server, self.loop, link.feed)
        self.view.on_pick = self.pick_module
        self.twin: KinematicTwin | None = None
        self._stop = threading.Event()
        self._programmatic = threading.local()
        self._last_toast: tuple[tuple[str, str], float] | None = None
        self.toasts = 0
        """Toasts sent (a repeat within TOAST_SECONDS is not)."""
        self._rebuild_lock = threading.RLock()
        self._link_lock = threading.Lock()
        self._build()
        studio.on_notice(lambda title, text, error: self.notify(title, text, error=error))
        self.server.on_client_connect(self._frame_camera)
        self._threads = [threading.Thread(target=self._render, name="studio-render", daemon=True),
                         threading.Thread(target=self._refresh, name="studio-refresh", daemon=True),
                         threading.Thread(target=self._poll, name="studio-poll", daemon=True)]  # fmt: skip
        for thread in self._threads:
            thread.start()

    # -- helpers --------------------------------------------------------------------------------------------------

    def safe(self, fn: Callable[..., Any]) -> Callable[[Any], None]:
        """A callback whose failure is shown as a notification instead of escaping into viser's thread pool."""

        @functools.wraps(fn)
        def wrapped(event: Any) -> None:
            try:
                fn(event)
            except Exception as exc:
                log.info("action failed: %s", exc)
                self.notify("Error", str(exc), error=True)

        return wrapped

    def pick_module(self, module_id: int) -> None:
        """A module clicked in the 3D view: select it in the editor, the preview's plot and the attribute browser."""
        modules = self.doc.data()["modules"]
        index = next((k for k, m in enumerate(sorted(modules, key=lambda m: m["id"])) if m["id"] == module_id), None)
        if index is not None:
            self.editor.module_index.value = index + 1  # its callback resyncs the editor (and the control table)
        if module_id <= self.preview.plot_module.max:
            self.preview.plot_module.value = module_id
        self.monitor.select(f"m{module_id}")
        self.status.content = f"Selected module {module_id}"

    @property
    def status(self) -> Any:
        """The status line (the robot bar's)."""
        return self.bar.status

    def notify(self, title: str, body: str, *, error: bool = False) -> None:
        """Say it in the status line, and as a toast unless the same toast went out less than TOAST_SECONDS ago
        (typing into a field with a problem used to pile up one toast per keystroke)."""
        self.status.content = f"**{title}**: {body}"
        now = time.monotonic()
        last = self._last_toast
        if last is not None and last[0] == (title, body) and now - last[1] < TOAST_SECONDS:
            return
        self._last_toast = ((title, body), now)
        self.toasts += 1
        for client in self.server.get_clients().values():
            client.add_notification(title, body, color="red" if error else "blue", auto_close_seconds=TOAST_SECONDS)

    def resolved(self, title: str, now: str) -> None:
        """The problem the status line reports under ``title`` is gone: say ``now`` instead (one status, current)."""
        if self.status.content.startswith(f"**{title}**"):
            self.status.content = now
            self._last_toast = None

    def _frame_camera(self, client: Any) -> None:
        """Look at the robot from close enough to see its modules move."""
        robot = self.doc.data()["robot"]
        size = float(robot.get("modules", 8)) * float(robot.get("module_size", 0.05))
        client.camera.position = (0.4 * size + 0.3, -0.9 * size - 0.4, 0.4 * size + 0.3)
        client.camera.look_at = (0.0, 0.0, 0.05)

    # -- layout ---------------------------------------------------------------------------------------------------

    def _build(self) -> None:
        gui = self.server.gui
        gui.configure_theme(control_width="large", show_share_button=False)  # a page that commands a robot
        self.bar = RobotBar(self)  # E-STOP first: above every tab
        gui.main_panel.dock_right()
        self.panel = gui.add_panel()
        self.plots_tab = self.panel.add_tab("Plots")  # first: what the page shows at once
        self.table_tab = self.expanded_tab = self.panel.add_tab("Control table")
        self.panel.float(x=12, y=-12, width=PANEL_WIDTH, height=PANEL_HEIGHT)
        tabs = gui.add_tab_group()
        with tabs.add_tab("Gait"):
            self.editor = GaitEditor(self, initial=self.studio.gait.name)
        with tabs.add_tab("Preview"):
            self.preview = PreviewPanel(self, self.plots_tab)
        with tabs.add_tab("Deploy"):
            self.deployer = DeployPanel(self)
        with tabs.add_tab("Drive"):
            self.drive = DrivePanel(self)
        with tabs.add_tab("Monitor"):
            self.monitor = MonitorPanel(self, self.plots_tab)
        self._build_keys()
        self.editor.sync()

    def _build_keys(self) -> None:
        """Keyboard shortcuts, as viser's command-palette hotkeys (a key typed into a field stays the field's; the
        E-STOP's Escape is the page script's, which no field keeps)."""
        keys = (
            ("Play / pause the preview", "space", None, lambda: self.loop.request("play", not self.loop.playing)),
            ("Step the preview back", "arrowleft", "shift", lambda: self.loop.request("step", -1)),
            ("Step the preview forward", "arrowright", "shift", lambda: self.loop.request("step", 1)),
            ("Undo the last edit", "Z", "cmd/ctrl", lambda: self.editor.history("Undo")),
            ("Redo", "Z", "cmd/ctrl+shift", lambda: self.editor.history("Redo")),
        )

        def add(label: str, key: str, action: Any, modifier: str | None = None) -> None:
            command = self.server.gui.add_command(label, hotkey=key, modifier=modifier)  # type: ignore[arg-type]  # viser's Literal of keys
            command.on_trigger(self.safe(lambda _: action()))

        for label, key, modifier, action in keys:
            add(label, key, action, modifier)
        self.drive.bind_keys(add)  # the arrow keys drive

    @contextlib.contextmanager
    def programmatic(self) -> Iterator[None]:
        """Controls set by the server (not the user) inside this block: their update callbacks do nothing.

        viser calls a control's callbacks synchronously, in the thread that sets its value: the flag is that
        thread's alone. (It was one flag for the process: a user's edit arriving on viser's thread pool while the
        20 Hz refresh was setting the timeline was taken for the server's own and silently dropped.) The lock
        keeps the editor's resync and the refresh from interleaving."""
        with self._rebuild_lock:
            outer = self.syncing
            self._programmatic.active = True
            try:
                yield
            finally:
                self._programmatic.active = outer

    @property
    def syncing(self) -> bool:
        """True in a thread that is setting controls itself (see :meth:`programmatic`)."""
        return getattr(self._programmatic, "active", False)

    # -- which robot, which view ----------------------------------------------------------------------------------

    def attach(self, robot: str) -> None:
        """Show and command robot ``robot`` from now on (a new link; the old one is closed)."""
        with self._link_lock:
            new = self.studio.connect(robot)
            old, self.link = self.link, new
            self.deployer.relink()
            self.monitor.relink()
            self.twin = None
            self.view.live = new.feed
            self.view.set_source(self.view.source)
        old.close()
        self.notify("Robot", f"now showing and commanding robot {robot!r}")

    def show(self, source: str) -> None:
        """Show the "preview" or the "live" robot in the 3D view (and say which, under the buttons).

        A real robot sends no poses: its Live view is a kinematic twin of the edited gait's robot, posed from the
        modules' joint.angle publications (made once, on the first look)."""
        if source == "live" and not self.studio.simulated and self.twin is None:
            self.twin = KinematicTwin(self.doc.gait())
            self.twin.follow(self.link.feed, self.link.node)
        self.view.set_source(source)
        # the preview simulation pauses while the live robot is shown (its CPU is the live view's), and plays again
        self.loop.request("play", source == "preview")
        self.bar.tick()

    # -- threads --------------------------------------------------------------------------------------------------

    def _render(self) -> None:
        """Draw each frame the preview records, as it is recorded: at speed 1 the loop records 60 frames a second
        and each is drawn once (a fixed 60 Hz clock beating against the loop's would skip some and repeat others);
        faster playback is drawn at most every MIN_DRAW_INTERVAL."""
        last = 0.0
        while not self._stop.is_set():
            if not self.view.wait_changed(timeout=0.1):
                continue
            pause = last + MIN_DRAW_INTERVAL - time.monotonic()
            if pause > 0 and self._stop.wait(pause):
                return
            last = time.monotonic()
            try:
                self.view.draw()
            except Exception:
                log.exception("drawing the preview failed")

    def _refresh(self) -> None:
        """The page from what is known (20 Hz): never a round trip to the robot, so a robot that stops answering
        never freezes the page (the E-STOP's label, the "robot lost" line)."""
        while not self._stop.wait(0.05):
            try:
                self._refresh_once()
            except Exception:
                log.exception("refreshing the dashboard failed")

    def _poll(self) -> None:
        """Once a second, by asking the modules: every module's gait status, and who holds the deploy lease."""
        while not self._stop.wait(1.0):
            try:
                if self.link.lost() is None:
                    self.link.roster.poll_gaits(stop=self._stop)
                    self.deployer.poll_lease()
            except Exception:
                log.exception("polling the robot failed")

    def _refresh_once(self) -> None:
        self.bar.tick()
        self.preview.refresh()
        loop = self.loop
        with self.programmatic():
            self.drive.sync(loop.sim.gait)
        shown = loop.shown()
        with contextlib.suppress(ValueError):  # a gait with no single period has no cursor
            self.editor.draw_control_table(cursor=None if shown is None else shown.time / loop.sim.gait.period)
        self.monitor.refresh()

    def close(self) -> None:
        self._stop.set()
        for thread in self._threads:
            thread.join(timeout=5)
        self.bar.close()
        self.deployer.close()
        self.monitor.close()
        self.link.close()
        self.loop.close()
        self.server.stop()
