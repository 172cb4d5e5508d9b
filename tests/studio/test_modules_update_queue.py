"""The Modules tab's firmware update without a browser: the page is shared by every tab, so a second image sent
while one is queued or running is refused and said, never run after the first (a review saw a 0.4.0 update from one
tab followed at once by a 0.3.5 one from another: a downgrade, and the first tab never told)."""

from __future__ import annotations

import contextlib
import shutil
import threading
from collections.abc import Callable, Iterator
from types import SimpleNamespace
from typing import Any

import pytest

from web import modules_panel
from web.modules_panel import ModulesPanel

from ..helpers import wait_until

pytestmark = [
    pytest.mark.timeout(120),
    pytest.mark.skipif(shutil.which("arm-none-eabi-gcc") is None, reason="make test installs gcc-arm-none-eabi"),
]


class Control:
    def __init__(self, value: Any = None) -> None:
        self.content = self.value = value

    def on_click(self, callback: Callable[[Any], None]) -> None: ...

    def on_update(self, callback: Callable[[Any], None]) -> None: ...

    def on_upload(self, callback: Callable[[Any], None]) -> None: ...


class Gui:
    def __getattr__(self, name: str) -> Callable[..., Control]:
        return lambda *args, **kwargs: Control(args[1] if len(args) > 1 else None)


def _image(version: int) -> bytes:
    from asm_module.emulated import versioned_image
    from asm_module.firmware_image import image_bytes

    return image_bytes(versioned_image(version))


@pytest.fixture
def panel(monkeypatch) -> Iterator[tuple[ModulesPanel, threading.Event, list[bytes]]]:
    release, sent = threading.Event(), []

    def update_robot(node: Any, names: list[str], image: bytes, **_: Any) -> list[str]:
        sent.append(image)
        release.wait(30)  # the update runs until the test says
        return []

    monkeypatch.setattr(modules_panel, "update_robot", update_robot)
    robot = SimpleNamespace(alive_modules=lambda: [], node=None, lookup=None)
    page = SimpleNamespace(gui=Gui(), robot=robot, safe=lambda f: f, syncing=False,
                           programmatic=contextlib.nullcontext, on_arrival=lambda handle, note: None)  # fmt: skip
    made = ModulesPanel(page)  # type: ignore[arg-type]
    try:
        yield made, release, sent
    finally:
        release.set()
        made.close()


def test_a_second_update_while_one_is_queued_or_running_is_refused_and_said(panel) -> None:
    made, release, sent = panel
    first, second = _image(0x000400), _image(0x000305)
    made._queue_update(first)
    assert "Queued a" in made.update_md.content and "version 0.4.0" in made.update_md.content
    assert wait_until(lambda: len(sent) == 1, timeout=30)  # running now
    made._queue_update(second)
    said = made.update_md.content
    assert said.startswith("⚠ not sent: an update (a ") and "version 0.4.0) is still queued or running" in said
    release.set()
    assert wait_until(lambda: made._pending_update is None, timeout=30)
    assert sent == [first], "the refused image was never sent"
    made._queue_update(second)  # once the first has ended, the next one goes
    assert wait_until(lambda: len(sent) == 2, timeout=30) and sent[1] == second
