"""The one object a panel talks to: the page's controls and notices, the edited gait, the preview, and the robot.

Panels (web/editor.py, preview_panel.py, deploy_panel.py, drive.py, monitor_panel.py, robot_bar.py) are built with a
:class:`Page` and use nothing else of the dashboard: what one panel's action means to another (a deploy makes the
view go Live and plots the modules' angles; a rebuilt robot drops modules from the plots) is a page *event* the
dashboard wires (``on``/``emit``), so no panel imports another or the dashboard. The robot is reached through
``page.robot`` (web/link.py), which the page swaps when the user picks another robot — a panel asks for it at each
use and never keeps it.

Every callback of a control is wrapped by ``safe`` (a failure becomes a notice, never a dead server) and either
takes the document's lock or queues a request to the preview loop, because viser runs callbacks on a thread pool.
"""

from __future__ import annotations

import collections
import contextlib
import functools
import logging
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from types import SimpleNamespace
from typing import Any, Literal, Protocol

import viser

from asm_module.feed import RobotStatus
from gaits.model import Gait
from gaits.terrain import FLAT, Terrain

from .confirm import unplain
from .document import GaitDocument
from .link import RobotLink
from .preview import PreviewLoop
from .scene_view import SceneView

log = logging.getLogger("asm_studio.web")
TOAST_SECONDS = 6.0
Event = Literal["deployed", "modules_removed", "plotted", "show", "attach", "relinked", "pick", "adopt"]
"""What panels tell each other through the page: ``deployed(gait)`` (started on the robot),
``modules_removed(names)`` (gone with a rebuilt robot), ``plotted()`` (a live plot got a series), ``show(source)``
("preview" or "live" asked for), ``attach(robot)`` (another robot asked for), ``relinked()`` (the page now commands
another robot), ``pick(module_id)`` (clicked in the 3D view), ``adopt(gait, text)`` (a tuned gait becomes the edited
one, ``text`` its file with its provenance)."""


class Backend(Protocol):
    """What the page needs of the backend that builds it (server.studio.Studio is one): the page imports nothing
    of server/, so the two never import each other."""

    gait: Gait
    """The gait opened at start."""
    gait_text: str | None
    """The text of its file (a download keeps its comments)."""
    gait_path: Path | None
    """Its file (a robot file the gait names lies beside it)."""
    c_modules: str | None
    """The simulated modules that run the C runtime ("odd", "even", "all", "1,3,5"), in the robot and the preview."""
    layout_file: Path | None
    """Where the page keeps its last layout across restarts of the studio (web/layout_store.py); None: nowhere."""

    @property
    def simulated(self) -> bool:
        """The robot shown is simulated (it publishes poses); else a real bus."""
        ...

    def connect(self, robot: str) -> RobotLink:
        """A new link to robot ``robot``."""
        ...

    def robots(self) -> list[RobotStatus]:
        """The robots on the network now."""
        ...

    def ensure_robot(self, gait: Gait, terrain: Terrain = FLAT) -> str | None:
        """Make a simulated robot the one ``gait`` describes, on ``terrain``; a message when it was rebuilt."""
        ...

    def on_notice(self, callback: Callable[[str, str, bool], None]) -> None:
        """Call ``callback(title, text, error)`` with what the backend has to say."""
        ...

    @property
    def recordings_folder(self) -> Path:
        """Where the Record button writes its MCAP files: the Replay tab lists them."""
        ...

    def start_recording(self, robot: str, gait_name: str, gait_text: str, said: Callable[[str, bool], None]) -> None:
        """Record ``robot`` to MCAP with the gait embedded; ``said(line, error)`` once it records (or cannot)."""
        ...

    def stop_recording(self, said: Callable[[str, bool], None]) -> None:
        """Finish the recording; ``said(line, error)`` says what was written."""
        ...


class Page:
    """See the module docstring."""

    def __init__(
        self,
        server: viser.ViserServer,
        backend: Backend,
        link: RobotLink,
        doc: GaitDocument,
        loop: PreviewLoop,
        view: SceneView,
    ) -> None:
        self.server = server
        self.gui = server.gui
        self._backend = backend
        self.doc = doc
        self.loop = loop
        """The preview loop: panels only ``request`` of it and read what it recorded (it owns the simulation)."""
        self.view = view
        self._link = link
        self._listeners: dict[str, list[Callable[..., None]]] = {}
        self._programmatic = threading.local()
        self._sync_lock = threading.RLock()
        self._last_toast: tuple[tuple[str, str], float] | None = None
        self._acting = threading.local()
        self._arrived: collections.deque[tuple[Callable[..., None], Any, Any, Any]] = collections.deque()
        """Edits kept by :meth:`on_edit` on viser's loop and not applied yet: (apply, tab, value, context or error)."""
        self._applying = threading.Lock()
        self._arriving = threading.local()  # .client: the tab whose edit's context is read (see arriving_client)
        self._kept: dict[int, tuple[Any, Callable[..., Any]]] = {}  # id(keep callback) → (handle, keep callback)
        """The controls whose edits :meth:`on_edit` keeps, and its keeping callback (see :meth:`close`)."""
        self.last_editor: int | None = None
        """The client (browser tab) whose edit of the gait came last."""
        self.toasts = 0
        """Toasts sent (a repeat within TOAST_SECONDS is not)."""
        self.status: Any = None
        """The status line (a markdown handle, the robot bar's); notices land here."""

    # -- the robot ------------------------------------------------------------------------------------------------

    @property
    def robot(self) -> RobotLink:
        """The link to the robot the page shows and commands now (swapped by ``relink``)."""
        return self._link

    def relink(self, link: RobotLink) -> RobotLink:
        """Command ``link``'s robot from now on; returns the old link (the caller closes it)."""
        old, self._link = self._link, link
        return old

    @property
    def simulated(self) -> bool:
        """The robot is simulated (it publishes poses); else a real bus."""
        return self._backend.simulated

    def robots(self) -> list[RobotStatus]:
        """The robots on the network now (a round trip: not from a refresh)."""
        return self._backend.robots()

    def ensure_robot(self, gait: Gait) -> str | None:
        """Make a simulated robot the one ``gait`` describes, on the preview's ground (the Preview tab's picker);
        a message when it was rebuilt."""
        return self._backend.ensure_robot(gait, self.loop.terrain)

    @property
    def recordings_folder(self) -> Path:
        """Where the Record button writes its files (the Replay tab lists them)."""
        return self._backend.recordings_folder

    @property
    def layout_file(self) -> Path | None:
        """Where the page keeps its last layout (the backend's choice)."""
        return getattr(self._backend, "layout_file", None)

    @property
    def recorder(self) -> Backend:
        """The backend, for the Record button (start_recording, stop_recording)."""
        return self._backend

    # -- events between panels ------------------------------------------------------------------------------------

    def on(self, event: Event, callback: Callable[..., None]) -> None:
        self._listeners.setdefault(event, []).append(callback)

    def emit(self, event: Event, *args: Any) -> None:
        for callback in self._listeners.get(event, ()):
            callback(*args)

    # -- notices --------------------------------------------------------------------------------------------------

    def safe(self, fn: Callable[[Any], Any]) -> Callable[[Any], None]:
        """A callback whose failure is shown as a notification instead of escaping into viser's thread pool."""

        @functools.wraps(fn)
        def wrapped(event: Any) -> None:
            acting = getattr(self._acting, "client", None)  # a safe callback inside another (in_turn's edits)
            self._acting.client = getattr(event, "client", None)
            try:
                fn(event)
            except Exception as exc:
                log.info("action failed: %s", exc)
                self.notify("Error", str(exc), error=True)
            finally:
                self._acting.client = acting

        return wrapped

    def on_edit(
        self,
        handle: Any,
        apply: Callable[..., None],
        *,
        click: bool = False,
        context: Callable[[], Any] | None = None,
    ) -> Callable[[], None]:
        """Call ``apply`` with each value a user gives ``handle``, as it arrived, one at a time in the order the page's
        edits arrived, whichever control they are of (and with a value set from the server outside
        :meth:`programmatic`, as the page's own actions and tests do); ``context`` (read as the value arrives,
        passed after it): what the value is of, e.g. the selected state. Returns what forgets ``handle`` (for a
        control removed from the page before the page closes).

        viser sets a control's value on its event loop and runs its callbacks later on a thread pool, so a callback
        reading ``handle.value`` may read what another callback's resync put there in between: "Add (copy of
        forward)" resynced the Sequence field to the document's empty sequence after the sequence typed next had
        arrived, and that sequence was lost. A coroutine callback runs on the loop right after viser sets the value,
        so the value (with its tab and its context) is kept there, and the pool's callback applies what was kept:
        everything kept so far, in arrival order, since the pool may run a later edit's callback first (a neighbour
        typed, then its state: the state's callback, run first, was undone by the neighbour's older view)."""

        def read_context(client_id: int | None) -> tuple[Any, ...]:
            if context is None:
                return ()
            self._arriving.client = client_id
            try:
                return (context(),)
            finally:
                self._arriving.client = None

        async def keep(event: Any) -> None:
            if event.client_id is not None:
                try:
                    kept: tuple[Any, ...] | BaseException = read_context(event.client_id)
                except Exception as exc:  # told to that tab when applied, not lost on viser's loop
                    kept = exc
                self._arrived.append((apply, event.client, event.target.value, kept))

        def run(event: Any) -> None:
            if event.client_id is None:  # set from the server, synchronously in the setting thread
                if not self.syncing:
                    self.safe(lambda _: apply(event.target.value, *read_context(None)))(event)
                return
            self._apply_arrived()

        register = handle.on_click if click else handle.on_update
        register(keep)
        register(run)
        if click:
            return lambda: None
        self._kept[id(keep)] = (handle, keep)

        def forget() -> None:
            self._kept.pop(id(keep), None)

        return forget

    def in_turn(self, handler: Callable[[Any], None]) -> Callable[[Any], None]:
        """``handler`` for a click that reads what the edits made (a download): the edits that arrived before the
        click are applied first. viser's pool may run a click's callback before the callbacks of edits that came
        earlier (a sequence typed, Enter, then Download: the file had no sequence, in a fresh-clone run)."""

        def run(event: Any) -> None:
            if getattr(event, "client_id", None) is not None:  # a user's click; one set by the server runs at once,
                self._apply_arrived()  # in the setting thread, which may be applying an edit (the lock is not
            handler(event)  # re-entrant)

        return run

    def arriving_client(self) -> int | None:
        """The tab whose edit is arriving, read inside an :meth:`on_edit` context (None there for a value set from
        the server, and anywhere else): what a context is of may depend on what that tab did before it."""
        return getattr(self._arriving, "client", None)

    def on_arrival(self, handle: Any, note: Callable[[Any], None]) -> None:
        """Call ``note`` with each user's event of ``handle`` on viser's loop as it arrives, before any callback
        of it on the pool: for what an :meth:`on_edit` context must know in arrival order (the editor counts the
        selection moves that come after a click). Taken back by :meth:`close`."""

        async def keep(event: Any) -> None:
            if event.client_id is not None:
                note(event)

        handle.on_update(keep)
        self._kept[id(keep)] = (handle, keep)

    def on_command(self, command: Any, apply: Callable[[], None]) -> None:
        """Run ``apply`` when a command palette hotkey fires, in its place among the page's edits (see
        :meth:`on_edit`): Ctrl+Z ran on the pool at once, and took back the edit before the one typed just before
        it, whose callback had not run yet."""

        async def keep(event: Any) -> None:
            self._arrived.append((lambda _: apply(), event.client, None, ()))

        command.on_trigger(keep)
        command.on_trigger(lambda _: self._apply_arrived())

    def _apply_arrived(self) -> None:
        """Apply every edit kept so far, oldest first, each as its own tab's (see :meth:`on_edit`)."""
        with self._applying:
            while self._arrived:
                apply, client, value, kept = self._arrived.popleft()

                def applied(_: Any, apply: Any = apply, value: Any = value, kept: Any = kept) -> None:
                    if isinstance(kept, BaseException):
                        raise kept
                    apply(value, *kept)

                self.safe(applied)(SimpleNamespace(client=client))

    def close(self) -> None:
        """Take back the callbacks that keep values on viser's loop: once the server stops, a value set from here
        would have viser schedule one on a closed loop (RuntimeError out of the setter). A button group has no
        public remover, and the server never sets one."""
        for handle, keep in self._kept.values():
            handle.remove_update_callback(keep)
        self._kept.clear()

    def notify(self, title: str, body: str, *, error: bool = False) -> None:
        """Say it in the status line, and as a toast unless the same toast went out less than TOAST_SECONDS ago
        (typing into a field with a problem used to pile up one toast per keystroke)."""
        if self.status is not None:
            self.status.content = f"**{title}**: {body}"
        now = time.monotonic()
        last = self._last_toast
        if last is not None and last[0] == (title, body) and now - last[1] < TOAST_SECONDS:
            return
        self._last_toast = ((title, body), now)
        self.toasts += 1
        for client in self.server.get_clients().values():
            client.add_notification(unplain(title), unplain(body), color="red" if error else "blue",
                                    auto_close_seconds=TOAST_SECONDS)  # fmt: skip

    def edited(self, what: str) -> None:
        """The gait was edited (``what``) by the tab acting now: when another tab edited it last, the other tabs
        are told that one tab edits it now (they show the same document: a rename in one appears in all). Edits
        the server makes (no tab acting) say nothing."""
        client = getattr(self._acting, "client", None)
        if client is None:
            return
        previous, self.last_editor = self.last_editor, client.client_id
        if previous == client.client_id:
            return
        for other in self.server.get_clients().values():
            if other.client_id != client.client_id:
                other.add_notification("Edited elsewhere", f"{what} in another tab; this tab shows it, and its "
                                       "Undo would take it back", color="yellow", auto_close_seconds=30.0)  # fmt: skip

    def undoing_elsewhere(self) -> bool:
        """The tab acting now is about to undo or redo an edit another tab made."""
        client = getattr(self._acting, "client", None)
        return client is not None and self.last_editor is not None and self.last_editor != client.client_id

    def resolved(self, title: str, now: str) -> None:
        """The problem the status line reports under ``title`` is gone: say ``now`` instead (one status, current)."""
        if self.status is not None and self.status.content.startswith(f"**{title}**"):
            self.status.content = now
            self._last_toast = None

    # -- controls the server sets ---------------------------------------------------------------------------------

    @contextlib.contextmanager
    def programmatic(self) -> Iterator[None]:
        """Controls set by the server (not the user) inside this block: their update callbacks do nothing.

        viser calls a control's callbacks synchronously, in the thread that sets its value: the flag is that
        thread's alone. (It was one flag for the process: a user's edit arriving on viser's thread pool while the
        20 Hz refresh was setting the timeline was taken for the server's own and silently dropped.) The lock
        keeps the editor's resync and the refresh from interleaving."""
        with self._sync_lock:
            outer = self.syncing
            self._programmatic.active = True
            try:
                yield
            finally:
                self._programmatic.active = outer

    @property
    def syncing(self) -> bool:
        """True in a thread that is setting controls itself (see :meth:`programmatic`)."""
        return getattr(self._programmatic, "active", False)

    def atomic(self) -> contextlib.AbstractContextManager[None]:
        """Many control changes sent to the browser as one."""
        return self.server.atomic()
