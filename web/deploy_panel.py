"""The Deploy tab: stage and verify the edited gait on every module (nothing moves), then start it with one
broadcast when the user who clicked says Start — all or nothing (gaits/deploy.py) — and a log that keeps every line.

On a simulated robot the robot first becomes the edited gait's robot; on a real bus the user confirms first, told
which modules on the bus are not in the gait."""

from __future__ import annotations

import html
import time
from typing import TYPE_CHECKING, Any

from gaits.deploy import activate, deploy, module_name, start_all, stop_all

if TYPE_CHECKING:
    from .app import Dashboard

LOG_LINES = 500
"""Lines the deploy log keeps (it scrolls)."""


class DeployPanel:
    """The Deploy tab of ``app``; see the module docstring."""

    def __init__(self, app: Dashboard) -> None:
        self.app = app
        gui = app.server.gui
        target = "the simulated modules" if app.studio.simulated else "the modules on the REAL CAN bus"
        gui.add_markdown(f"Deploy the edited gait to {target}: validate, stage it beside the running gait and "
                         "verify each checksum (nothing moves yet); then, when you say Start, switch every module "
                         "with one broadcast and confirm each — all or nothing.")  # fmt: skip
        self.button = gui.add_button("Deploy")
        self.button.on_click(app.safe(self.on_deploy))
        self.progress = gui.add_progress_bar(0.0)
        self.log_html = gui.add_html("")
        self._lines: list[str] = []
        self.run_buttons = gui.add_button_group("Modules", ["Start all", "Stop all"])
        self.run_buttons.on_click(app.safe(self.on_run))

    def on_deploy(self, event: Any) -> None:
        gait = self.app.doc.gait()  # GaitError (shown) if the edited gait is invalid
        if not self.app.studio.simulated:
            self._confirm_real(event, gait)
            return
        self._deploy(event, gait)

    def _confirm_real(self, event: Any, gait: Any) -> None:
        wanted = {module_name(a.id) for a in gait.modules}
        others = [n for n in self.app.modules() if n not in wanted]
        lines = [f"{gait.name} will be written to {gait.robot.modules} modules on the bus."]
        if others:
            lines.append(f"⚠ {', '.join(others)} on the bus are not in this gait: they keep running what they run "
                         "(the activation reaches only the modules that staged this gait).")  # fmt: skip
        self.app.confirm(event, "Deploy to the real robot?", lines, "Yes, deploy", "red",
                         lambda: self._deploy(event, gait))  # fmt: skip

    def log(self, line: str) -> None:
        """One more line in the deploy log, which keeps every line and scrolls (newest at the bottom)."""
        self._lines.append(html.escape(line))
        del self._lines[:-LOG_LINES]
        self.log_html.content = ('<div style="max-height:12em;overflow-y:auto;font-size:0.85em;'
                                 'display:flex;flex-direction:column-reverse"><div>'
                                 + "<br>".join(self._lines) + "</div></div>")  # fmt: skip

    def _deploy(self, event: Any, gait: Any) -> None:
        """Stage and verify (nothing moves), then ask the user who clicked before starting."""
        report = self.stage(gait)
        lines = [
            f"{_staged(gait, report)}.",
            "Start it now? Every module switches to it at once, from where it stands.",
        ]
        self.app.confirm(event, f"Start {gait.name}?", lines, "Start", "green", lambda: self.start(gait, report))

    def stage(self, gait: Any) -> Any:
        """Deploy steps 1-3 (lease, stage, verify); the DeployReport to start from."""
        app = self.app

        def progress(done: int, total: int, message: str) -> None:
            self.progress.value = 100.0 * done / total
            self.log(message)

        self.progress.value = 0.0
        self.log(f"— deploy {gait.name} at {time.strftime('%H:%M:%S')} —")
        before = set(app.roster.alive())
        rebuilt = app.studio.ensure_robot(gait)  # the simulated robot becomes the edited one
        if rebuilt:
            self.log(rebuilt)
            wanted = {module_name(a.id) for a in gait.modules}
            removed = sorted(n for n in before if n.startswith("m") and n[1:].isdigit() and n not in wanted)
            app.roster.forget(removed)
            for plot in app.plots:
                plot.forget(removed)
            deadline = time.monotonic() + 30.0
            while not wanted <= set(app.node.discover()) and time.monotonic() < deadline:  # type: ignore[union-attr]
                time.sleep(0.1)
        report = deploy(app.node, gait, progress=progress, timeout=5.0, start=False)  # type: ignore[arg-type]
        self.log(_staged(gait, report) + "; nothing moves until Start")
        app.notify("Staged", _staged(gait, report))
        return report

    def start(self, gait: Any, report: Any) -> None:
        """Deploy steps 4-5: one broadcast activates the staged gait; each module confirms; the view goes Live."""
        app = self.app
        report = activate(app.node, report, timeout=5.0)  # type: ignore[arg-type]
        app.drive.deployed = gait
        self.log(f"started: {len(report.running)} of {gait.robot.modules} modules confirmed running {gait.name}")
        app.notify("Deployed", f"{_staged(gait, report)}; "
                   f"{len(report.running)} of {gait.robot.modules} confirmed running it")  # fmt: skip
        for assignment in gait.modules[:4]:
            app.plot.watch(module_name(assignment.id), "joint.angle")
        app.show("live")

    def on_run(self, event: Any) -> None:
        app = self.app
        if event.target.value == "Start all":
            names = [module_name(a.id) for a in app.doc.gait().modules]
            running = start_all(app.node, names)  # type: ignore[arg-type]
            app.notify("Modules", f"{len(running)} of {len(names)} modules confirmed running")
        else:
            stop_all(app.node)  # type: ignore[arg-type]
            app.notify("Modules", "stop sent to every module")


def _staged(gait: Any, report: Any) -> str:
    return f"{gait.name}: staged and verified on {len(report.checksums)} modules"
