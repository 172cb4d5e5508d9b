"""The Deploy tab: stage and verify the edited gait on every module (nothing moves), then start it with one
broadcast when the user says Start — all or nothing (gaits/deploy.py) — and a log that keeps every line.

The deploy lease is held from staging until Start (or Cancel, or the question expiring), so no other deployer can
stage or start meanwhile; the tab says who holds the robot's lease when it is not this page. On a simulated robot
the studio's own robot first becomes the edited gait's robot; on a real bus the user confirms first, told how the
robot differs from the gait's (gaits/compatible.py: modules missing or not in the gait, joint limits that would clamp
it, a module that says it is another type than the gait describes, or whose joint turns like another module type's).
Whoever started the robot, a deploy to modules that say they are other types than the gait describes is refused
before anything is sent (gaits.deploy's own check) and asked about: a simulated robot another person started, built
of another gait's modules, is asked about as a real one is. Questions are rows of the tab, never a dialog over the
E-STOP (web/confirm.py)."""

from __future__ import annotations

import html
import threading
import time
from collections.abc import Collection
from typing import TYPE_CHECKING, Any

from asm_module.names import module_name
from gaits.compatible import mismatches, module_lines, read_limits, read_objects
from gaits.deploy import DeployReport, RobotMismatch
from gaits.model import Gait

from .confirm import InlineConfirm

if TYPE_CHECKING:
    from .link import RobotLink
    from .page import Page

LOG_LINES = 500
"""Lines the deploy log keeps (it scrolls)."""


class DeployPanel:
    """The Deploy tab of ``page``; see the module docstring."""

    def __init__(self, page: Page) -> None:
        self.page = page
        gui = page.gui
        self.intro = gui.add_markdown("")
        self._describe_target()
        self.button = gui.add_button("Deploy")
        self.button.on_click(page.safe(page.in_turn(lambda _: self.on_deploy())))  # the gait with every edit before
        self.confirm = InlineConfirm(gui, page.safe)
        self.lease_md = gui.add_markdown("")
        self.progress = gui.add_progress_bar(0.0)
        self.log_html = gui.add_html("")
        self._lines: list[str] = []
        self.run_buttons = gui.add_button_group("Modules", ["Start all", "Stop all"])
        self.run_buttons.on_click(page.safe(page.in_turn(self.on_run)))  # the modules of every edit before it
        self._staged: DeployReport | None = None
        self._staged_lock = threading.Lock()
        page.on("relinked", self.relink)

    def _describe_target(self) -> None:
        target = "the simulated modules" if self.page.simulated else "the modules on the REAL CAN bus"
        self.intro.content = (f"Deploy the edited gait to {target} of robot **{self.page.robot.robot}**: validate, "
                              "stage it beside the running gait and verify each checksum (nothing moves yet); then, "
                              "when you say Start, switch every module with one broadcast and confirm each — all or "
                              "nothing.")  # fmt: skip

    def relink(self) -> None:
        """The page now commands another robot: a deployment staged on the old one is given up."""
        self.confirm.withdraw()
        self._describe_target()
        self.lease_md.content = ""

    def on_deploy(self) -> None:
        gait = self.page.doc.gait()  # GaitError (shown) if the edited gait is invalid
        self.page.robot.require("deploy")
        robot = self.page.robot
        alive = robot.alive_modules()
        wanted = {module_name(a.id) for a in gait.modules} & set(alive)
        infos = read_objects(robot.lookup, sorted(wanted), "module.info")
        types = read_objects(robot.lookup, sorted(wanted), "module.type")  # none from a module that says none
        calibrations = read_objects(robot.lookup, sorted(wanted), "joint.calibration")
        for line in module_lines(infos, calibrations, types):  # a simulated robot's too: its modules may be boards
            self.log(line)  # what each module runs, is and how it is calibrated, before anything is sent
        if not self.page.simulated:
            problems = mismatches(gait, alive, read_limits(robot.lookup, sorted(wanted)), infos, types)
            question = f"Deploy {gait.name} to the {gait.robot.modules} modules of the REAL robot?"
            if problems:  # said before anything is sent: the robot is not the one previewed
                question += " ⚠ Not the robot this gait was made for: " + "; ".join(problems) + "."
                self.log("robot check: " + "; ".join(problems))
            self.confirm.ask(question, "Yes, deploy", lambda: self._deploy(gait, accept=problems, asked=robot))
            return
        self._deploy(gait)

    def log(self, line: str) -> None:
        """One more line in the deploy log, which keeps every line and scrolls (newest at the bottom)."""
        self._lines.append(html.escape(line))
        del self._lines[:-LOG_LINES]
        self.log_html.content = ('<div style="max-height:12em;overflow-y:auto;font-size:0.85em;'
                                 'display:flex;flex-direction:column-reverse"><div>'
                                 + "<br>".join(self._lines) + "</div></div>")  # fmt: skip

    def _deploy(self, gait: Gait, accept: Collection[str] = (), asked: RobotLink | None = None) -> None:
        """Stage and verify (nothing moves, the lease stays held), then ask before starting. A deployment of this
        page still waiting for its Start is given up first (its lease released): the new one replaces it. Modules
        that say they are other types than the gait describes are asked about first, unless ``accept`` holds what
        the user said yes to — about the robot link ``asked``: a yes given for one robot never deploys to another
        the page was switched to meanwhile."""
        link = self.page.robot
        if asked is not None and asked is not link:
            self.log(f"{gait.name}: not deployed: the yes was for robot {asked.robot}, and the page now commands "
                     f"robot {link.robot}; press Deploy to be asked about this one")  # fmt: skip
            self.page.notify("Not deployed", f"the yes was for robot {asked.robot}, not {link.robot}", error=True)
            return
        self.confirm.withdraw()
        try:
            report = self.stage(gait, accept)
        except RobotMismatch as mismatch:  # nothing was sent: the user decides
            problems = mismatch.problems
            self.log("robot check: " + "; ".join(problems))
            self.confirm.ask(f"Deploy {gait.name} to robot {self.page.robot.robot}? ⚠ Not the robot this gait was "
                             "made for: " + "; ".join(problems) + ".", "Yes, deploy",
                             lambda: self._deploy(gait, accept=problems, asked=link))  # fmt: skip
            return
        with self._staged_lock:
            self._staged = report
        self.confirm.ask(f"{_staged(gait, report)}. Start it now? Every module switches to it at once, from where "
                         "it stands.", "Start", lambda: self.start(gait, report),
                         on_cancel=lambda: self._give_up(report, "cancelled"))  # fmt: skip

    def _give_up(self, report: DeployReport, why: str) -> None:
        report.cancel()
        with self._staged_lock:
            if self._staged is report:
                self._staged = None
        self.log(f"{report.gait}: not started ({why}); the lease is released, every module runs what it ran")

    def stage(self, gait: Gait, accept: Collection[str] = ()) -> DeployReport:
        """Deploy steps 1-3 (lease, stage, verify); the DeployReport to start from, still holding the lease."""
        page, robot = self.page, self.page.robot

        def progress(done: int, total: int, message: str) -> None:
            self.progress.value = 100.0 * done / total
            self.log(message)

        self.progress.value = 0.0
        self.log(f"— deploy {gait.name} to robot {robot.robot} at {time.strftime('%H:%M:%S')} —")
        rebuilt = page.ensure_robot(gait)  # the simulated robot becomes the edited one
        if rebuilt:
            self.log(rebuilt)
            wanted = {module_name(a.id) for a in gait.modules}
            removed = [n for n in robot.modules() if n not in wanted]
            robot.forget(removed)
            page.emit("modules_removed", removed)
            robot.await_modules(wanted, timeout=30.0)
            robot.await_present(timeout=30.0)  # its process too: a deploy right after was refused as "lost"
        report = robot.stage(gait, progress, accept)
        self.log(_staged(gait, report) + "; nothing moves until Start (the deploy lease is held until then)")
        page.notify("Staged", _staged(gait, report))
        return report

    def start(self, gait: Gait, report: DeployReport) -> None:
        """Deploy steps 4-5: one broadcast activates the staged gait; each module confirms; the view goes Live."""
        with self._staged_lock:
            self._staged = None
        report = self.page.robot.start(report)
        self.log(f"started: {len(report.running)} of {gait.robot.modules} modules confirmed running {gait.name}")
        self.page.notify("Deployed", f"{_staged(gait, report)}; "
                         f"{len(report.running)} of {gait.robot.modules} confirmed running it")  # fmt: skip
        self.page.emit("deployed", gait)

    def on_run(self, event: Any) -> None:
        page = self.page
        if event.target.value == "Start all":
            names = [module_name(a.id) for a in page.doc.gait().modules]
            running = page.robot.start_all(names)
            page.notify("Modules", f"{len(running)} of {len(names)} modules confirmed running")
        else:
            page.robot.stop_all()
            page.notify("Modules", "stop sent to every module")

    def poll_lease(self) -> None:
        """Say who holds the robot's deploy lease (once a second, from the page's refresh)."""
        with self._staged_lock:
            mine = self._staged is not None
        holder = None if mine else self.page.robot.lease_holder()
        if mine:
            text = "Deploy lease: **held by this page** until you Start or Cancel"
        elif holder:
            text = f"Deploy lease: held by **{holder}** — deploying here is refused until it is released"
        else:
            text = ""
        if self.lease_md.content != text:
            self.lease_md.content = text

    def close(self) -> None:
        self.confirm.withdraw()


def _staged(gait: Gait, report: DeployReport) -> str:
    return f"{gait.name}: staged and verified on {len(report.checksums)} modules"
