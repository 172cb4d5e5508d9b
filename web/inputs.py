"""An input that fits an attribute's type, derived from its codec (the one place the type is defined).

bool → a checkbox; integers → a number input with step 1 (its range in the label); floats → a number input; float
arrays of 2 or 3 → a vector input; anything else (text, bytes as hex, arrays, records, JSON) → a text box parsed by
:func:`web.monitor.parse_value`. A service gets a "running" checkbox: set it to start the service, clear it to stop.
The attribute browser swaps the input whenever another object is chosen.
"""

from __future__ import annotations

import json
import math
from typing import Any

import viser

from asm_py.remote import RemoteAttribute, RemoteObject, RemoteService

from .monitor import format_value, parse_value

JS_SAFE = 2**53 - 1
"""Largest integer a browser's number input holds exactly; wider ranges are left unbounded in the page."""


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
            self.handle = gui.add_number(label, initial_value=int(value), step=1, hint=f"{low}..{high}")
        elif self.kind == "float" and math.isfinite(float(value)):
            self.handle = gui.add_number(label, initial_value=float(value), step=0.001)
        elif self.kind == "float_array" and info.get("length") in (2, 3) and all(map(math.isfinite, value)):
            v = [float(x) for x in value]
            if len(v) == 2:
                self.handle = gui.add_vector2(label, (v[0], v[1]), step=0.001)
            else:
                self.handle = gui.add_vector3(label, (v[0], v[1], v[2]), step=0.001)
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
