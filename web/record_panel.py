"""The Record button (in the Monitor tab): the robot the page shows, recorded to an MCAP file by the backend (the
same recorder as ``asm-record``: every attribute value, the poses for Foxglove's 3D panel, status, e-stops and group
messages, the edited gait embedded). Foxglove, Lichtblick and the ``mcap`` tools open the file. The callbacks only
queue the request: the backend looks the robot up and finishes the file on its own thread, then says what it did.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from gaits.model import GaitError

if TYPE_CHECKING:
    from .page import Page

ACTIONS = ["● Record", "■ Stop recording"]


class RecordPanel:
    def __init__(self, page: Page) -> None:
        self.page = page
        self.buttons = page.gui.add_button_group("Recording", ACTIONS,
                                                 hint="record the robot shown to MCAP (Foxglove opens it)")  # fmt: skip
        self.buttons.on_click(page.safe(page.in_turn(self._on_click)))  # the gait with every edit before it
        self.line = page.gui.add_markdown("Not recording.")

    def _on_click(self, event: Any) -> None:
        if event.target.value == ACTIONS[0]:
            doc = self.page.doc
            self.line.content = f"Recording: looking up robot {self.page.robot.robot} …"
            try:
                text = doc.text(inline=True)  # a recording's gait stands alone
            except GaitError:  # a gait with problems now: recorded without it
                text = ""
            name = str(doc.data().get("name", "gait"))
            self.page.recorder.start_recording(self.page.robot.robot, name, text, self._said)
        else:
            self.line.content = "Recording: finishing the file …"
            self.page.recorder.stop_recording(self._said)

    def _said(self, line: str, error: bool) -> None:
        """What the backend did (on its thread): the line under the buttons, and a notice."""
        self.line.content = f"{'⚠ ' if error else ''}Recording: {line}"
        self.page.notify("Recording", line, error=error)
