"""Editing and driving programs in the page (issue 16), without a browser: the controls are set from here, which
runs the same callbacks a user's edit does (test_drive_e2e.py drives the page in Chromium)."""

from __future__ import annotations

import asyncio
import threading
from types import SimpleNamespace
from typing import Any

import pytest

from gaits.model import LIBRARY
from tests.helpers import wait_until
from web.program_editor import TIME, parse_sequence

pytestmark = pytest.mark.timeout(120)


def _select(app, automaton: str, state: int) -> None:
    app.editor.automaton.value = automaton
    app.editor.state_index.value = state


def test_what_ends_a_state_is_edited_at_the_field_and_undone_in_one_step(studio) -> None:
    app = studio.app
    editor = app.editor
    editor.open_file(LIBRARY / "contact_inchworm.toml")
    _select(app, "lead", 8)  # "land": until contact
    events = editor.events
    assert events.until.value == "contact" and events.value.disabled
    events.until.value = "at_goal"
    state = app.doc.data()["automata"]["lead"]["states"][7]
    assert state["until"] == "at_goal" and state["tolerance"] == 2.0 and not events.value.disabled
    events.value.value = 3.5
    assert app.doc.data()["automata"]["lead"]["states"][7]["tolerance"] == 3.5
    events.until.value = "torque"  # the tolerance goes with at_goal: replaced, not left for the loader to refuse
    state = app.doc.data()["automata"]["lead"]["states"][7]
    assert state["until"] == "torque" and "tolerance" not in state and not app.doc.problems
    events.until.value = "neighbour"
    events.state.value = "h9"  # the lead's neighbour -1 is module 0: no such module
    assert app.doc.problems and "no module" in editor.state_problem.content + editor.problems.content
    events.neighbour.value = 1
    events.state.value = "h2"
    assert not app.doc.problems, app.doc.problems
    events.until.value = TIME
    assert "until" not in app.doc.data()["automata"]["lead"]["states"][7] and not app.doc.problems
    events.one_shot.value = True
    assert app.doc.gait().automata["lead"].one_shot
    editor.history("Undo")
    assert not app.doc.gait().automata["lead"].one_shot and events.one_shot.value is False


def test_gaits_of_the_program_and_its_sequence_are_edited_in_the_page(studio) -> None:
    app = studio.app
    program = app.editor.program
    program.name.value = "left"
    program.on_action("Add (copy of forward)")
    assert "left" in app.doc.data()["gaits"] and program.editing.value == "left"
    app.editor.module_index.value = 3
    app.editor.phase.value = 0.5  # edits module 3 in the gait being edited: left
    assert app.doc.data()["gaits"]["left"]["modules"][2]["phase"] == 0.5
    assert app.doc.data()["modules"][2]["phase"] != 0.5
    program.sequence.value = "forward 2, left 3, forward"
    assert app.doc.gait().sequence == [("forward", 2), ("left", 3), ("forward", 0)]
    program.sequence.value = "forward, left 2"  # forward never ends by itself: the problem shows at the field
    assert "never ends by itself" in program.problem.content
    program.sequence.value = "forward 2, left x"  # not a sequence: refused, nothing changed
    assert "e.g. 'forward 5" in app.page.status.content
    program.sequence.value = "forward 2, left 3, forward"
    app.editor.modules.value = 10  # the robot grows: every gait of the program grows with it
    assert len(app.doc.data()["gaits"]["left"]["modules"]) == 10 and not app.doc.problems
    program.on_action("Remove edited")
    assert "gaits" not in app.doc.data() and app.doc.gait().sequence == [("forward", 2), ("forward", 0)]


def test_the_drive_buttons_steer_the_preview_and_refuse_a_gait_the_program_lacks(studio) -> None:
    app = studio.app
    app.page.safe(lambda _: app.drive.command("◀ Left"))(None)  # as a click runs it: the caterpillar has no left gait
    assert "no 'left' gait" in app.page.status.content
    app.editor.open_file(LIBRARY / "steerable_caterpillar.toml")
    assert wait_until(lambda: app.loop.sim.gait.name == "steerable_caterpillar", timeout=30)
    app.drive.command("◀ Left")
    sim = app.loop.sim
    assert wait_until(lambda: all(r.gait.mode.peek() == 1 for r in sim.modules.values()), timeout=30)
    assert "Preview: **left**" in app.drive.state.content
    app.drive.command("■ Stop")
    assert wait_until(lambda: not any(r.gait.started for r in sim.modules.values()), timeout=30)
    app.drive.command("▼ Reverse")  # driving a stopped preview starts it again
    assert wait_until(lambda: all(r.gait.started for r in sim.modules.values()), timeout=30)
    assert wait_until(lambda: all(r.gait.direction.peek() == -1 for r in sim.modules.values() if r.module_id % 2), 30)


@pytest.mark.parametrize("text", ["forward 5, , left 3, forward", "forward 0x5", "for ward 5", "forward 123456",
                                  "left 2; forward", "é 2", "forward 5, left"])  # fmt: skip
def test_a_sequence_is_parsed_or_refused_with_a_reason(text) -> None:
    if text in ("forward 5, , left 3, forward", "forward 5, left"):  # a step without cycles: until it ends
        assert parse_sequence(text)[-1][1] is None
        return
    with pytest.raises(ValueError):
        parse_sequence(text)


def test_the_drive_tab_sends_a_broadcast_signal_to_the_preview(studio) -> None:
    from gaits.model import loads
    from tests.gaits.preview import SIGNALLED

    app = studio.app
    app.editor.open(loads(SIGNALLED.replace("emit = 7", "emit = 8")))
    assert wait_until(lambda: app.loop.sim.gait.name == "signalled", timeout=30)
    sim = app.loop.sim
    assert wait_until(lambda: sim.data.time > 1.2, timeout=30)
    assert all(sim.modules[k].gait.state.peek() == 0 for k in range(2, 7))  # module 1 emits 8: nobody waits on it
    app.drive.signal.value = 7
    app.page.safe(lambda _: app.drive.send_signal(int(app.drive.signal.value)))(None)
    assert wait_until(lambda: all(sim.modules[k].gait.state.peek() != 0 for k in range(2, 7)), timeout=30)
    assert "signal **7**" in app.drive.state.content
    app.page.safe(lambda _: app.drive.send_signal(300))(None)
    assert "1..255" in app.page.status.content


def test_a_clicked_state_is_selected_and_anything_else_the_page_sends_is_refused(studio) -> None:
    """What the page's script writes into the editor's hidden field when a state is clicked (web/page_script.py):
    ``automaton:index:count`` selects that state; a hostile or stale text selects nothing."""
    editor = studio.app.editor
    editor.open_file(LIBRARY / "contact_inchworm.toml")
    editor.select_clicked("lead:7:1")
    assert (editor.automaton.value, editor.state_index.value) == ("lead", 8)
    for wrong in ("lead:99:2", "nope:1:3", "lead:-1:4", "lead:x:5", "lead:1", "", "lead:1:2:3", "a" * 100_000):
        with pytest.raises(ValueError):
            editor.select_clicked(wrong)
        assert (editor.automaton.value, editor.state_index.value) == ("lead", 8)
    editor.clicked.value = "lead:2:6"  # as the page sets it: through the field's callback
    assert wait_until(lambda: editor.state_index.value == 3, timeout=10)


class _HeldPool:
    """Stands in for viser's thread pool: keeps what the page's messages submit, to run in an order the test picks."""

    def __init__(self) -> None:
        self.held: list[tuple[Any, tuple[Any, ...]]] = []

    def submit(self, fn: Any, *args: Any) -> Any:
        self.held.append((fn, args))
        return SimpleNamespace(add_done_callback=lambda _: None)


def _arrives(app, handle, value: Any, client_id: int = 7) -> None:
    """A browser tab's edit of ``handle`` as viser's event loop handles it (the value is set there, then the
    callbacks are handed to the pool)."""
    from viser import _messages

    gui = app.server.gui
    message = _messages.GuiUpdateMessage(handle._impl.uuid, {"value": value})
    asyncio.run_coroutine_threadsafe(gui._handle_gui_updates(client_id, message), gui._event_loop).result(10)


def test_a_sequence_typed_right_after_add_is_kept_when_the_add_runs_first(studio, monkeypatch) -> None:
    """Found by test_drive_e2e under load: "Add (copy of forward)" clicked, then a sequence typed. viser set the
    field's value on its event loop, then the Add's callback resynced the editor from the document (an empty
    sequence) and the sequence's callback, run next on the pool, read "" from the field: the typed sequence was
    lost. The pool's worst order is replayed here: both messages arrive, then the callbacks run in that order."""
    app = studio.app
    program = app.editor.program
    pool = _HeldPool()
    monkeypatch.setattr(app.server.gui, "_thread_executor", pool)
    monkeypatch.setitem(app.server._connected_clients, 7, SimpleNamespace(client_id=7))
    program.name.value = "wiggle"
    _arrives(app, program.actions, "Add (copy of forward)")
    _arrives(app, program.sequence, "forward 2, wiggle 3, forward")
    assert len(pool.held) == 2
    for fn, args in pool.held:
        fn(*args)
    assert "wiggle" in app.doc.data()["gaits"]
    assert app.doc.gait().sequence == [("forward", 2), ("wiggle", 3), ("forward", 0)]
    assert program.sequence.value == "forward 2, wiggle 3, forward"


def test_a_download_clicked_right_after_an_edit_holds_the_edit_when_the_pool_runs_the_click_first(
    studio, monkeypatch
) -> None:
    """Found by test_drive_e2e in a fresh-clone run: a sequence typed, Enter, then Download: the file had no
    sequence. The click's callback ran on viser's pool before the sequence's, and read the document without it;
    a download is now taken in its place among the page's edits."""
    from gaits.model import loads

    app = studio.app
    pool = _HeldPool()
    monkeypatch.setattr(app.server.gui, "_thread_executor", pool)
    files: list[str] = []
    tab = SimpleNamespace(client_id=7, send_file_download=lambda name, content, **_: files.append(content.decode()))
    monkeypatch.setitem(app.server._connected_clients, 7, tab)
    _arrives(app, app.editor.program.sequence, "forward 2, forward")
    _arrives(app, app.editor.download, True)
    for fn, args in reversed(pool.held):  # the pool's worst order: the click's callbacks first
        fn(*args)
    assert len(files) == 1 and loads(files[0]).sequence == [("forward", 2), ("forward", 0)], files


def test_deploy_and_tuning_clicked_right_after_an_edit_take_the_edited_gait_when_the_click_runs_first(
    studio, monkeypatch
) -> None:
    """As the download above: Deploy and Start tuning read the edited gait, so each takes its place among the
    page's edits (the deploy's and the search's own work stubbed: what gait each would have read)."""
    app = studio.app
    pool = _HeldPool()
    monkeypatch.setattr(app.server.gui, "_thread_executor", pool)
    monkeypatch.setitem(app.server._connected_clients, 7, _tab(7))
    from gaits.model import loads

    read: list[list] = []
    monkeypatch.setattr(app.deployer, "on_deploy", lambda: read.append(app.doc.gait().sequence))
    monkeypatch.setattr(app.tuner, "start", lambda: read.append(app.doc.gait().sequence))
    recorded = lambda _, __, text, ___: read.append(loads(text).sequence)  # noqa: E731
    monkeypatch.setattr(app.page.recorder, "start_recording", recorded)
    monkeypatch.setattr(app.page.robot, "start_all", lambda names: read.append(app.doc.gait().sequence) or [])
    clicks = [
        (app.deployer.button, True, "forward 2, forward"),
        (app.tuner.control, "Start tuning", "forward 3"),
        (app.recording.buttons, "● Record", "forward 4"),
        (app.deployer.run_buttons, "Start all", "forward 5"),
    ]
    for button, value, text in clicks:
        pool.held.clear()
        _arrives(app, app.editor.program.sequence, text)
        _arrives(app, button, value)
        for fn, args in reversed(pool.held):  # the pool's worst order: the click's callbacks first
            fn(*args)
    assert read == [[("forward", 2), ("forward", 0)], [("forward", 3)], [("forward", 4)], [("forward", 5)]], read


def test_a_click_in_turn_knows_its_tab_and_one_set_by_the_server_inside_an_edit_does_not_wait_for_itself(
    studio, monkeypatch
) -> None:
    """The review of ``Page.in_turn``: the edits applied first reset the page's acting tab to none (the click was
    then taken for the server's own action), and an edit whose apply set such a button from the server waited for
    the edits' lock it held itself, for ever."""
    app, page = studio.app, studio.app.page
    pool = _HeldPool()
    monkeypatch.setattr(app.server.gui, "_thread_executor", pool)
    tab = SimpleNamespace(client_id=7, add_notification=lambda *a, **k: None)
    monkeypatch.setitem(app.server._connected_clients, 7, tab)
    seen: list[object] = []
    button = app.server.gui.add_button("in_turn probe")
    button.on_click(page.safe(page.in_turn(lambda _: seen.append(page._acting.client))))
    field = app.server.gui.add_text("in_turn probe field", initial_value="")
    page.on_edit(field, lambda value: button._impl.value and None)
    _arrives(app, field, "an edit first")
    _arrives(app, button, True)
    for fn, args in reversed(pool.held):
        fn(*args)
    assert seen == [tab], seen
    inner = page.in_turn(lambda _: seen.append("set by the server"))
    page.on_edit(field, lambda value: inner(SimpleNamespace(client_id=None, client=None)))
    pool.held.clear()
    _arrives(app, field, "an edit that clicks")
    done = threading.Thread(target=lambda: [fn(*args) for fn, args in pool.held], daemon=True)
    done.start()
    done.join(10)
    assert not done.is_alive() and seen[-1] == "set by the server", seen


def test_each_edit_is_applied_with_the_value_it_arrived_with_in_arrival_order(studio, monkeypatch) -> None:
    """The page's on_edit, alone: two values typed into a field, a resync setting it in between, the pool running
    the callbacks late; a value set by the server inside ``programmatic`` is not an edit, one set outside it is."""
    app = studio.app
    pool = _HeldPool()
    monkeypatch.setattr(app.server.gui, "_thread_executor", pool)
    monkeypatch.setitem(app.server._connected_clients, 7, SimpleNamespace(client_id=7))
    field = app.server.gui.add_text("on_edit probe", initial_value="")
    applied: list[str] = []
    app.page.on_edit(field, applied.append)
    _arrives(app, field, "first")
    _arrives(app, field, "second")
    with app.page.programmatic():
        field.value = "resynced"
    for fn, args in pool.held:
        fn(*args)
    assert applied == ["first", "second"]
    field.value = "set by the page's own action"
    assert applied == ["first", "second", "set by the page's own action"]


def _wave_rows(app) -> list[tuple[float, float]]:
    """The caterpillar's states as (angle, duration), as the document has them."""
    return [(s["angle"], s["duration"]) for s in app.doc.data()["automata"]["wave"]["states"]]


def _wave_state_selected(app, monkeypatch, state: int, *tabs: int) -> _HeldPool:
    """The caterpillar's S``state`` selected, viser's pool held, and browser ``tabs`` connected."""
    with app.page.programmatic():
        app.editor.automaton.value = "wave"
        app.editor.state_index.value = state
    app.editor.sync()
    pool = _HeldPool()
    monkeypatch.setattr(app.server.gui, "_thread_executor", pool)
    for client_id in tabs:
        monkeypatch.setitem(app.server._connected_clients, client_id, _tab(client_id))
    return pool


def _tab(client_id: int) -> SimpleNamespace:
    return SimpleNamespace(client_id=client_id, add_notification=lambda *a, **k: None)


def test_a_click_set_by_the_server_leaves_a_users_pending_click_to_itself(studio, monkeypatch) -> None:
    """A review of stop 53's click: a user's click, then the user's slider (the click loses), then a click set by
    the page's own action; the server's click took the user's pending entry and was judged by its count."""
    app = studio.app
    editor = app.editor
    pool = _wave_state_selected(app, monkeypatch, 1, 7)
    _arrives(app, editor.clicked, "wave:3:8")
    _arrives(app, editor.state_index, 2.0)
    editor.clicked.value = "wave:5:9"  # outside programmatic: applied at once, in this thread
    assert int(editor.state_index.value) == 6
    for fn, args in pool.held:
        fn(*args)
    assert int(editor.state_index.value) == 6


def test_an_edit_arriving_while_its_click_is_being_selected_is_the_clicked_states(studio, monkeypatch) -> None:
    """A review of stop 53's click: the click's entry went before the controls showed its state, so an angle that
    arrived while the pool selected it (waiting for the page's sync lock, which the 20 Hz refresh holds) landed on
    the state selected before."""
    app = studio.app
    editor = app.editor
    pool = _wave_state_selected(app, monkeypatch, 1, 7)
    before = _wave_rows(app)
    _arrives(app, editor.clicked, "wave:3:8")
    entered, release = threading.Event(), threading.Event()
    select = editor._select

    def held_select(*args: Any) -> None:
        entered.set()
        release.wait(10)
        select(*args)

    monkeypatch.setattr(editor, "_select", held_select)
    ((fn, args),) = pool.held
    pool.held.clear()
    selecting = threading.Thread(target=fn, args=args)
    selecting.start()
    try:
        assert entered.wait(10)
        _arrives(app, editor.angle, 33.0)
    finally:
        release.set()
        selecting.join(10)
    for fn, args in pool.held:
        fn(*args)
    rows = _wave_rows(app)
    assert rows[3][0] == 33.0 and rows[0] == before[0], rows


def test_another_tabs_edit_is_of_what_its_controls_show_not_this_tabs_pending_click(studio, monkeypatch) -> None:
    """A review of stop 53's click: tab 7 clicked S4 in the view, and tab 8, its controls still showing S1, clicked
    Remove: S4 went. Only the clicking tab's edits follow its click."""
    app = studio.app
    editor = app.editor
    pool = _wave_state_selected(app, monkeypatch, 1, 7, 8)
    before = _wave_rows(app)
    _arrives(app, editor.clicked, "wave:3:8", client_id=7)
    _arrives(app, editor.state_actions, "Remove", client_id=8)
    for fn, args in pool.held:
        fn(*args)
    assert _wave_rows(app) == before[1:]


def test_a_click_whose_states_moved_before_it_was_selected_selects_nothing_and_asks_again(studio, monkeypatch) -> None:
    """A click's index is of the states as its tab showed them: when they moved before it was selected (a gait
    opened from the library, which is not an edit kept in arrival order), it would select another state."""
    app = studio.app
    editor = app.editor
    pool = _wave_state_selected(app, monkeypatch, 2, 7)
    _arrives(app, editor.clicked, "wave:3:8")
    app.doc.remove_state("wave", 0)  # the states move under the pending click
    for fn, args in pool.held:
        fn(*args)
    assert int(editor.state_index.value) == 2
    assert "make it again" in app.page.status.content, app.page.status.content


@pytest.mark.parametrize("order", ["arrival", "reversed"])
def test_an_angle_typed_right_after_a_state_is_clicked_in_the_view_is_that_states(studio, monkeypatch, order) -> None:
    """Left open at stop 52: a state clicked in the 3D view (the page's script writes it into the editor's hidden
    field) was selected only when its callback ran on viser's pool, so an angle typed right after the click, whose
    state is read as it arrives, landed on the state selected before. A selection made after the click (the State
    slider) still wins over it, and a stale click selects nothing and leaves the edits after it where they were."""
    app = studio.app
    editor = app.editor
    pool = _wave_state_selected(app, monkeypatch, 1, 7)
    before = _wave_rows(app)
    _arrives(app, editor.clicked, "wave:3:8")
    _arrives(app, editor.angle, 33.0)
    for fn, args in pool.held if order == "arrival" else reversed(pool.held):
        fn(*args)
    rows = _wave_rows(app)
    assert rows[3][0] == 33.0 and rows[0] == before[0], rows
    assert int(editor.state_index.value) == 4
    pool.held.clear()
    _arrives(app, editor.clicked, "wave:5:8")
    _arrives(app, editor.state_index, 2.0)  # the slider after the click: S2
    _arrives(app, editor.angle, 21.0)
    for fn, args in pool.held if order == "arrival" else reversed(pool.held):
        fn(*args)
    rows = _wave_rows(app)
    assert rows[1][0] == 21.0 and rows[5] == before[5], rows
    pool.held.clear()
    _arrives(app, editor.clicked, "wave:99:8")  # a state the gait does not have: refused, nothing selected
    _arrives(app, editor.angle, 12.0)  # typed for it: refused with it, not put on the state selected before
    for fn, args in pool.held if order == "arrival" else reversed(pool.held):
        fn(*args)
    assert _wave_rows(app) == rows and int(editor.state_index.value) == 2
    assert "S100" in app.page.status.content or "99" in app.page.status.content, app.page.status.content


def test_an_edit_lands_on_the_state_selected_when_it_came_and_is_credited_to_its_own_tab(studio, monkeypatch) -> None:
    """An angle typed for S1, then S2 selected, the pool running both late: the angle is S1's (it was read from
    the selection when the callback ran: S2's). Two tabs' sequences, the pool running them in reverse: the last to
    arrive wins and the page credits the tab that typed it."""
    app = studio.app
    editor = app.editor
    automaton = next(iter(app.doc.data()["automata"]))
    with app.page.programmatic():
        editor.automaton.value = automaton
        editor.state_index.value = 1
    editor.sync()
    before = [s["angle"] for s in app.doc.data()["automata"][automaton]["states"][:2]]
    pool = _HeldPool()
    monkeypatch.setattr(app.server.gui, "_thread_executor", pool)
    for client_id in (7, 8):
        monkeypatch.setitem(app.server._connected_clients, client_id, _tab(client_id))
    _arrives(app, editor.angle, 33.0)
    _arrives(app, editor.state_index, 2.0)
    for fn, args in pool.held:
        fn(*args)
    states = app.doc.data()["automata"][automaton]["states"]
    assert [states[0]["angle"], states[1]["angle"]] == [33.0, before[1]]
    pool.held.clear()
    program = editor.program
    _arrives(app, program.sequence, "forward 3", client_id=7)
    _arrives(app, program.sequence, "forward 2", client_id=8)
    for fn, args in reversed(pool.held):
        fn(*args)
    assert app.doc.gait().sequence == [("forward", 2)] and app.page.last_editor == 8


@pytest.mark.parametrize("order", ["arrival", "reversed"])
def test_what_ends_a_state_lands_on_the_state_selected_when_it_came_with_the_fields_it_came_with(
    studio, monkeypatch, order: str
) -> None:
    """What ends a state is written from several fields at once (event, tolerance, neighbour, ...), read from the
    handles when the callback ran: with S2 selected in between (its fields resynced), an "at_goal" chosen for S1
    landed on S2, and S1 kept its old ending. The emitted signal and one-shot were read from the selection late
    too. Each is now applied to the state, and with the fields, shown when it came."""
    app = studio.app
    editor = app.editor
    editor.open_file(LIBRARY / "contact_inchworm.toml")
    _select(app, "lead", 8)  # "land": until contact
    before = app.doc.data()["automata"]["lead"]["states"]
    s8, s9 = dict(before[7]), dict(before[8])
    events = editor.events
    pool = _HeldPool()
    monkeypatch.setattr(app.server.gui, "_thread_executor", pool)
    monkeypatch.setitem(app.server._connected_clients, 7, _tab(7))
    _arrives(app, events.until, "at_goal")
    _arrives(app, events.emit, 5.0)
    _arrives(app, editor.state_index, 9.0)
    for fn, args in pool.held if order == "arrival" else reversed(pool.held):
        fn(*args)
    states = app.doc.data()["automata"]["lead"]["states"]
    assert states[7] == {**s8, "until": "at_goal", "tolerance": 2.0, "emit": 5}, states[7]
    assert states[8] == s9, "the state selected after the edits came is untouched"
    assert int(editor.state_index.value) == 9


def test_a_grid_row_a_name_and_a_state_removal_keep_what_they_came_with(studio, monkeypatch) -> None:
    """The same race in the grid, the gait's name and the state buttons. A grid row typed, then resynced by another
    edit before its callback ran: the row read back the resynced value, equal to what was shown, and the typed
    angle was lost. A name typed, then resynced: the same. "Remove" clicked on S4, then S6 selected: S6 went."""
    app = studio.app
    editor = app.editor
    doc = app.doc
    rows = lambda: _wave_rows(app)  # noqa: E731
    before = rows()
    angle, duration = before[2]
    pool = _wave_state_selected(app, monkeypatch, 4, 7)
    _arrives(app, editor.grid.rows[("wave", 2)], (angle + 7.5, duration))
    _arrives(app, editor.tools.name, "my caterpillar")
    _arrives(app, editor.state_actions, "Remove")
    _arrives(app, editor.state_index, 6.0)
    doc.update_state("wave", 2, {"duration": duration + 0.25})  # another tab's edit, resynced before the pool ran
    editor.after_edit()
    for fn, args in pool.held:
        fn(*args)
    assert doc.data()["name"] == "my caterpillar"
    expected = [*before[:2], (angle + 7.5, duration + 0.25), *before[4:]]  # S3 edited by both, S4 removed
    assert rows() == expected


def test_edits_of_different_fields_apply_in_the_order_they_came_whichever_callback_runs_first(
    studio, monkeypatch
) -> None:
    """Found by an adversarial review: the order was kept per control only. A neighbour typed, then its state; the
    pool ran the state's callback first, and the neighbour's, applied next with the fields as they were when it
    came, put the old state back. Every kept edit of the page is now applied oldest first, by whichever callback
    runs first."""
    app = studio.app
    editor = app.editor
    editor.open_file(LIBRARY / "contact_inchworm.toml")
    _select(app, "lead", 8)
    events = editor.events
    events.until.value = "neighbour"  # set from here outside programmatic: applied at once, as an edit
    events.state.value = "h9"
    pool = _HeldPool()
    monkeypatch.setattr(app.server.gui, "_thread_executor", pool)
    monkeypatch.setitem(app.server._connected_clients, 7, _tab(7))
    _arrives(app, events.neighbour, 1.0)
    _arrives(app, events.state, "h2")
    for fn, args in reversed(pool.held):
        fn(*args)
    state = app.doc.data()["automata"]["lead"]["states"][7]
    assert (state["neighbour"], state["state"]) == (1, "h2")


@pytest.mark.parametrize("order", ["arrival", "reversed"])
def test_an_edit_by_index_that_states_moved_under_is_refused_not_moved_onto_another_state(
    studio, monkeypatch, order: str
) -> None:
    """Found by an adversarial review: tab 8 removes S3 and tab 7's edit of S5 comes after it, made on the grid
    tab 7 saw before the removal: applied by index, it landed on the old S6 (on the last row: "list index out of
    range"). An edit made before a removal is applied before it; one whose states moved in between is refused."""
    app = studio.app
    editor = app.editor
    doc = app.doc
    rows = lambda: _wave_rows(app)  # noqa: E731
    before = rows()
    pool = _wave_state_selected(app, monkeypatch, 3, 7, 8)
    angle, duration = before[4]
    if order == "reversed":  # S5's edit came first: applied first, then the removal, whatever the pool's order
        _arrives(app, editor.grid.rows[("wave", 4)], (angle + 7.5, duration), client_id=7)
        _arrives(app, editor.state_actions, "Remove", client_id=8)
        for fn, args in reversed(pool.held):
            fn(*args)
        assert rows() == [*before[:2], before[3], (angle + 7.5, duration), *before[5:]]
        return
    _arrives(app, editor.state_actions, "Remove", client_id=8)
    _arrives(app, editor.grid.rows[("wave", 4)], (angle + 7.5, duration), client_id=7)
    _arrives(app, editor.events.emit, 9.0, client_id=7)  # by the selection: refused as well
    for fn, args in pool.held:
        fn(*args)
    assert rows() == [*before[:2], *before[3:]], "the removal only"
    assert all("emit" not in s for s in doc.data()["automata"]["wave"]["states"])
    assert "make it again" in app.page.status.content


def test_an_edit_whose_context_fails_is_told_to_its_tab_not_lost(studio, monkeypatch) -> None:
    """A context function that raised did so on viser's loop, where nobody heard it: the edit was lost silently."""
    app = studio.app
    pool = _HeldPool()
    monkeypatch.setattr(app.server.gui, "_thread_executor", pool)
    monkeypatch.setitem(app.server._connected_clients, 7, _tab(7))
    field = app.server.gui.add_text("context probe", initial_value="")
    applied: list[tuple[str, str]] = []
    failures = [RuntimeError("the selection could not be read")]

    def context() -> str:
        if failures:
            raise failures.pop()
        return "read"

    app.page.on_edit(field, lambda value, where: applied.append((value, where)), context=context)
    _arrives(app, field, "one")
    _arrives(app, field, "two")
    for fn, args in pool.held:
        fn(*args)
    assert applied == [("two", "read")]
    assert "the selection could not be read" in app.page.status.content


def test_an_undo_generate_and_a_refusal_keep_their_place_among_the_edits(studio, monkeypatch) -> None:
    """Found by a second review. An Undo that moved no state refused the edit typed after it (every undo moved the
    layout). A field whose edit was refused kept showing the refused value, so typing it again sent nothing. Generate
    ran ahead of the edits that came before it. A phase typed for a module the robot had just lost said only
    "Error"."""
    from gaits.generate import generate

    app = studio.app
    editor = app.editor
    doc = app.doc
    described = doc.data().get("description", "")
    doc.set_meta("description", "a step to undo")
    pool = _wave_state_selected(app, monkeypatch, 3, 7)
    angle = _wave_rows(app)[2][0]
    _arrives(app, editor.history_actions, "Undo")
    _arrives(app, editor.angle, angle + 5.0)
    for fn, args in reversed(pool.held):
        fn(*args)
    assert doc.data().get("description", "") == described and _wave_rows(app)[2][0] == angle + 5.0
    pool.held.clear()
    _arrives(app, editor.angle, angle + 9.0)
    doc.add_state("wave", 10)  # another tab's insert, applied first: S3's number may have changed
    editor.after_edit()
    for fn, args in pool.held:
        fn(*args)
    assert _wave_rows(app)[2][0] == angle + 5.0 and "make it again" in app.page.status.content
    assert editor.angle.value == angle + 5.0, "the field shows the document again: typing the value again is an edit"
    pool.held.clear()
    with app.page.programmatic():
        editor.module_index.value = 3
    editor.sync()
    _arrives(app, editor.phase, 0.5)
    _arrives(app, editor.tools.make, None)
    expected = generate(editor.tools.spec())
    for fn, args in reversed(pool.held):
        fn(*args)
    assert doc.data()["name"] == expected.name
    assert next(m["phase"] for m in doc.data()["modules"] if m["id"] == 3) == next(
        m.phase for m in expected.modules if m.id == 3
    ), "the phase came before Generate: applied first, then replaced by the generated gait"
    pool.held.clear()
    with app.page.programmatic():
        editor.module_index.value = 10
    editor.sync()
    _arrives(app, editor.modules, 4.0)
    _arrives(app, editor.phase, 0.25)
    for fn, args in pool.held:
        fn(*args)
    assert "no module 10" in app.page.status.content


def _hotkey(app, label: str, client_id: int = 7) -> None:
    """A command palette hotkey pressed in a tab, as viser's event loop handles it."""
    from viser import _messages

    gui = app.server.gui
    handle = next(h for h in gui._command_handle_from_uuid.values() if h._impl.props.label == label)
    message = _messages.CommandTriggerMessage(handle._impl.uuid)
    asyncio.run_coroutine_threadsafe(gui._handle_command_trigger(client_id, message), gui._event_loop).result(10)


@pytest.mark.parametrize("how", ["button", "Ctrl+Z"])
def test_an_undo_takes_back_the_edit_typed_just_before_it(studio, monkeypatch, how: str) -> None:
    """Found by a third review: Ctrl+Z ran at once on viser's pool, ahead of the angle typed just before it, and took
    back the edit before that one (the description), leaving the angle."""
    app = studio.app
    editor = app.editor
    doc = app.doc
    doc.set_meta("description", "a step to undo")
    pool = _wave_state_selected(app, monkeypatch, 3, 7)
    angle = _wave_rows(app)[2][0]
    _arrives(app, editor.angle, angle + 5.0)
    if how == "button":
        _arrives(app, editor.history_actions, "Undo")
    else:
        _hotkey(app, "Undo the last edit")
    for fn, args in reversed(pool.held):
        fn(*args)
    assert _wave_rows(app)[2][0] == angle and doc.data().get("description") == "a step to undo"


@pytest.mark.filterwarnings(r"ignore:Queued a \w+ on a closed connection:UserWarning")  # stopped on purpose
def test_a_control_set_after_the_page_closed_is_still_set(studio) -> None:
    """on_edit's coroutine callback, scheduled on viser's loop by every value set from the server: after the server
    stopped, viser raised RuntimeError (the loop closed) out of the setter, and the edit was lost."""
    app = studio.app
    app.page.close()
    app.server.stop()
    app.editor.program.sequence.value = "forward 4"
    assert app.doc.gait().sequence == [("forward", 4)]
    app.editor.state_index.value = 3  # the selection's arrival counter (Page.on_arrival) is taken back too
    app.editor.clicked.value = "wave:4:1"
    assert app.editor.state_index.value == 5
