"""Updating modules' firmware over the bus (docs/protocol.md §12): what ``asm-flash`` and, later, the studio call.

:func:`update_modules` streams one image to each module in 512-byte SETs of ``firmware.image`` (one reassembled
message each: the board's limit is 640 bytes), has it checked by a SET of ``firmware.install`` to the image's CRC-32,
then waits for the module to come back from its reset and reads the version it runs. Modules are updated at once,
one thread each, so their transfers share the bus (each waits for its own acknowledgements, the bus carries the
others' frames meanwhile). A module without ``firmware.image`` (a Python module: its software is a Python package)
is skipped and said so; one that refuses the image keeps running the old one, which is reported with the reason.
"""

from __future__ import annotations

import struct
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

from asm_py.errors import AsmError, Locked
from asm_py.node import Node

from ._profile import FIRMWARE_STATES, IMAGE_CHUNK
from .firmware_image import check, version_text
from .halts import read_halts
from .names import is_module

Progress = Callable[[str, int, int], None]
"""``progress(module, bytes_written, image_bytes)``, called from the module's update thread after every chunk."""


@dataclass(frozen=True)
class ModuleUpdate:
    """What happened to one module: ``outcome`` is ``updated``, ``skipped``, ``refused``, ``rolled_back`` or
    ``failed``; the versions it ran before and runs now (None: not known), and why, in words."""

    module: str
    outcome: str
    old_version: int | None
    new_version: int | None
    detail: str = ""

    def __str__(self) -> str:
        old = version_text(self.old_version) if self.old_version is not None else "?"
        new = version_text(self.new_version) if self.new_version is not None else "?"
        return f"{self.module}: {self.outcome} ({old} -> {new}){': ' + self.detail if self.detail else ''}"


def update_modules(node: Node, modules: Sequence[str], image: bytes, *, progress: Progress | None = None,
                   timeout: float = 10.0, reboot_timeout: float = 30.0) -> list[ModuleUpdate]:  # fmt: skip
    """Update ``modules`` (node names) to ``image`` (ImageError before anything is sent if it is not a whole image),
    all at once; one :class:`ModuleUpdate` per module, in their order. ``timeout`` bounds each request,
    ``reboot_timeout`` the wait for a module to come back running the new image."""
    info = check(image)
    if not modules:
        return []
    others = [n for n in node.discover() if is_module(n) and n not in modules]  # the robot's other modules too
    walking = _gait_running(node, [*modules, *others], timeout)  # the whole robot: one reset under it fells it
    if walking:  # all or nothing: not one module reset under a robot that walks on the others
        raise GaitRunning(f"not sent: a gait runs on {', '.join(walking)}; an update resets each module it reaches, "
                          "mid-step (the robot falls where it stands): stop the gait first")  # fmt: skip
    with ThreadPoolExecutor(max_workers=len(modules), thread_name_prefix="asm-flash") as pool:
        futures = [pool.submit(_update_one, node, name, image, info.crc, info.version, progress, timeout,
                               reboot_timeout) for name in modules]  # fmt: skip
        return [future.result() for future in futures]


class GaitRunning(ValueError):
    """An update asked for while a gait runs on some of the modules: nothing was sent."""


def _gait_running(node: Node, modules: Sequence[str], timeout: float) -> list[str]:
    """The ``modules`` whose gait service runs now (asm_module.halts); latches are refused module by module below,
    as the board itself refuses a latched update."""
    return read_halts(node, modules, timeout).walking


def _status(node: Node, module: str, timeout: float) -> dict[str, int]:
    return node.lookup(module, "firmware.status", timeout=timeout).get(timeout=timeout)  # pyright: ignore[reportAttributeAccessIssue]


def _update_one(node: Node, module: str, image: bytes, crc: int, version: int, progress: Progress | None,
                timeout: float, reboot_timeout: float) -> ModuleUpdate:  # fmt: skip
    try:
        target = node.lookup(module, "firmware.image", timeout=timeout)
    except LookupError:
        return ModuleUpdate(module, "skipped", None, None, "no firmware.image: not a board (a Python module is "
                            "updated as a package)")  # fmt: skip
    except (AsmError, OSError) as exc:
        return ModuleUpdate(module, "failed", None, None, f"not reached: {exc}")
    old: int | None = None
    try:
        old = _status(node, module, timeout)["running"]
        if node.lookup(module, "estop", timeout=timeout).get(timeout=timeout):  # pyright: ignore[reportAttributeAccessIssue]
            return ModuleUpdate(module, "refused", old, old, "its e-stop is latched: an update ends in a reset, which "
                                "would release it (release the e-stop first)")  # fmt: skip
        for offset in range(0, len(image), IMAGE_CHUNK):
            piece = image[offset : offset + IMAGE_CHUNK]
            target.set(struct.pack("<I", offset) + piece, timeout=timeout)  # pyright: ignore[reportAttributeAccessIssue]
            if progress is not None:
                progress(module, offset + len(piece), len(image))
        install = node.lookup(module, "firmware.install", timeout=timeout)
        try:
            install.set(crc, timeout=timeout)  # pyright: ignore[reportAttributeAccessIssue]
        except ValueError:  # EstopLatched too: latched while the image was written (the board says so, above)
            state = FIRMWARE_STATES[_status(node, module, timeout)["state"]]
            return ModuleUpdate(module, "refused", old, old, f"the module checked the image and refused it ({state})")
    except Locked:  # the board's own guard: a gait started on it (by a group Start) while the image streamed
        return ModuleUpdate(module, "refused", old, old, "a gait was started on it during the update: a module takes "
                            "no part of an update while its gait runs (stop the gait, update again)")  # fmt: skip
    except (AsmError, OSError, ValueError, LookupError) as exc:
        return ModuleUpdate(module, "failed", old, None, f"while writing: {exc}")
    return _come_back(node, module, old, version, timeout, reboot_timeout)


def _come_back(node: Node, module: str, old: int | None, version: int, timeout: float,
               reboot_timeout: float) -> ModuleUpdate:  # fmt: skip
    """Wait for the module to run again after its reset; what it runs says how the update went."""
    time.sleep(0.2)  # the reset follows the install's reply by 0.1 s: do not read the old image's status
    deadline = time.monotonic() + reboot_timeout
    last = ""
    while time.monotonic() < deadline:
        try:
            status = _status(node, module, timeout)
        except (AsmError, OSError, LookupError) as exc:
            last = str(exc)
            time.sleep(0.1)
            continue
        running, state = status["running"], FIRMWARE_STATES[status["state"]]
        if running == version and state == "confirmed":
            return ModuleUpdate(module, "updated", old, running)
        if state == "rolled_back":
            return ModuleUpdate(module, "rolled_back", old, running, "the new image did not confirm itself")
        if state not in ("installed", "trial"):  # back, running something else
            return ModuleUpdate(module, "failed", old, running, f"back running {version_text(running)} ({state})")
        time.sleep(0.1)
    return ModuleUpdate(module, "failed", old, None, f"not back within {reboot_timeout:g} s ({last or 'no answer'})")
