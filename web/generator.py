"""The Gait tab's tools for making gaits fast: name and description, a generator for the classic families, and
whole-gait operations (spread phases, shift phases, scale amplitude).

Each control only edits the document (one undo step each) and lets the editor show and re-preview it; a value that
cannot be used is refused with its reason and changes nothing.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import viser

from gaits.generate import FAMILIES, WaveSpec, generate

from .document import GaitDocument
from .inputs import number, whole

Safe = Callable[[Callable[[Any], None]], Callable[[Any], None]]
"""The dashboard's wrapper that shows a callback's failure instead of losing it in viser's thread pool."""
LABELS = {"travelling_wave": "travelling wave", "rolling_loop": "rolling loop", "sidewinding": "sidewinding"}
DEFAULTS = {  # a family's usual numbers, filled in when it is chosen
    "travelling_wave": {"amplitude": 45.0, "wavelength": 6.0},
    "rolling_loop": {"amplitude": 45.0, "wavelength": 6.0},
    "sidewinding": {"amplitude": 60.0, "wavelength": 12.0},
}


class GaitTools:
    """The controls; ``edited`` is the editor's after-edit (show, validate, re-preview)."""

    def __init__(self, gui: viser.GuiApi, doc: GaitDocument, *, edited: Callable[[], None], safe: Safe,
                 syncing: Callable[[], bool], on_edit: Callable[..., Any]) -> None:  # fmt: skip
        self.doc = doc
        self._edited = edited
        self._syncing = syncing
        self.name = gui.add_text("Name", initial_value="")
        self.description = gui.add_text("Description", initial_value="")
        for handle, field in ((self.name, "name"), (self.description, "description")):
            # the text as it came (the page's on_edit): a resync from another edit may replace it before this runs
            on_edit(handle, lambda text, field=field: self._edit(lambda: doc.set_meta(field, text)))
        with gui.add_folder("Make a gait", expand_by_default=False):
            self.family = gui.add_dropdown("Family", [LABELS[f] for f in FAMILIES])
            self.modules = number(gui, "Module count", initial_value=12, step=1, hint="2..254 (a loop: 4 or more)")
            self.amplitude = number(gui, "Amplitude (deg)", initial_value=45.0, step=1.0)
            self.wavelength = number(gui, "Wavelength (modules)", initial_value=6.0, step=0.5,
                                     hint="modules per wave; negative: it runs the other way")  # fmt: skip
            self.period = number(gui, "Period (s)", initial_value=1.0, step=0.1)
            self.states = number(gui, "States per period", initial_value=16, step=1)
            self.axes = gui.add_dropdown("Joint axes", ["pitch", "yaw", "alternating"],
                                         hint="travelling wave: pitch (caterpillar) or yaw (undulation)")  # fmt: skip
            self.make = gui.add_button("Generate")
        with gui.add_folder("Whole gait", expand_by_default=False):
            self.amount = number(gui, "Amount", initial_value=0.1, step=0.05,
                                 hint="Shift: cycles added to every phase. Scale: the factor.")  # fmt: skip
            self.whole = gui.add_button_group("Apply", ["Spread phases", "Shift phases", "Scale amplitude"])
        self.family.on_update(safe(lambda _: None if syncing() else self._family_chosen()))
        # in order with the edits that came before them, with the fields as they were when clicked (the page's on_edit)
        on_edit(self.make, lambda _, spec: self._edit(lambda: self.doc.replace(generate(spec))), click=True,
                context=self.spec)  # fmt: skip
        on_edit(self.whole, self._on_whole, click=True, context=lambda: float(self.amount.value))

    def spec(self) -> WaveSpec:
        """The generator's fields as a WaveSpec (generate() checks every number)."""
        return WaveSpec(family=self._family(), modules=whole(self.modules.value, "Module count"),
                        amplitude=float(self.amplitude.value), wavelength=float(self.wavelength.value),
                        period=float(self.period.value), states=whole(self.states.value, "States per period"),
                        axes=self.axes.value)  # fmt: skip

    def sync(self, data: dict[str, Any]) -> None:
        """Show the document's name and description (called by the editor inside its programmatic block)."""
        self.name.value = data.get("name", "")
        self.description.value = data.get("description", "")

    def _family(self) -> str:
        return next(f for f in FAMILIES if LABELS[f] == self.family.value)

    def _family_chosen(self) -> None:
        family = self._family()
        self.amplitude.value = DEFAULTS[family]["amplitude"]
        self.wavelength.value = DEFAULTS[family]["wavelength"]

    def _on_whole(self, action: str, amount: float) -> None:
        if action == "Spread phases":
            self._edit(self.doc.spread_phases)
        elif action == "Shift phases":
            self._edit(lambda: self.doc.shift_phases(amount))
        else:
            self._edit(lambda: self.doc.scale_amplitude(amount))

    def _edit(self, change: Callable[[], None]) -> None:
        change()
        self._edited()
