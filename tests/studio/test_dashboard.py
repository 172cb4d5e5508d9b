"""The dashboard in this process, without a browser: a Studio on port 0 (no Zenoh), its controls set from here.

viser runs a control's callbacks when the server sets its value, so setting a handle's value here goes through the
same callback a user's edit in the page does (the browser path itself is test_studio_e2e.py's)."""

from __future__ import annotations

import time
from collections import deque
from types import SimpleNamespace

import numpy as np
import pytest

from gaits.model import load
from tests.helpers import wait_until

pytestmark = pytest.mark.timeout(120)


def test_a_grid_row_edits_its_state_selects_it_and_re_previews(studio):
    app = studio.app
    grid = app.editor.grid
    assert len(grid.rows) == 16  # the caterpillar's one automaton: 16 states
    generation = app.loop.generation
    grid.rows[("wave", 5)].value = (-12.5, 0.0625)
    state = app.doc.gait().automata["wave"].states[5]
    assert state.angle == -12.5 and state.duration == 0.0625
    assert app.editor.automaton.value == "wave" and app.editor.state_index.value == 6
    assert app.editor.angle.value == -12.5  # the cell editor shows the same state
    assert wait_until(lambda: app.loop.generation > generation, timeout=20)
    assert app.loop.sim.gait.automata["wave"].states[5].angle == -12.5
    # a beyond-limits angle is kept with its problem shown, and never reaches the preview
    grid.rows[("wave", 0)].value = (95.0, 0.0625)
    assert "outside the joint limits" in app.editor.state_problem.content
    assert "Problems" in app.editor.problems.content
    app.editor.history("Undo")
    assert grid.rows[("wave", 0)].value[0] == pytest.approx(19.134)
    assert not app.doc.problems


def test_a_users_edit_is_not_lost_while_the_server_is_setting_controls_elsewhere(studio):
    """Reproduces a lost edit: a user's edit arrives on viser's thread pool while another thread (the 20 Hz refresh)
    is inside programmatic(); the edit was taken for the server's own and dropped."""
    import threading

    app = studio.app
    inside, release = threading.Event(), threading.Event()

    def refresh_holding_the_flag() -> None:
        with app.page.programmatic():
            inside.set()
            release.wait(5)

    other = threading.Thread(target=refresh_holding_the_flag)
    other.start()
    try:
        assert inside.wait(5)
        assert not app.page.syncing  # the flag is that thread's, not this one's
        threading.Timer(0.3, release.set).start()
        app.editor.angle.value = 42.0  # the user's edit, as viser delivers it
    finally:
        release.set()
        other.join(5)
    assert app.doc.gait().automata["wave"].states[0].angle == 42.0


def test_a_row_never_rounds_what_it_did_not_change(studio):
    app = studio.app
    app.doc.update_state("wave", 0, {"duration": 1 / 12})  # shown as 0.083333 in the page (6 decimal places)
    app.editor.after_edit()
    row = app.editor.grid.rows[("wave", 0)]
    assert tuple(row.value) == (19.134, 0.083333)
    row.value = (20.0, 0.083333)
    state = app.doc.gait().automata["wave"].states[0]
    assert state.angle == 20.0 and state.duration == 1 / 12


def test_the_grid_follows_the_table_shape(studio):
    app = studio.app
    app.editor.open(load("gaits/library/legged_walk.toml"))
    automata = app.doc.gait().automata
    assert set(app.editor.grid.rows) == {(n, k) for n, a in automata.items() for k in range(len(a.states))}
    app.doc.add_state("hip", 0)
    app.editor.after_edit()
    assert ("hip", len(automata["hip"].states)) in app.editor.grid.rows


def test_deploying_another_robot_resizes_the_simulated_modules(studio):
    app = studio.app
    app.editor.modules.value = 12  # the Robot folder's module count, as typed in the page
    assert app.doc.gait().robot.modules == 12
    gait = app.doc.gait()
    app.deployer.start(gait, app.deployer.stage(gait))  # Deploy, then Start in the dialog that follows
    assert wait_until(lambda: app.link.status.modules == 12, 20)
    assert wait_until(
        lambda: all(app.link.node.lookup(f"m{i}", "gait.service", timeout=2).running for i in (1, 12)), 20
    )
    app.editor.modules.value = 6
    gait = app.doc.gait()
    report = app.deployer.stage(gait)
    assert not any(
        app.link.node.lookup(f"m{i}", "gait.service", timeout=2).running for i in range(1, 7)
    )  # nothing moves
    app.deployer.start(gait, report)
    assert wait_until(lambda: app.link.status.modules == 6, 20)
    assert "simulated robot rebuilt: 12 → 6 modules" in app.deployer.log_html.content
    assert wait_until(lambda: [n for n, _, _ in app.link.roster.rows()] == [f"m{i}" for i in range(1, 7)], 20)


def test_a_deploy_that_rebuilds_the_robot_waits_for_its_process_to_be_back(studio, monkeypatch):
    """The studio restarts its robot for a gait of another size; the robot's modules were heard again before the
    robot process itself, and the deploy was refused ("robot 'robot' is not on the network (for 7.2 s)", a
    Chromium run under load): the deploy now waits for the process too."""
    app = studio.app
    link = app.link
    real_lost, real_await = link.lost, link.await_modules
    heard: list[float] = []

    def await_modules(names: set[str], timeout: float) -> bool:
        done = real_await(names, timeout)
        heard.append(time.monotonic())
        return done

    def lost() -> str | None:  # the new process is seen 1.5 s after its modules
        if heard and time.monotonic() - heard[0] < 1.5:
            return "robot 'robot' is not on the network (for 0.1 s)"
        return real_lost()

    app.editor.modules.value = 6
    monkeypatch.setattr(link, "await_modules", await_modules)
    monkeypatch.setattr(link, "lost", lost)
    gait = app.doc.gait()
    app.deployer.start(gait, app.deployer.stage(gait))
    assert heard and time.monotonic() - heard[0] >= 1.5
    assert wait_until(lambda: app.link.status.modules == 6, 20)


def test_the_attribute_browser_gives_each_type_its_input(studio):
    app = studio.app
    assert wait_until(lambda: "m1" in app.monitor.browse_module.options, timeout=10)
    app.monitor.browse_module.value = "m1"
    app.monitor.list_objects()
    kinds = {}
    for name in ("joint.goal", "estop", "joint.limits", "gait.table", "gait.service", "gait.checksum"):
        app.monitor.browse_object.value = name  # the user's choice builds the input
        kinds[name] = (type(app.monitor._value_input.handle).__name__, app.monitor._value_input.kind)
    assert kinds == {
        "joint.goal": ("GuiNumberHandle", "float"),
        "estop": ("GuiCheckboxHandle", "bool"),
        "joint.limits": ("GuiVector2Handle", "float_array"),
        "gait.table": ("GuiTextHandle", "text"),
        "gait.service": ("GuiCheckboxHandle", "service"),
        "gait.checksum": ("GuiNumberHandle", "int"),
    }

    def remote(name: str):  # read back from the module, as any other tool would
        return app.link.node.lookup("m1", name, timeout=5)

    app.monitor.browse_object.value = "joint.limits"
    app.monitor._value_input.handle.value = (-30.0, 45.0)
    app.monitor._value_input.write()
    assert remote("joint.limits").peek() == (-30.0, 45.0)
    app.monitor.browse_object.value = "joint.goal"
    app.monitor._value_input.handle.value = 60.0
    app.monitor._value_input.write()
    assert remote("joint.goal").peek() == 45.0  # the module clamps to its limits, whatever the page sends
    assert app.monitor._value_input.refresh() == 45.0 and app.monitor._value_input.handle.value == 45.0
    app.monitor.browse_object.value = "gait.service"
    app.monitor._value_input.handle.value = True
    app.monitor._value_input.write()
    assert wait_until(lambda: remote("gait.service").running, 5)
    app.monitor._value_input.handle.value = False
    app.monitor._value_input.write()
    assert wait_until(lambda: not remote("gait.service").started, 5)


def test_a_failing_action_becomes_a_notification(studio):
    app = studio.app
    app.monitor.browse_module.value = "nobody"
    app.page.safe(lambda _: app.monitor.list_objects())(None)
    assert app.page.status.content.startswith("**Error**")


def test_the_view_follows_the_robot_and_the_ground_moves_under_it(studio):
    app = studio.app
    assert wait_until(lambda: app.loop.metrics().distance > 0.05, timeout=30)  # the caterpillar has crawled away
    assert wait_until(lambda: app.view._drawn is not None and app.view._drawn.time > 1.0, timeout=10)
    positions = np.concatenate([np.asarray(handle.batched_positions) for handle, _ in app.view._batches])
    assert np.abs(positions[:, :2].mean(axis=0)).max() < 1e-3  # drawn around the origin
    ground = np.asarray(app.view._ground.position)
    assert np.all(np.abs(ground[:2]) <= 0.5)  # ground_offset: its darker lines on whole metres, its edges far
    app.view.follow = False
    assert wait_until(lambda: np.abs(np.concatenate([np.asarray(h.batched_positions) for h, _ in app.view._batches])
                                     [:, :2].mean(axis=0)).max() > 0.04, timeout=10)  # fmt: skip


def test_a_failing_grid_edit_becomes_a_notification(studio):
    app = studio.app
    last = app.editor.grid.rows[("wave", 15)]
    app.doc.remove_state("wave", 15)  # the table shrank (another tab, say) before this row was rebuilt
    last.value = (10.0, 0.0625)
    assert app.page.status.content.startswith("**Error**")
    assert len(app.doc.gait().automata["wave"].states) == 15  # nothing half applied


def test_every_plot_is_against_seconds_with_units_and_the_live_window_is_chosen(studio):
    """uPlot takes an x axis as UNIX dates unless told otherwise: the page showed "1/1/70 12:00am" for 0 s."""
    app = studio.app
    for plot in (app.preview.angles, app.editor.expanded):
        assert plot.scales == {"x": {"time": False}}
        assert plot.axes[0]["label"] == "time (s)" and plot.axes[1]["label"]
    # the live plots: seconds before now on a fixed range, the window chosen (web/monitor.py SeriesPlot)
    assert app.monitor.lives[0].handle.scales == {"x": {"time": False, "range": (-10.0, 0.0)}}
    assert app.monitor.lives[0].handle.axes[0]["label"] == "seconds before now"
    assert app.monitor.plot.window == 10.0
    app.monitor.window.value = "300"  # as the page's dropdown sets it
    assert app.monitor.plot.window == 300.0
    for live in app.monitor.lives:
        assert wait_until(lambda live=live: live.handle.scales["x"]["range"] == (-300.0, 0.0), timeout=10)
    app.monitor.window.value = "10"


def test_one_toast_per_distinct_problem_and_the_status_line_is_always_current(studio):
    app = studio.app
    sent = app.page.toasts
    app.editor.phase.value = 1.5  # typed into the page: a problem, toasted
    app.editor.after_edit()  # the same problem again (another keystroke, a resync): not toasted again
    app.editor.phase.value = 1.55  # a different problem: toasted
    assert app.page.toasts - sent == 2
    assert app.page.status.content.startswith("**Invalid**")
    app.editor.phase.value = 0.5
    assert "is valid again" in app.page.status.content  # no stale "Invalid" next to a valid gait


def test_the_gait_control_table_shows_modules_by_time_with_the_selection_and_a_moving_cursor(studio):
    from web.control_table import CELL_HEIGHT, CELL_WIDTH, FRAME

    app = studio.app
    editor = app.editor
    editor.module_index.value = 3  # select module 3, as the page's slider does
    image = editor.control.image
    assert image.shape == (8 * CELL_HEIGHT, 64 * CELL_WIDTH, 3)  # 8 modules down, 64 samples of a period across
    top = 2 * CELL_HEIGHT
    assert (image[top, 10] == FRAME).all() and not (image[0, 10] == FRAME).all()  # module 3 is framed
    # the wave: module 1 at phase 0 starts at 0° (white-ish), and some cell is strongly red and some strongly blue
    assert image[..., 0].max() >= 190 and image[..., 2].max() >= 190
    editor.draw_control_table(cursor=0.5, force=True)
    column = 32 * CELL_WIDTH
    assert (editor.control.image[:, column] == 0).all()  # the cursor: a black column at half the period


def test_control_table_colours_are_signed_and_scaled_to_the_limits():
    import numpy as np

    from web.control_table import colours

    c = colours(np.array([-90.0, 0.0, 45.0, 90.0, 200.0]), 90.0)
    assert tuple(c[1]) == (255, 255, 255)
    assert c[0][2] > c[0][0] and c[3][0] > c[3][2]  # blue for negative, red for positive
    assert tuple(c[3]) == tuple(c[4])  # clipped at the limit
    assert c[2][1] > c[3][1]  # half the limit is paler than the limit


def test_clicking_a_module_in_3d_selects_it_in_the_editor_the_plot_and_the_browser(studio):
    import mujoco

    app = studio.app
    assert wait_until(lambda: bool(app.view._batches), timeout=20)  # the scene is built by the drawing thread
    model = app.view._model
    for _, ids in app.view._batches:
        names = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, int(model.geom_bodyid[g])) for g in ids]
        if "b5" in names:
            app.view._picked(model, ids, names.index("b5"))  # what viser calls with the clicked instance
            break
    else:
        raise AssertionError("no piece of body b5 in the scene")
    assert app.editor.module_index.value == 5 and app.preview.plot_module.value == 5
    assert "Selected module 5" in app.page.status.content
    assert (app.editor.control.image[4 * 12, 10] == (255, 170, 0)).all()  # the control table frames module 5


def test_the_live_plot_can_be_paused_and_resumed(studio):
    import numpy as np

    app = studio.app
    now = app.monitor.clock()  # the samples are recent
    app.monitor.plot.series[("m1", "joint.angle")] = deque([(now - 1.0, 1.0), (now, 2.0)])
    assert wait_until(lambda: len(app.monitor.lives[0].handle.data[0]) == 2, timeout=10)
    app.monitor.freeze.value = True
    app.monitor.plot.series[("m1", "joint.angle")].append((now + 0.5, 3.0))
    time.sleep(0.5)  # ten refreshes
    assert len(app.monitor.lives[0].handle.data[0]) == 2  # held still
    app.monitor.freeze.value = False
    assert wait_until(lambda: len(app.monitor.lives[0].handle.data[0]) == 3, timeout=10)
    assert np.asarray(app.monitor.lives[0].handle.data[1])[-1] == 3.0
    app.monitor.plot.unwatch_all()


def test_each_module_is_labelled_at_its_joint_in_the_3d_view(studio):
    app = studio.app
    assert wait_until(lambda: len(app.view._labels) == 8, timeout=20)
    assert [label.text for label in app.view._labels] == [f"m{k}" for k in range(1, 9)]
    assert wait_until(lambda: len({tuple(label.position) for label in app.view._labels}) == 8, timeout=20)
    import numpy as np

    points = np.array([label.position for label in app.view._labels])
    gaps = np.linalg.norm(np.diff(points, axis=0), axis=1)
    assert np.allclose(gaps, 0.05, atol=2e-3)  # neighbouring joints are one 5 cm module apart: each label at its own
    app.view.set_labels(False)
    assert wait_until(lambda: not app.view._labels, timeout=20)


def test_the_studio_deploys_to_and_estops_a_robot_whose_odd_modules_run_in_c() -> None:
    """asm-studio --c-modules odd: modules 1, 3, 5, 7 of its robot and of its preview run the C runtime; the page's
    Deploy, E-STOP and release treat them like the others."""
    from server.studio import Studio, StudioOptions

    studio = Studio(StudioOptions(port=0, c_modules="odd"))
    try:
        app = studio.app
        app.draw_unwatched = True  # the test reads the preview with no browser (which would hold it otherwise)
        assert [i for i, m in sorted(app.loop.sim.modules.items()) if m.language == "c"] == [1, 3, 5, 7], (
            "the preview runs the same modules in C"
        )
        assert wait_until(lambda: len({round(f.goals[2], 1) for f in list(app.loop.frames)}) > 5, 20), "and they move"
        assert wait_until(lambda: len(app.link.alive_modules()) == 8, 20)
        gait = app.doc.gait()
        app.deployer.start(gait, app.deployer.stage(gait))  # Deploy, then Start in the dialog that follows
        running = lambda: [app.link.node.lookup(f"m{i}", "gait.service", timeout=2).running for i in range(1, 9)]  # noqa: E731
        assert wait_until(lambda: all(running()), 20)
        goal = app.link.node.lookup("m3", "joint.goal", timeout=2)  # a C module: its gait moves its goal
        first = goal.peek()
        assert wait_until(lambda: abs(goal.peek() - first) > 1.0, 10)
        assert app.bar.press_estop() is None  # the E-STOP button's callback
        assert wait_until(lambda: len(app.link.status.estop or []) == 8, 10), "every module latched, C too"
        assert "latched on 8 of 8 modules (read back)" in app.page.status.content
        assert not any(running())
        app.bar._release(app.link.modules())
        assert wait_until(lambda: not app.link.status.estop, 10)
    finally:
        studio.close()


def test_a_second_deploy_while_start_waits_replaces_the_first_instead_of_blaming_the_page(studio):
    """Found by an adversarial run: Deploy, then Deploy again while "Start it now?" waits — the page refused itself,
    naming its own lease as another deployer's."""

    app = studio.app
    app.deployer.on_deploy()
    # issue 28's fourth review: a simulated robot's deploy said nothing of its modules (they may be emulated boards
    # whose calibration the deploy depends on): each one's firmware, type and calibration, as for a real robot
    assert "m1: Python 0." in app.deployer.log_html.content and "soft limits" in app.deployer.log_html.content
    assert app.deployer.confirm.pending and "held by this page" in (
        app.deployer.poll_lease() or app.deployer.lease_md.content
    )
    app.deployer.on_deploy()  # again: the first deployment is given up, the new one staged
    assert app.deployer.confirm.pending and "not started (cancelled)" in app.deployer.log_html.content
    assert not app.page.status.content.startswith("**Error**")
    app.deployer.confirm._on_click(SimpleNamespace(target=SimpleNamespace(value="Start")))
    node = app.link.node
    assert wait_until(lambda: all(node.lookup(f"m{i}", "gait.service", timeout=2).running for i in range(1, 9)), 20)


def test_a_layout_round_trips_and_a_file_that_is_not_one_changes_nothing(studio):
    monitor = studio.app.monitor
    assert wait_until(lambda: "m1" in monitor.browse_module.options, timeout=10)
    monitor.apply_layout({"version": 1, "window": 60.0, "plots": {"Live plot 2": ["m2/joint.angle", "m1/joint.goal"]}})
    saved = monitor.layout()
    assert saved["window"] == 60.0 and monitor.window.value == "60"
    assert saved["plots"]["Live plot 2"] == ["m1/joint.goal", "m2/joint.angle"]
    for wrong in ({"plots": {"Live plot 9": []}}, {"plots": {}, "window": 7.0}, {"plots": {"Live plot 1": ["m1"]}}, []):
        with pytest.raises(ValueError, match="not a layout"):
            monitor.apply_layout(wrong)
        assert monitor.layout() == saved  # nothing changed
    # issue 29's third review: a layout naming an attribute that is not there (or not a number) emptied a plot,
    # half refilled it and saved the half; it changes nothing now, and says which one
    for missing, why in (("m99/nothing", "m99/nothing cannot be plotted"), ("m1/x0", "m1/x0 cannot be plotted"),
                         ("m1/module.type", "not a number, nothing to plot")):  # fmt: skip
        with pytest.raises(ValueError, match=why):
            plots = {"Live plot 1": ["m2/joint.angle"], "Live plot 2": ["m3/joint.angle", missing]}
            monitor.apply_layout({"version": 1, "window": 30.0, "plots": plots})
        assert monitor.layout() == saved, "nothing changed"
    with pytest.raises(ValueError, match="not a number"):
        monitor.plots[0].watch("m1", "module.type")  # the attribute browser's Plot refuses it too
    monitor.apply_layout({"plots": {"Live plot 2": []}, "window": 10.0})
    assert monitor.layout()["plots"]["Live plot 2"] == []


def test_the_monitor_lists_the_objects_by_itself_once_the_node_answers(studio, monkeypatch):
    """The object list showed "-" until List was pressed when the page's one listing failed (a robot still
    starting): it tries again by itself until the chosen node answers."""
    monitor = studio.app.monitor
    link = studio.app.page.robot
    real, calls = link.list_objects, []

    def not_up_yet(*args, **kwargs):
        calls.append(args)
        if len(calls) < 3:
            raise TimeoutError("no answer yet")
        return real(*args, **kwargs)

    monkeypatch.setattr(link, "list_objects", not_up_yet)
    monitor.relink()  # as when the page shows a robot afresh: nothing listed
    assert list(monitor.browse_object.options) == ["-"]
    assert wait_until(lambda: "joint.goal" in monitor.browse_object.options, timeout=30), calls
    assert len(calls) == 3 and monitor.browse_module.value == "m1"
