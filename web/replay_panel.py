"""The Replay tab: open an MCAP recording (one in the recordings folder, or uploaded) and play it in the 3D view —
the same page, no robot needed — with a timeline (play, pause, scrub, step, speed), a plot of a recorded attribute
of every module up to the replay time, the modules' last values and the run's events (e-stops, deploys, drives).
"Leave replay" (or the robot bar's Live) returns to the live robot.

Opening reads the whole file: that runs on this panel's own thread (``replay-open``), so the callbacks only queue
a request; the replay clock is the ReplaySource's loop (web/replay.py); the page's 20 Hz refresh moves the
timeline, the plot and the lists from the replay time, and the render thread draws the frames.
"""

from __future__ import annotations

import logging
import queue
import threading
from pathlib import Path
from typing import TYPE_CHECKING, Any

from viser._messages import GuiSliderMark

from .confirm import plain
from .inputs import slider
from .monitor import SeriesPlot, format_value, plot_file
from .recording import Recording, RecordingError, open_recording, read_bytes, utf8_name, utf8_text
from .replay import SPEEDS, ReplaySource, last_values, plot_data, plot_samples

if TYPE_CHECKING:
    from .page import Page

log = logging.getLogger("asm_studio.replay")
NO_FILE = "-"
PLOT_WINDOW = 30.0
"""Seconds of recorded values the replay plot shows, up to the replay time."""
PLOTTED_MODULES = 8
"""The replay plot shows the chosen attribute of at most this many modules (the first ones)."""
SPEED_LABELS = [f"{s:g}x" for s in SPEEDS]


MARKS = {"e-stop": "E", "group": "G", "status": "S"}
"""The letter an event of each kind has on the timeline."""
MAX_MARKS = 60
"""Events marked on the timeline at most (beyond, the list says them): marks closer than a letter are unreadable."""


def timeline_marks(recording: Recording) -> tuple[GuiSliderMark, ...]:
    """The timeline's marks: its ends, and a letter at each event (the first MAX_MARKS)."""
    end = max(0.01, round(recording.duration, 2))
    marks = [GuiSliderMark(value=0.0, label="0"), GuiSliderMark(value=end, label=f"{end:g}")]
    marks += [GuiSliderMark(value=round(e.time, 2), label=MARKS.get(e.kind, "?")) for e in recording.events[:MAX_MARKS]]
    return tuple(marks)


def chosen_file(folder: Path, name: str) -> Path:
    """The recordings folder's file ``name`` (what the dropdown sent): a plain ``.mcap`` file name, nothing that
    leaves the folder (a page's value is a client's input)."""
    if not name.endswith(".mcap") or Path(name).name != name or name.startswith("."):
        raise ValueError(f"{name!r} is not an MCAP file of the recordings folder")
    return folder / name


def _shown(exc: Exception) -> str:
    """Why a file was not opened, as page text: it may quote a file name that is not UTF-8, or markup."""
    return plain(utf8_text(str(exc)))


class ReplayPanel:
    """The Replay tab of ``page``; its plot is drawn in the page's plots panel."""

    def __init__(self, page: Page, plots_tab: Any) -> None:
        self.page = page
        gui = page.gui
        self.source: ReplaySource | None = None
        self._plotted: tuple[float, list[tuple[str, str]]] | None = None
        self._plotting = threading.Lock()
        """One refresh's plot at a time: the page's refresh thread marked a time plotted before its plot was shown,
        and a refresh from elsewhere that found it marked returned with the plot not yet there (test_replay)."""
        """The replay time and attributes last plotted."""
        self._opening: queue.Queue[tuple[str, Any] | None] = queue.Queue()
        self.file = gui.add_dropdown("Recording", [NO_FILE], hint="an MCAP file of the recordings folder")
        open_buttons = gui.add_button_group("Recordings", ["Open", "List files"])
        open_buttons.on_click(page.safe(self._on_open))
        self.upload = gui.add_upload_button("Upload an MCAP file", mime_type=".mcap",
                                            hint="replay a recording from this computer")  # fmt: skip
        self.upload.on_upload(page.safe(self._on_upload))
        self.line = gui.add_markdown("No recording open.")
        self.play = gui.add_button_group("Replay", ["▶ Play", "Pause", "Leave replay"])
        self.play.on_click(page.safe(self._on_play))
        self.timeline = slider(gui, "Replay time (s)", min=0.0, max=1.0, initial_value=0.0)
        self.timeline.on_update(page.safe(self._on_seek))
        steps = gui.add_button_group("Replay step", ["◀ frame", "frame ▶"])
        steps.on_click(page.safe(lambda e: self._request("step", -1 if "◀" in e.target.value else 1)))
        self.speed = gui.add_dropdown("Replay speed", SPEED_LABELS, initial_value="1x")
        self.speed.on_update(page.safe(self._on_speed))
        self.attribute = gui.add_dropdown("Replay plot", [NO_FILE], hint="the recorded attribute plotted, per module")
        export = gui.add_button_group("Export the replay plot", ["Export CSV", "Export MCAP"],
                                      hint="download the recorded values the replay plot shows")  # fmt: skip
        export.on_click(page.safe(self._export))
        self.events = gui.add_markdown("")
        self.roster = gui.add_markdown("")
        self.plot = SeriesPlot(gui, plots_tab, title="Replay: recorded values", y_label="value", aspect=3.0)
        self._thread = threading.Thread(target=self._open_loop, name="replay-open", daemon=True)
        self._thread.start()
        self.list_files()

    # -- callbacks: queue, never read a file or wait ---------------------------------------------------------------

    def _on_open(self, event: Any) -> None:
        if event.target.value == "List files":
            self._opening.put(("list", None))
        elif self.file.value == NO_FILE:
            raise ValueError("no recording chosen: pick one of the recordings folder (List files), or upload one")
        else:
            self.open_path(chosen_file(self.page.recordings_folder, str(self.file.value)))

    def open_path(self, path: Path) -> None:
        """Open ``path`` and replay it (read on the panel's thread; the line says how it went)."""
        self.line.content = f"Opening {plain(utf8_text(path.name))} …"
        self._opening.put(("path", path))

    def _on_upload(self, event: Any) -> None:
        uploaded = event.target.value
        self.line.content = f"Opening {plain(str(uploaded.name))} …"
        self._opening.put(("bytes", (uploaded.name, uploaded.content)))

    def _request(self, kind: str, value: Any = None) -> None:
        if self.source is None:
            raise ValueError("no recording open: open one first")
        self.source.request(kind, value)

    def _on_play(self, event: Any) -> None:
        action = event.target.value
        if action == "Leave replay":
            self.leave()
        else:
            if self.source is not None and self.page.view.source != "replay":
                self.page.emit("show", "replay")  # back in the replay after a look at the live robot
            self._request("play" if "Play" in action else "pause")

    def _on_seek(self, event: Any) -> None:
        """A user's drag or typed time (the refresh moving the slider is not one): a time outside the recording is
        refused and said, never moved to its start or end (the page's own box refuses it first: web/page_script.py);
        the refresh puts the slider back where the replay is."""
        source = self.source
        if self.page.syncing or source is None:
            return
        t = float(event.target.value)
        if not 0.0 <= t <= max(source.clock.duration, float(self.timeline.max)):  # its end mark: rounded up
            raise ValueError(f"replay time {t:g} s refused: {plain(source.recording.name)} runs from 0 to "
                             f"{source.clock.duration:.2f} s")  # fmt: skip
        self._request("seek", t)

    def _on_speed(self, event: Any) -> None:
        label = str(event.target.value)
        if label not in SPEED_LABELS:
            raise ValueError(f"replay speed {label!r} is not one of {', '.join(SPEED_LABELS)}")
        if self.source is not None:
            self._request("speed", SPEEDS[SPEED_LABELS.index(label)])

    def _export(self, event: Any) -> None:
        """Download the recorded samples the replay plot shows (its window up to the replay time) as CSV or MCAP, to
        the tab that asked: each series' own times and the file's values, exactly (nothing interpolated or held)."""
        source = self.source
        if source is None:
            raise ValueError("no recording open: open one, then export its plot")
        labels, samples = plot_samples(source.recording, self.keys(), source.time(), PLOT_WINDOW)
        if not labels:
            raise ValueError(f"the replay plot shows nothing: {plain(str(self.attribute.value))} has no numbers "
                             "recorded")  # fmt: skip
        kind = "csv" if event.target.value == "Export CSV" else "mcap"
        content = plot_file(kind, labels, samples)
        event.client.send_file_download(f"replay-plot.{kind}", content, save_immediately=True)

    # -- the panel's thread ---------------------------------------------------------------------------------------

    def _open_loop(self) -> None:
        while (request := self._opening.get()) is not None:
            kind, value = request
            try:
                if kind == "list":
                    self.list_files()
                    continue
                recording = open_recording(value) if kind == "path" else read_bytes(value[1], value[0])
            except RecordingError as exc:
                self.line.content = f"⚠ Not opened: {_shown(exc)}"
                self.page.notify("Replay", _shown(exc), error=True)
                log.info("not replayed: %s", exc)
                continue
            except Exception as exc:  # a bug must not end the thread: said like a refusal
                log.exception("opening a recording failed")
                self.line.content = f"⚠ Not opened: {_shown(exc)}"
                continue
            self.start(recording)
            del recording  # this loop's frame waits for the next request: it must not keep the last one alive

    def list_files(self) -> None:
        """The recordings folder's MCAP files, newest first."""
        folder = self.page.recordings_folder
        try:
            files = sorted(folder.glob("*.mcap"), key=lambda p: p.stat().st_mtime, reverse=True)
        except OSError:
            files = []
        names = [p.name for p in files if utf8_name(p.name)]
        if len(names) < len(files):  # never sent to the page (see utf8_name); said, so the file is not just missing
            self.line.content = (f"⚠ {len(files) - len(names)} file(s) of the recordings folder have names that are "
                                 "not UTF-8 and are not listed: rename them to replay them")  # fmt: skip
        names = names or [NO_FILE]
        with self.page.programmatic():
            if list(self.file.options) != names:
                self.file.options = names

    def start(self, recording: Recording) -> None:
        """Replay ``recording`` from its start, paused, in the 3D view."""
        old, self.source = self.source, ReplaySource(recording)
        self._plotted = None
        source = self.source
        with self.page.programmatic():
            self.timeline.max = max(0.01, round(recording.duration, 2))
            self.timeline.value = 0.0
            self.timeline._marks = timeline_marks(recording)  # viser has no public setter for a slider's marks
            self.speed.value = "1x"
            objects = recording.objects() or [NO_FILE]
            self.attribute.options = objects
            self.attribute.value = "joint.angle" if "joint.angle" in objects else objects[0]
        self.page.view.replay = source
        self.page.emit("show", "replay")
        if old is not None:
            old.close()
        kept = "" if recording.complete else " — its writer did not finish it: replayed up to its last whole chunk"
        if recording.jumps:
            where, by = recording.jumps[0]
            more = f" (and {len(recording.jumps) - 1} more times)" if len(recording.jumps) > 1 else ""
            kept += (f" — ⚠ its log times jump by {by:,.0f} s at {where:.2f} s{more}: a recorder's clock stepped, or "
                     "a message's time is wrong; the timeline spans the gap")  # fmt: skip
        if recording.damaged and recording.complete:  # a torn last chunk of an unfinished file is said above
            kept += (f" — ⚠ {recording.damaged} damaged chunk{'s' if recording.damaged > 1 else ''} skipped: the "
                     "file is corrupt, their messages are missing")  # fmt: skip
        warning = f"  \n⚠ {plain(source.error)}" if source.error else ""
        self.line.content = (f"**{plain(recording.name)}**: {recording.duration:.2f} s, {len(recording.frames)} poses, "
                             f"{len(recording.series)} attributes of {len(recording.nodes())} nodes, "
                             f"{len(recording.events)} events{kept}{warning}")  # fmt: skip
        replaced = "" if old is None else (f" (it replaces {plain(old.recording.name)}: a studio has one replay, "
                                           "every tab shows it)")  # fmt: skip
        self.page.notify("Replay", f"{plain(recording.name)} opened: Play, or drag the replay time{replaced}")
        log.info("replaying %s: %.2f s, %d poses", recording.name, recording.duration, len(recording.frames))

    def leave(self) -> None:
        """Back to the live robot; the recording is closed."""
        source, self.source = self.source, None
        self.page.emit("show", "live")
        if source is not None:
            source.close()
            if self.page.view.replay is source:  # the scene held it: the recording (GBs for hours) stayed in memory
                self.page.view.replay = None
        self.line.content = "No recording open."
        self.events.content = self.roster.content = ""
        self.plot.show([], (), 0.0, PLOT_WINDOW)
        self._plotted = None

    # -- the page's refresh ---------------------------------------------------------------------------------------

    def keys(self) -> list[tuple[str, str]]:
        """The (node, object) pairs the replay plot shows."""
        source = self.source
        if source is None:
            return []
        nodes = [n for n in source.recording.nodes() if (n, str(self.attribute.value)) in source.recording.series]
        return [(n, str(self.attribute.value)) for n in nodes[:PLOTTED_MODULES]]

    def refresh(self) -> None:
        """Timeline, plot, events and values at the replay time (the page's 20 Hz refresh)."""
        source = self.source
        if source is None:
            return
        recording, (t, playing) = source.recording, source.shown()
        with self.page.programmatic():
            shown = round(t, 2)
            if abs(self.timeline.value - shown) >= 0.005:
                self.timeline.value = shown
        keys = self.keys()
        with self._plotting:
            if (t, keys) != self._plotted:  # paused: the plot is not sent again 20 times a second
                labels, data = plot_data(recording, keys, t, PLOT_WINDOW)
                self.plot.show(labels, data, t, PLOT_WINDOW)  # seconds before the replay time, as the live plots
                self._plotted = (t, keys)
        state = "▶ playing" if playing else ("■ ended" if t >= source.clock.duration else "paused")
        events = "  \n".join(f"{'●' if e.time <= t else '○'} {e.time:7.2f} s · {plain(e.text)}"
                              for e in recording.events[:40])  # fmt: skip
        more = f"  \n… and {len(recording.events) - 40} more" if len(recording.events) > 40 else ""
        self._set(self.events, f"**t = {t:.2f} s** of {source.clock.duration:.2f} s · {state} · "
                  f"{source.clock.speed:g}x  \n**Events** (● passed; on the timeline: E e-stop, G deploy or drive, S "
                  f"e-stop latched or released)  \n{events or 'none'}{more}")  # fmt: skip
        values = last_values(recording, t)
        rows = [plain(node) + " " + ", ".join(f"{plain(obj)} = **{plain(format_value(v))}**"
                                              for obj, v in sorted(objs.items())[:4])
                for node, objs in sorted(values.items(), key=lambda kv: (len(kv[0]), kv[0]))]  # fmt: skip
        self._set(self.roster, "**Modules in the recording** (last values at t)  \n" + "  \n".join(rows[:32]))

    @staticmethod
    def _set(handle: Any, content: str) -> None:
        if handle.content != content:
            handle.content = content

    def close(self) -> None:
        self._opening.put(None)
        self._thread.join(5)
        if self.source is not None:
            self.source.close()
