"""Confirmations without a dialog: a question and its buttons in a row of the panel, so the E-STOP button above
(and its key) stays within reach while the user decides — a modal dialog held every click until it was closed.

An :class:`InlineConfirm` is hidden until :meth:`ask`; "yes" runs the action, "no" or a new question withdraws the
old one, and a question nobody answers withdraws itself after ``expires`` seconds (a "Start?" left for tomorrow
must not start anything). Its callbacks run on viser's thread pool and only take its own lock. A question is plain
text: what a robot reports (a module's type, a lease holder's name) is shown as written, never as markup or HTML.
"""

from __future__ import annotations

import re
import threading
import time
from collections.abc import Callable
from typing import Any

ASK_SECONDS = 60.0
_MARKUP = re.compile(r"([\\`*_{}\[\]()#+\-.!|<>~&])")


def plain(text: str) -> str:
    """``text`` as markdown that shows it as written: every ASCII punctuation character a markdown or HTML reading
    could act on is escaped (CommonMark's backslash escapes; viser's markdown renders raw HTML)."""
    return _MARKUP.sub(r"\\\1", text)


_ESCAPED = re.compile(r"\\([\\`*_{}\[\]()#+\-.!|<>~&])")


def unplain(text: str) -> str:
    """``plain``'s escapes taken out again: the text for a toast, which shows its body as written, not as
    markdown (the status line's ``run\\.mcap opened`` showed there with its backslash)."""
    return _ESCAPED.sub(r"\1", text)


class InlineConfirm:
    """A hidden question row; see the module docstring."""

    def __init__(self, gui: Any, safe: Callable[[Callable[[Any], None]], Callable[[Any], None]]) -> None:
        self._lock = threading.Lock()
        self._action: Callable[[], None] | None = None
        self._cancelled: Callable[[], None] | None = None
        self._asked_at = 0.0
        self._expires = ASK_SECONDS
        self.asked = ""
        """The question asked last, as plain text (the markdown shows it as written)."""
        self.question = gui.add_markdown("", visible=False)
        self.buttons = gui.add_button_group("Confirm", ["Yes", "Cancel"], visible=False)
        self.buttons.on_click(safe(self._on_click))

    @property
    def pending(self) -> bool:
        with self._lock:
            return self._action is not None

    def ask(
        self,
        question: str,
        yes: str,
        action: Callable[[], None],
        *,
        on_cancel: Callable[[], None] | None = None,
        expires: float = ASK_SECONDS,
    ) -> None:
        """Show ``question`` with buttons ``yes`` and Cancel; ``action`` runs on yes, ``on_cancel`` otherwise."""
        with self._lock:
            previous, self._cancelled = self._cancelled, on_cancel
            self._action = action
            self._asked_at = time.monotonic()
            self._expires = expires
        if previous is not None:
            previous()
        self.asked = question
        self.question.content = f"**{plain(question)}**"
        self.buttons.options = [yes, "Cancel"]
        self.question.visible = self.buttons.visible = True

    def _on_click(self, event: Any) -> None:
        answer = event.target.value
        with self._lock:
            action, cancelled = self._action, self._cancelled
            self._action = self._cancelled = None
        self._hide()
        if action is None:
            return
        if answer == "Cancel":
            if cancelled is not None:
                cancelled()
            return
        action()

    def withdraw(self) -> None:
        """Take the question back (as Cancel would)."""
        with self._lock:
            cancelled = self._cancelled if self._action is not None else None
            self._action = self._cancelled = None
        self._hide()
        if cancelled is not None:
            cancelled()

    def expire(self) -> None:
        """Withdraw a question left unanswered too long (the page's refresh calls this)."""
        with self._lock:
            stale = self._action is not None and time.monotonic() - self._asked_at > self._expires
        if stale:
            self.withdraw()

    def _hide(self) -> None:
        if self.question.visible:
            self.question.visible = self.buttons.visible = False
