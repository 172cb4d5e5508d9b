"""An input that fits an attribute's type, derived from its codec (the one place the type is defined).

bool → a checkbox; integers → a number input with step 1 (its range in the label); floats → a number input; float
arrays of 2 or 3 → a vector input; anything else (text, bytes as hex, arrays, records, JSON) → a text box parsed by
:func:`web.monitor.parse_value`. A service gets a "running" checkbox: set it to start the service, clear it to stop.
The attribute browser swaps the input whenever another object is chosen.
"""

from __future__ import annotations

import json
import math
from typing import Any, TypeVar

import viser

from asm_py.remote import RemoteAttribute, RemoteObject, RemoteService

from .monitor import format_value, parse_value

JS_SAFE = 2**53 - 1
"""Largest integer a browser's number input holds exactly; wider ranges are left unbounded in the page."""
DIGITS = 6
"""Decimal places every number field of the page takes and shows (no trailing zeros: 8 shows as 8). viser derives a
field's precision from its step, and the field's formatter rounds typed text to it: 2.5 typed into a field of step 1
was sent as 2, 12.25 into one of step 0.5 as 12.2. Text with more decimals than this is refused by the page's script
(web/page_script.py), never rounded; a whole-number field refuses a fraction itself (:func:`whole`)."""

SLIDER_DECIMALS = {"State": 0, "Module": 0, "Plot module": 0, "Preview timeline (frame)": 0, "Speed": 1,
                   "Replay time (s)": 2}  # fmt: skip
"""Every slider of the page by its label, and the decimal places it takes (its step is 10**-decimals). A slider's
number box rounds typed text to its precision (2.5 into State picked state 2, 0.25 into Speed ran at 0.3, without a
word): the page's script refuses text with more decimals than its slider takes (web/page_script.py)."""


def slider(gui: viser.GuiApi, label: str, *, min: float, max: float,
           initial_value: float) -> viser.GuiSliderHandle[Any]:  # fmt: skip
    """``gui.add_slider`` for the page, its step from SLIDER_DECIMALS (every slider of the page is made here)."""
    decimals = SLIDER_DECIMALS[label]
    step: float = 1 if decimals == 0 else 10.0**-decimals
    return gui.add_slider(label, min=min, max=max, step=step, initial_value=initial_value)


Precise = TypeVar("Precise", viser.GuiNumberHandle[Any], viser.GuiVector2Handle, viser.GuiVector3Handle)


def precise(handle: Precise) -> Precise:
    """``handle`` (a number or vector input) made to take and show DIGITS decimal places, whatever its step. (Its
    value must be a float too: see :func:`number`.)"""
    handle.precision = DIGITS
    return handle


def number(gui: viser.GuiApi, label: str, initial_value: float, **kwargs: Any) -> viser.GuiNumberHandle[Any]:
    """``gui.add_number`` for the page: the field keeps what was typed (:func:`precise`). Every number field of the
    page is made here.

    Its value is a float, a whole-number field's too, and whatever sets it later sets a float: viser casts what the
    page sends to the type of the value the handle holds, so a field holding an int took 2.5 as int(2.5) = 2 (the
    same as the 2 it held: no callback at all, or a 2 the user never typed). A whole-number field's reader refuses
    a fraction itself (:func:`whole`)."""
    return precise(gui.add_number(label, float(initial_value), **kwargs))


def whole(value: Any, field: str) -> int:
    """A whole-number field's value as an int; ValueError naming ``field`` for a fraction (never rounded, never
    truncated: 2.5 is not 2), or for something that is no number at all."""
    if isinstance(value, int) and not isinstance(value, bool):
        return value  # exact, however wide (a float holds integers to 2**53 only)
    as_float = float(value)
    if not as_float.is_integer():
        raise ValueError(f"{field} must be a whole number, not {as_float:g}")
    return int(as_float)


class ValueInput:
    """The input for one remote object; :meth:`write` sends what the page holds, :meth:`refresh` fetches it."""

    def __init__(self, gui: viser.GuiApi, obj: RemoteObject) -> None:
        self.obj = obj
        self.handle: Any
        if isinstance(obj, RemoteService):
            self.kind = "service"
            self.handle = gui.add_checkbox(f"{obj.name} running", initial_value=bool(obj.running),
                                           hint="check to start the service, clear to stop it; then Set")  # fmt: skip
            return
        if not isinstance(obj, RemoteAttribute):
            raise TypeError(f"{obj.name} is neither an attribute nor a service")
        value = obj.peek()
        info = obj.codec.describe()
        self.kind = info.get("kind")
        label = f"{obj.name} ({info.get('spec')})"
        if self.kind == "bool":
            self.handle = gui.add_checkbox(label, initial_value=bool(value))
        elif self.kind == "int":
            # no min/max on the input: the browser would clamp (an int8 of 300 became 127 and was written to the
            # module); read() refuses a value outside the codec's range instead, and nothing is sent
            low, high = info.get("min"), info.get("max")
            self.handle = number(gui, label, initial_value=int(value), step=1, hint=f"{low}..{high}")
            if abs(value) > JS_SAFE:  # wider than a float holds: kept exact (the page cannot show it exactly anyway)
                self.handle.value = int(value)
        elif self.kind == "float" and math.isfinite(float(value)):
            self.handle = number(gui, label, initial_value=float(value), step=0.001)
        elif self.kind == "float_array" and info.get("length") in (2, 3) and all(map(math.isfinite, value)):
            v = [float(x) for x in value]
            if len(v) == 2:
                self.handle = precise(gui.add_vector2(label, (v[0], v[1]), step=0.001))
            else:
                self.handle = precise(gui.add_vector3(label, (v[0], v[1], v[2]), step=0.001))
        else:
            self.kind = "text"
            self.handle = gui.add_text(label, initial_value=_as_text(value))

    def _attribute(self) -> RemoteAttribute:
        """The object as the attribute it is: Monitor makes inputs for attributes and services only."""
        if not isinstance(self.obj, RemoteAttribute):
            raise TypeError(f"{self.obj.name} is not an attribute")
        return self.obj

    def write(self) -> Any:
        """Set the remote attribute to the page's value (start or stop a service) and wait for it; returns it."""
        value = self.read()
        if isinstance(self.obj, RemoteService):
            if value:
                self.obj.start(wait=True)
            else:
                self.obj.stop(wait=True)
        else:
            self._attribute().set(value, wait=True)
        return value

    def refresh(self) -> Any:
        """Fetch the remote value (or whether a service runs), show it in the input and return it."""
        value = self.obj.running if isinstance(self.obj, RemoteService) else self._attribute().peek()
        self.show(value)
        return value

    def read(self) -> Any:
        """The value in the page, as the attribute's codec takes it (ValueError/TypeError if it cannot be)."""
        value = self.handle.value
        if self.kind == "text":
            return parse_value(self._attribute(), value)
        if self.kind == "float_array":
            value = tuple(float(v) for v in value)
        if self.kind == "int":  # a fraction refused by name (never written as 2); a whole float (2.0) as the int
            value = whole(value, self.obj.name)
        if isinstance(self.obj, RemoteAttribute):
            self.obj.codec.normalize(value)  # out of the type's range: ValueError here, before anything is sent
        return value

    def show(self, value: Any) -> None:
        if self.kind == "text":
            self.handle.value = _as_text(value)
        elif self.kind == "float_array":
            self.handle.value = tuple(float(v) for v in value)
        elif self.kind == "float" and not math.isfinite(value):
            return  # a number input cannot show NaN; the markdown line above it does
        elif self.kind == "int" and abs(value) <= JS_SAFE:
            self.handle.value = float(value)  # a float, so that a fraction typed comes as one (see number())
        else:
            self.handle.value = value

    def remove(self) -> None:
        self.handle.remove()


def _as_text(value: Any) -> str:
    """Text that :func:`parse_value` reads back to ``value`` (bytes as hex, arrays and records as JSON)."""
    if isinstance(value, bytes | bytearray):
        return value.hex()
    if isinstance(value, str):
        return value
    if isinstance(value, tuple | list | dict):
        return json.dumps(value)
    return format_value(value)
