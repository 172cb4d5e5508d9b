"""The dashboard: one viser page to edit a gait, preview it in MuJoCo, deploy it to modules and watch them.

Layout: the side panel (docked right) starts with the robot bar — E-STOP, its release, the status line, the robots
of the network and what the 3D view shows (web/robot_bar.py) — then tabs: Gait (web/editor.py), Preview
(web/preview_panel.py), Deploy (web/deploy_panel.py), Drive (web/drive.py), Monitor (web/monitor_panel.py), Tune
(web/tune_panel.py: the search for a better gait, in worker processes), Modules (web/modules_panel.py: each
module's firmware and calibration), Replay (web/replay_panel.py: an MCAP recording played in the 3D view with a
timeline, its plots and values). A
second panel over the 3D view's lower left shows the plots and the gait control table. No dialog ever covers the
E-STOP: confirmations are rows of the panel (web/confirm.py), and Escape presses E-STOP from anywhere
(web/page_script.py).

The dashboard builds the page (web/page.py) and the panels, answers the page events that are the page's own
(attach another robot, show the preview or the live robot), and runs three threads: drawing the 3D view, a 20 Hz
refresh from what is known, and a 1 Hz poll of the robot. Panels see only the Page.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections.abc import Callable
from typing import Any

from viser._messages import HotkeyKey, KeyModifier

from .deploy_panel import DeployPanel
from .document import GaitDocument
from .drive import DrivePanel
from .editor import GaitEditor
from .guard import AccessGuard, guarded_server
from .link import RobotLink
from .live import KinematicTwin
from .modules_panel import ModulesPanel
from .monitor_panel import MonitorPanel
from .numbering_panel import NumberingPanel
from .page import Backend, Page
from .preview import PreviewLoop
from .preview_panel import PreviewPanel
from .record_panel import RecordPanel
from .replay_panel import ReplayPanel
from .robot_bar import RobotBar
from .scene_view import SceneView
from .state_timeline import WINDOW_SECONDS
from .tune_panel import TunePanel

__all__ = ["Backend", "Dashboard"]

log = logging.getLogger("asm_studio.web")
PANEL_WIDTH, PANEL_HEIGHT = 560, 330
"""The table-and-plots panel, floating over the 3D view's lower left (it fits a 1366×768 screen beside the side
panel)."""
MIN_DRAW_INTERVAL = 1 / 100


class Dashboard:
    """The viser app of a Backend, attached to one robot by ``link``; see the module docstring."""

    def __init__(
        self,
        studio: Backend,
        link: RobotLink,
        *,
        host: str = "127.0.0.1",
        port: int = 8080,
        token: str | None = None,
        max_fps: float | None = None,
    ) -> None:
        self.studio = studio
        self.draw_interval = MIN_DRAW_INTERVAL if max_fps is None else max(MIN_DRAW_INTERVAL, 1.0 / max_fps)
        """The least time between two frames of the 3D view sent to the browsers (``--max-fps``): a page that
        draws at most N frames a second (web/page_script.py) is sent no more, and handles a third of the messages."""
        self.guard = AccessGuard(host, token, max_fps=max_fps)
        self.server = guarded_server(self.guard, host=host, port=port, label="ASM Studio", verbose=False)
        self.port = self.server.get_port()
        self.doc = GaitDocument(studio.gait, text=studio.gait_text, path=studio.gait_path)
        self.loop = PreviewLoop(studio.gait, c_modules=studio.c_modules)
        self.view = SceneView(self.server, self.loop, link.feed)
        self.page = Page(self.server, studio, link, self.doc, self.loop, self.view)
        self.view.on_pick = lambda module_id: self.page.emit("pick", module_id)
        self.twin: KinematicTwin | None = None
        self.draw_unwatched = False
        """Draw the 3D view, the control table and the preview's line with no browser connected (in-process tests
        read them; a studio nobody watches otherwise spends nothing on them — they were half its idle CPU)."""
        self._stop = threading.Event()
        self._link_lock = threading.Lock()
        self._build()
        studio.on_notice(lambda title, text, error: self.page.notify(title, text, error=error))
        self.server.on_client_connect(self._on_connect)
        self._threads = [threading.Thread(target=self._render, name="studio-render", daemon=True),
                         threading.Thread(target=self._refresh, name="studio-refresh", daemon=True),
                         threading.Thread(target=self._poll, name="studio-poll", daemon=True)]  # fmt: skip
        for thread in self._threads:
            thread.start()

    @property
    def link(self) -> RobotLink:
        """The robot the page shows and commands now."""
        return self.page.robot

    def watched(self) -> bool:
        """Whether anyone sees the page now (a browser connected), so drawing it is worth its CPU."""
        return self.draw_unwatched or bool(self.server.get_clients())

    def _on_connect(self, client: Any) -> None:
        """A browser came: what was not drawn while nobody watched is drawn now, from the newest state."""
        self._frame_camera(client)
        self.view.redraw()
        if self.loop.gait.timed:  # else the refresh draws the states over time
            with contextlib.suppress(ValueError):
                self.editor.draw_control_table(force=True)
        else:
            self.editor.redraw_later()

    def _frame_camera(self, client: Any) -> None:
        """Look at the robot from close enough to see its modules move."""
        robot = self.doc.data()["robot"]
        size = float(robot.get("modules", 8)) * float(robot.get("module_size", 0.05))
        client.camera.position = (0.4 * size + 0.3, -0.9 * size - 0.4, 0.4 * size + 0.3)
        client.camera.look_at = (0.0, 0.0, 0.05)

    # -- layout ---------------------------------------------------------------------------------------------------

    def _build(self) -> None:
        gui, page = self.server.gui, self.page
        gui.configure_theme(control_width="large", show_share_button=False)  # a page that commands a robot
        self.bar = RobotBar(page)  # E-STOP first: above every tab
        gui.main_panel.dock_right()
        self.panel = gui.add_panel()
        plots_tab = self.panel.add_tab("Plots")  # first: what the page shows at once
        table_tab = self.panel.add_tab("Control table")
        self.panel.float(x=12, y=-12, width=PANEL_WIDTH, height=PANEL_HEIGHT)
        tabs = gui.add_tab_group()
        with tabs.add_tab("Gait"):
            self.editor = GaitEditor(page, self.studio.gait.name, table_tab, table_tab)
        with tabs.add_tab("Preview"):
            self.preview = PreviewPanel(page, plots_tab)
        with tabs.add_tab("Deploy"):
            self.deployer = DeployPanel(page)
        with tabs.add_tab("Drive"):
            self.drive = DrivePanel(page)
        with tabs.add_tab("Monitor"):
            self.recording = RecordPanel(page)
            self.monitor = MonitorPanel(page, plots_tab)
        with tabs.add_tab("Replay"):
            self.replay = ReplayPanel(page, plots_tab)
        with tabs.add_tab("Tune"):
            self.tuner = TunePanel(page)
        with tabs.add_tab("Modules"):
            self.numbering = NumberingPanel(page, lambda: self.modules.refresh())  # first: a new batch's first step
            self.modules = ModulesPanel(page)
        page.on("attach", self.attach)
        page.on("show", self.show)
        page.on("deployed", lambda gait: self.show("live"))
        page.on("plotted", self.panel.expand)
        page.on("pick", lambda module_id: setattr(page.status, "content", f"Selected module {module_id}"))
        page.on("adopt", self.adopt)
        self._build_keys()
        self.editor.sync()

    def _build_keys(self) -> None:
        """Keyboard shortcuts, as viser's command-palette hotkeys (a key typed into a field stays the field's; the
        E-STOP's Escape is the page script's, which no field keeps)."""
        keys: tuple[tuple[str, HotkeyKey, KeyModifier | None, Callable[[], object]], ...] = (
            ("Play / pause the preview", "space", None, lambda: self.loop.request("play", not self.loop.playing)),
            ("Step the preview back", "arrowleft", "shift", lambda: self.loop.request("step", -1)),
            ("Step the preview forward", "arrowright", "shift", lambda: self.loop.request("step", 1)),
        )
        history: tuple[tuple[str, HotkeyKey, KeyModifier, str], ...] = (
            ("Undo the last edit", "Z", "cmd/ctrl", "Undo"),
            ("Redo", "Z", "cmd/ctrl+shift", "Redo"),
        )

        def add(label: str, key: HotkeyKey, action: Any, modifier: KeyModifier | None = None) -> None:
            command = self.server.gui.add_command(label, hotkey=key, modifier=modifier)
            command.on_trigger(self.page.safe(lambda _: action()))

        for label, key, modifier, action in keys:
            add(label, key, action, modifier)
        for label, key, modifier, kind in history:  # in their place among the edits that came before them
            command = self.server.gui.add_command(label, hotkey=key, modifier=modifier)
            self.page.on_command(command, lambda kind=kind: self.editor.history(kind))
        self.drive.bind_keys(add)  # the arrow keys drive

    def adopt(self, gait: Any, text: str) -> None:
        """A tuned gait becomes the edited one: one undo step, its file's comments (its provenance) kept, and the
        robot file it names read beside the gait it was tuned from, as before."""
        self.doc.replace(gait, text=text, path=self.doc.path)
        self.editor.after_edit()
        self.page.notify("Adopted", f"the tuned {gait.name} is the edited gait (Undo gives the previous one back)")

    # -- which robot, which view ----------------------------------------------------------------------------------

    def attach(self, robot: str) -> None:
        """Show and command robot ``robot`` from now on (a new link; the old one is closed)."""
        with self._link_lock:
            new = self.studio.connect(robot)
            old = self.page.relink(new)
            self.page.emit("relinked")
            self.twin = None
            self.view.live = new.feed
            self.view.set_source(self.view.source)
        old.close()
        self.page.notify("Robot", f"now showing and commanding robot {robot!r}")

    def show(self, source: str) -> None:
        """Show the "preview", the "live" robot or the "replay" of a recording in the 3D view (and say which, under
        the buttons).

        A real robot sends no poses: its Live view is a kinematic twin of the edited gait's robot, posed from the
        modules' joint.angle publications (made once, on the first look)."""
        if source == "live" and not self.studio.simulated and self.twin is None:
            self.twin = KinematicTwin(self.doc.gait())
            self.twin.follow(self.link.feed, self.link.lookup)
        self.view.set_source(source)
        # the preview simulation pauses while the live robot is shown (its CPU is the live view's), and plays again
        self.loop.request("play", source == "preview")
        self.bar.tick()

    # -- threads --------------------------------------------------------------------------------------------------

    def _render(self) -> None:
        """Draw each frame the preview records, as it is recorded: at speed 1 the loop records 60 frames a second
        and each is drawn once (a fixed 60 Hz clock beating against the loop's would skip some and repeat others);
        faster playback is drawn at most every MIN_DRAW_INTERVAL (and at most every ``draw_interval``)."""
        last = 0.0
        while not self._stop.is_set():
            if not self.view.wait_changed(timeout=0.1) or not self.watched():
                continue
            pause = last + self.draw_interval - time.monotonic()
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
        watched = self.watched()
        self.loop.hold(not watched)  # nobody sees the preview: it waits where it is (its CPU is the studio's most)
        if watched:
            self.preview.refresh()
            self.tuner.refresh()
        loop = self.loop
        with self.page.programmatic():
            self.drive.sync(loop.gait)
        shown = loop.shown()
        if watched and loop.gait.timed:
            with contextlib.suppress(ValueError):  # a gait with no single period has no cursor
                self.editor.draw_control_table(cursor=None if shown is None else shown.time / loop.gait.period)
        elif watched:  # event-driven or one-shot: what the preview's modules did, in place of a blank table
            self.editor.draw_states(*loop.state_history(WINDOW_SECONDS), loop.ended_at)
        self.monitor.refresh()
        if watched:
            self.replay.refresh()

    def close(self) -> None:
        self._stop.set()
        for thread in self._threads:
            thread.join(timeout=5)
        self.bar.close()
        self.deployer.close()
        self.monitor.close()
        self.tuner.close()
        self.numbering.close()
        self.modules.close()
        self.replay.close()
        self.link.close()
        self.loop.close()
        self.page.close()
        self.server.stop()
