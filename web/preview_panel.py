"""The Preview tab: play, pause, speed, a timeline that scrubs, steps, the ground the preview runs on
(gaits/terrain.py), the look of the 3D view, the run's metrics and which module's commanded-vs-measured angle is
plotted. Its callbacks only queue requests to the preview loop (the loop owns the simulation)."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from gaits.metrics import unsigned_zero
from gaits.terrain import parse

from .inputs import slider
from .monitor import empty_plot, seconds_axes

GROUNDS = ("flat", "slope:5", "slope:-5", "step:0.03", "rough:seed=1,roughness=0.02", "patches:friction=0.3")
"""The grounds the picker offers (terrain specs, as ``gaits simulate --terrain`` takes them)."""

if TYPE_CHECKING:
    from .page import Page


class PreviewPanel:
    """The Preview tab of ``page``; its plot is drawn in the page's plots panel."""

    def __init__(self, page: Page, plots_tab: Any) -> None:
        self.page = page
        gui = page.gui
        loop, view = page.loop, page.view
        self.play = gui.add_button_group("Playback", ["Play", "Pause", "Reset"])
        self.play.on_click(page.safe(self._on_play))
        self.speed = slider(gui, "Speed", min=0.1, max=4.0, initial_value=1.0)
        self.speed.on_update(page.safe(lambda e: loop.request("speed", e.target.value)))
        self.timeline = slider(gui, "Preview timeline (frame)", min=0, max=1, initial_value=0)
        self.timeline.on_update(page.safe(self._on_seek))
        self.ground = gui.add_dropdown("Ground", GROUNDS, initial_value="flat",
                                       hint="what the preview runs on: a slope (degrees uphill), a step (m), rough "
                                       "ground, friction patches")  # fmt: skip
        self.ground.on_update(page.safe(lambda e: loop.request("terrain", parse(str(e.target.value)))))
        steps = gui.add_button_group("Step", ["◀ back", "forward ▶"])
        steps.on_click(page.safe(lambda e: loop.request("step", -1 if "back" in e.target.value else 1)))
        rich = gui.add_checkbox("Shadows and reflections", initial_value=False,
                                hint="nicer, but slow in a browser without a GPU")  # fmt: skip
        rich.on_update(page.safe(lambda e: view.set_rich(bool(e.target.value))))
        follow = gui.add_checkbox("Follow the robot", initial_value=True,
                                  hint="keep the robot in the middle; the ground moves under it")  # fmt: skip
        follow.on_update(page.safe(lambda e: setattr(view, "follow", bool(e.target.value))))
        labels = gui.add_checkbox("Module labels", initial_value=True, hint="each module's name at its joint")
        labels.on_update(page.safe(lambda e: view.set_labels(bool(e.target.value))))
        self.metrics = gui.add_markdown("")
        page.on("pick", self.pick)
        self.plot_module = slider(gui, "Plot module", min=1, max=max(2, page.doc.gait().robot.modules), initial_value=1)
        with plots_tab:
            self.angles = gui.add_uplot(data=empty_plot(3),
                                        series=({"label": "t"}, {"label": "commanded", "stroke": "orange"},
                                                {"label": "measured", "stroke": "steelblue"}),
                                        title="Preview: joint angle (deg)", aspect=3.0,
                                        **seconds_axes("degrees"))  # fmt: skip

    def pick(self, module_id: int) -> None:
        """A module clicked in the 3D view: plot its angles."""
        if module_id <= self.plot_module.max:
            self.plot_module.value = module_id

    def _on_play(self, event: Any) -> None:
        kind = event.target.value
        self.page.loop.request("reset" if kind == "Reset" else "play", kind == "Play")

    def _on_seek(self, event: Any) -> None:
        if not self.page.syncing:  # a user's drag scrubs (and pauses); the refresh moving the slider does not
            self.page.loop.request("seek", int(event.target.value))

    def refresh(self) -> None:
        """Metrics, timeline and plot from the preview loop, now (the page's 20 Hz refresh)."""
        page = self.page
        loop = page.loop
        m = loop.metrics()
        frames = len(loop.frames)
        warning = f"  \n⚠ {loop.error}" if loop.error else ""
        ground = "" if loop.terrain.kind == "flat" else f" on {loop.terrain.spec}"
        frame = loop.shown()
        if frame is not None and frame.running == 0 and loop.ended_at is not None:
            warning = f" · ■ **ended** at t = {loop.ended_at:.2f} s (no module's gait runs){warning}"
        heading = f"{unsigned_zero(m.heading, 0)}°" if m.moved else "n/a"  # never "-0°", nor the direction of noise
        self.metrics.content = (f"Preview{ground}: t = {m.seconds:.2f} s · distance **{m.distance:.3f} m** "
                                f"({m.body_lengths:.2f} BL) · speed **{m.speed:.3f} m/s** · heading {heading} · "
                                f"peak torque {m.peak_torque:.2f} N·m{warning}")  # fmt: skip
        with page.programmatic():
            modules = max(2, loop.gait.robot.modules)
            if self.plot_module.max != modules:
                self.plot_module.max = modules
            self.timeline.max = max(1, frames - 1)
            shown = max(0, frames - 1) if loop.cursor is None else min(loop.cursor, max(0, frames - 1))
            if self.timeline.value != shown:  # stepping and replaying move the frame box as the live end does
                self.timeline.value = shown
        t, goal, angle = loop.series(int(self.plot_module.value) - 1)
        self.angles.data = (t, goal, angle)
