"""The Modules tab: the robot's modules as a builder sees them — each one's firmware (``module.info``: language,
version, build, states held), type (``module.type``: what kind of module it says it is, compared with a gait's
robot description before a deploy) and calibration (``joint.calibration``: zero, direction, soft limits) in a
roster, and
per module the calibration edited and applied, or "Set current pose as zero" (docs/protocol.md §9).

A calibration is the module's own: it checks it (a value out of range or not finite is refused, never clamped, and
the refusal is shown here), stores it (a board's flash, a Python module's file) and applies it to every reading and
command; setting it never moves the joint. "Set current pose as zero" keeps the soft limits where they are on the
joint (their raw angles, to 0.01°; 0.01° inward if the module refuses them exact), so only the numbering of angles
moves. "Update firmware" sends an update image (``python -m asm_module.firmware_image ELF OUT``) to every module at
once (asm_module.flasher, what ``asm-flash`` runs), a bar following the bytes written, and says per module what it
ran before and runs now; a file that is not an image is refused at once, before anything is sent.

The callbacks only queue work: one thread (``studio-modules``) talks to the modules, so a slow or silent module
never holds viser's thread pool; it writes the roster and the line under the buttons when it is done.
"""

from __future__ import annotations

import contextlib
import math
import queue
import threading
from typing import TYPE_CHECKING, Any

from asm_module._profile import FIRMWARE_STATES
from asm_module.firmware_image import check
from asm_module.flasher import GaitRunning
from gaits.compatible import read_objects
from gaits.update import RobotHeld, update_robot

from .confirm import plain
from .inputs import number

if TYPE_CHECKING:
    from .page import Page

NONE = "-"
TIMEOUT = 2.0
"""Seconds a module has to answer each read or set."""
LIMIT_MARGIN = 0.01
"""Degrees "Set current pose as zero" moves the soft limits inward when the module refuses them exact (_zero_here)."""


def _version(info: dict[str, Any]) -> str:
    v = int(info["version"])
    language = {0: "Python", 1: "C"}.get(int(info["language"]), f"language {info['language']}")
    return f"{language} {v >> 16 & 0xFF}.{v >> 8 & 0xFF}.{v & 0xFF}"


UPDATE_OUTCOMES = {"interrupted": "interrupted (the image was not all written)", "refused": "refused the image",
                   "rolled_back": "rolled back (the new image did not confirm itself)",
                   "flash_error": "failed: flash error"}  # fmt: skip
"""firmware.status states that say the last update did not happen, as the roster words them."""


def update_note(status: dict[str, Any] | None) -> str:
    """What a module's firmware.status says of its last update when it did not happen (after a tool killed mid-update,
    the tab otherwise only said "not reachable"); "" otherwise."""
    if not status or not 0 <= int(status.get("state", -1)) < len(FIRMWARE_STATES):
        return ""
    said = UPDATE_OUTCOMES.get(FIRMWARE_STATES[int(status["state"])])
    return f", last update {said}" if said else ""


def roster_markdown(names: list[str], infos: dict[str, Any], calibrations: dict[str, Any],
                    angles: dict[str, float], types: dict[str, str] | None = None,
                    statuses: dict[str, Any] | None = None) -> str:  # fmt: skip
    """The roster as a markdown table, one row per module (narrow enough for the side panel); "—" for what a module
    did not say (a type as written: a board's port may set any bytes)."""
    types, statuses = types or {}, statuses or {}
    rows = ["| module | firmware | type | calibration | angle |", "|---" * 5 + "|"]
    for name in names:
        info, c, angle = infos.get(name), calibrations.get(name), angles.get(name)
        firmware = f"{_version(info)} `{int(info['build']):08x}` {info['max_states']} states" if info else "—"
        if info and int(info.get("tick_cycles", 0)) > 0:  # a board that times its own tick: its CPU budget in use
            firmware += f", tick {int(info['tick_cycles']):,} cycles, stack {int(info['stack_bytes']):,} B"
        firmware += update_note(statuses.get(name))
        calibration = f"{c['zero']:g}° {int(c['direction']):+d} {c['min']:g}..{c['max']:g}°" if c else "—"
        shown = f"{angle:.1f}°" if angle is not None else "—"
        kind = plain(types[name]) if types.get(name) else "—"
        rows.append(f"| {name} | {firmware} | {kind} | {calibration} | {shown} |")
    return "\n".join(rows) + "\n\nCalibration: zero, direction, soft limits."


def refusal_text(name: str, values: dict[str, Any], exc: Exception) -> str:
    """Why ``name`` refused the calibration ``values``, field by field: with min < max checked here already, what is
    left is the module's rule that each soft limit's raw angle (zero + direction·limit) lies within the joint's
    hardware range, which only the module knows."""
    raw = sorted(values["zero"] + values["direction"] * values[k] for k in ("min", "max"))
    said = str(exc).split(": ", 1)[-1].strip()
    return (f"{name} refused the calibration{f' ({said})' if said else ''}: Soft min {values['min']:g}° and Soft "
            f"max {values['max']:g}° are raw {raw[0]:g}..{raw[1]:g}° with Zero {values['zero']:g}° and direction "
            f"{values['direction']:+d}, which must lie within the joint's hardware range (a reset calibration "
            "shows it as the soft limits)")  # fmt: skip


class ModulesPanel:
    """The Modules tab of ``page``; see the module docstring. ``close`` stops its thread."""

    def __init__(self, page: Page) -> None:
        self.page = page
        gui = page.gui
        gui.add_markdown("Each module's firmware and calibration, read from the module itself. A calibration is "
                         "stored in the module and applied by it: angle = direction · (raw − zero).")  # fmt: skip
        self.read_button = gui.add_button("Read modules")
        self.roster_md = gui.add_markdown("Not read yet: **Read modules** asks every module that answers.")
        self.module = gui.add_dropdown("Calibrate module", [NONE])
        self.zero = number(gui, "Zero (raw °)", 0.0, step=0.1)
        self.direction = gui.add_dropdown("Joint direction", ["+1", "-1"])
        self.low = number(gui, "Soft min (°)", -90.0, step=0.1)
        self.high = number(gui, "Soft max (°)", 90.0, step=0.1)
        self.apply_button = gui.add_button("Apply calibration")
        self.zero_button = gui.add_button("Set current pose as zero")
        self.line = gui.add_markdown("")
        gui.add_markdown("**Firmware update** over the bus (docs/protocol.md §12): every module with the update "
                         "objects takes the image; Python modules are skipped (their software is a Python "
                         "package).")  # fmt: skip
        self.upload = gui.add_upload_button("Update firmware (.img)", mime_type=".img")
        self.progress = gui.add_progress_bar(0.0)
        self.update_md = gui.add_markdown("")
        self._lock = threading.Lock()
        self._calibrations: dict[str, dict[str, Any]] = {}
        """The calibrations last read, by module (the worker writes, the module picker reads)."""
        self._pending_update: str | None = None
        """The update queued or running (said to whoever sends another meanwhile); None when there is none."""
        self._jobs: queue.Queue[tuple[str, Any] | None] = queue.Queue()
        self.read_button.on_click(page.safe(lambda _: self._jobs.put(("read", None))))
        self.apply_button.on_click(page.safe(lambda _: self._queue_apply()))
        self.zero_button.on_click(page.safe(lambda _: self._queue_module("zero")))
        page.on_arrival(self.module, lambda _: self._show_selected(on_loop=True))  # a user's pick
        self.upload.on_upload(page.safe(lambda e: self._queue_update(bytes(e.target.value.content))))
        self._thread = threading.Thread(target=self._run, name="studio-modules", daemon=True)
        self._thread.start()

    # -- the callbacks: they only queue work or take the lock -------------------------------------------------------

    def _selected(self) -> str:
        name = str(self.module.value)
        if name == NONE:
            raise ValueError("pick a module first (Read modules lists them)")
        return name

    def _queue_module(self, job: str) -> None:
        self._jobs.put((job, self._selected()))

    def _queue_apply(self) -> None:
        values = {"zero": float(self.zero.value), "direction": 1 if self.direction.value == "+1" else -1,
                  "min": float(self.low.value), "max": float(self.high.value)}  # fmt: skip
        if not all(math.isfinite(values[k]) for k in ("zero", "min", "max")):
            raise ValueError(f"a calibration's numbers are finite, not {values}")
        self._jobs.put(("apply", (self._selected(), values)))

    def _queue_update(self, image: bytes) -> None:
        """A file that is not an update image is refused at once, under the update's own button (it was said by the
        worker, after whatever it was doing, on the calibration's line)."""
        try:
            check(image)
        except ValueError as exc:
            self.update_md.content = f"⚠ not sent: {exc}"
            return
        with self._lock:  # one update at a time, from whichever tab: a second one would silently follow the first
            if self._pending_update is not None:
                self.update_md.content = (f"⚠ not sent: an update ({self._pending_update}) is still queued or "
                                          "running; wait for its result, then send this one")  # fmt: skip
                return
            self._pending_update = f"a {len(image):,}-byte image of version {check(image).version_text}"
        self.update_md.content = f"Queued {self._pending_update} …"
        self._jobs.put(("update", image))

    def _show_selected(self, *, on_loop: bool = False) -> None:
        """The picked module's calibration into the fields (as last read). A user's pick fills them on viser's loop
        as it arrives (``on_loop``), before any later message of that tab sets a field or clicks Apply: filled
        later on viser's pool, the fill put back a zero typed right after the pick (m3 calibrated with zero 0°, a
        fresh-clone run), and an Apply the pool ran first took the last module's direction and limits (its
        review). On the loop no page lock is taken (none of these fields has a callback to silence)."""
        with self._lock:
            c = self._calibrations.get(str(self.module.value))
        if c is None or (not on_loop and self.page.syncing):
            return
        shown = [(self.zero, float(c["zero"])), (self.direction, "+1" if int(c["direction"]) > 0 else "-1"),
                 (self.low, float(c["min"])), (self.high, float(c["max"]))]  # fmt: skip
        with contextlib.nullcontext() if on_loop else self.page.programmatic():
            for field, value in shown:
                field.value = value

    # -- the worker ---------------------------------------------------------------------------------------------------

    def _run(self) -> None:
        while (job := self._jobs.get()) is not None:
            kind, argument = job
            try:
                if kind == "read":
                    self._read()
                elif kind == "apply":
                    self._apply(*argument)
                elif kind == "zero":
                    self._zero_here(argument)
                elif kind == "update":
                    try:
                        self._update(argument)
                    finally:
                        with self._lock:
                            self._pending_update = None
            except (
                GaitRunning,
                RobotHeld,
            ) as exc:  # under the update's own button, where the user looks for its result
                self.update_md.content = f"⚠ {exc}"
            except Exception as exc:  # a refusal, a silent module: said under the buttons, the worker goes on
                self.line.content = f"⚠ {exc}"

    def _read(self) -> None:
        robot = self.page.robot
        names = sorted(robot.alive_modules(), key=lambda n: int(n[1:]))
        self.line.content = f"Reading {len(names)} modules …"
        infos = read_objects(robot.lookup, names, "module.info", TIMEOUT)
        types = read_objects(robot.lookup, names, "module.type", TIMEOUT)
        calibrations = read_objects(robot.lookup, names, "joint.calibration", TIMEOUT)
        angles = {name: float(value) for name, value in read_objects(robot.lookup, names, "joint.angle",
                                                                      TIMEOUT).items()}  # fmt: skip
        with self._lock:
            self._calibrations = calibrations
        statuses = read_objects(robot.lookup, names, "firmware.status", TIMEOUT)  # Python modules have none
        roster = roster_markdown(names, infos, calibrations, angles, types, statuses) if names else "No module answers."
        self.roster_md.content = roster
        with self.page.programmatic():
            chosen = self.module.value
            self.module.options = names or [NONE]
            self.module.value = chosen if chosen in names else (names[0] if names else NONE)
        self._show_selected()
        self.line.content = f"Read {len(names)} modules: {len(infos)} said their firmware, {len(calibrations)} " \
                            "their calibration."  # fmt: skip

    def _apply(self, name: str, values: dict[str, Any]) -> None:
        if not values["min"] < values["max"]:
            raise ValueError(f"Soft min ({values['min']:g}°) must be below Soft max ({values['max']:g}°)")
        try:
            self.page.robot.lookup(name, "joint.calibration", timeout=TIMEOUT).set(values, wait=True, timeout=TIMEOUT)
        except ValueError as exc:  # a board's refusal carries no words: name the fields that can break its rule
            raise ValueError(refusal_text(name, values, exc)) from None
        self._read()
        self.line.content = (f"{name} calibrated: zero {values['zero']:g}°, direction {values['direction']:+d}, "
                             f"soft limits {values['min']:g}..{values['max']:g}° (stored in the module)")  # fmt: skip

    def _zero_here(self, name: str) -> None:
        """The joint's raw angle now becomes its zero; the soft limits stay where they are on the joint."""
        robot = self.page.robot
        calibration = robot.lookup(name, "joint.calibration", timeout=TIMEOUT)
        c = dict(calibration.get(timeout=TIMEOUT))
        angle = float(robot.lookup(name, "joint.angle", timeout=TIMEOUT).get(timeout=TIMEOUT))
        raw = round(c["zero"] + c["direction"] * angle, 2)
        shift = c["direction"] * (raw - c["zero"])  # the angle the new zero reads 0 at
        # the limits moved by as much, to 0.01°; when the module refuses that (float32 rounding put a limit's raw
        # angle a hair past the hardware's range: it refuses, never clamps), 0.01° inward — once, not at every press
        for margin in (0.0, LIMIT_MARGIN):
            values = {"zero": raw, "direction": c["direction"], "min": round(c["min"] - shift + margin, 2),
                      "max": round(c["max"] - shift - margin, 2)}  # fmt: skip
            try:
                calibration.set(values, wait=True, timeout=TIMEOUT)
                break
            except ValueError:
                if margin:
                    raise
        self._read()
        self.line.content = f"{name}: its pose now is its zero (raw {raw:.2f}°; it was at {angle:.2f}°)"

    def _update(self, image: bytes) -> None:
        """Every answering module to ``image`` at once, the robot held against deploys (gaits.update), the bar
        following the bytes written."""
        check(image)  # not an update image: said before anything is sent
        robot = self.page.robot
        names = sorted(robot.alive_modules(), key=lambda n: int(n[1:]))
        written: dict[str, int] = {}
        total = len(image) * max(1, len(names))

        def progress(module: str, done: int, size: int) -> None:
            with self._lock:
                written[module] = done
                self.progress.value = 100.0 * sum(written.values()) / total

        self.progress.value = 0.0
        self.update_md.content = f"Updating {len(names)} modules with a {len(image):,}-byte image …"
        # patient: a module behind a busy bus or a slow host answers late, and a failed update is redone by hand
        results = update_robot(robot.node, names, image, progress=progress, timeout=30.0, reboot_timeout=120.0)
        self.progress.value = 100.0
        self.update_md.content = "  \n".join(str(result) for result in results)
        self._read()

    def refresh(self) -> None:
        """Read the roster again (queued: called from another panel's thread)."""
        self._jobs.put(("read", None))

    def close(self) -> None:
        self._jobs.put(None)
        self._thread.join(timeout=10)
