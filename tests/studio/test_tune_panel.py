"""The Tune tab and the ground picker, in this process without a browser (the browser path is test_tune_e2e.py's):
a search started from the page runs in worker processes, shows its progress, its best can be previewed and adopted
(one undo step), and stopping it or closing the studio leaves no worker behind."""

from __future__ import annotations

import re
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from gaits.model import to_dict
from tests.helpers import wait_until

pytestmark = pytest.mark.timeout(180)


def _click(value: str) -> SimpleNamespace:
    return SimpleNamespace(target=SimpleNamespace(value=value), client=None)


def _gone(pids: list[int]) -> bool:
    """None of these processes runs (a zombie is not running: its parent has yet to reap it)."""

    def alive(pid: int) -> bool:
        try:
            status = Path(f"/proc/{pid}/status").read_text()
        except OSError:
            return False
        return "State:\tZ" not in status

    return not any(alive(pid) for pid in pids)


def test_a_search_from_the_page_improves_previews_adopts_and_undoes(studio):
    app = studio.app
    panel = app.tuner
    original = to_dict(app.doc.gait())
    panel.free["amplitude"].value = True
    panel.free["period"].value = True
    panel.budget.value = 12
    panel.seconds.value = 1.5
    run = panel.start(workers=2, popsize=4)
    assert wait_until(lambda: run.snapshot().evaluations > 0, timeout=90)  # progress shows while it runs
    pids = run.worker_pids()
    assert len(pids) == 2
    assert wait_until(lambda: not run.running, timeout=120)
    snap = run.snapshot()
    assert snap.state == "done" and snap.evaluations == 12
    assert snap.best is not None and snap.value >= snap.start_value  # never worse than where it started
    assert [n for n, _ in snap.history] == sorted(n for n, _ in snap.history)
    assert wait_until(lambda: _gone(pids), timeout=10)  # a finished search leaves no worker
    panel.refresh()
    assert "done" in panel.status.content and panel.progress.value == 100.0
    assert len(panel.curve.data[0]) == len(snap.history) + 1
    # the objective against each free parameter: every valid candidate, at the value it had
    valid = [(values, value) for values, value in snap.samples if value == value]
    assert len(snap.samples) == 11 and len(valid) >= 2  # the search's candidates (the start is not one)
    assert set(panel.scatters) == {"amplitude", "period"} and panel.scatters["period"].visible
    xs, ys = panel.scatters["period"].data
    assert sorted(zip(xs.tolist(), ys.tolist(), strict=True)) == sorted((v[1], y) for v, y in valid)
    # the best plays in the preview, then becomes the edited gait, and Undo gives the library gait back
    generation = app.loop.generation
    panel._on_best(_click("Preview best"))
    assert wait_until(lambda: app.loop.generation > generation, timeout=20)
    assert to_dict(app.loop.gait) == to_dict(snap.best)
    panel._on_best(_click("Adopt"))
    assert to_dict(app.doc.gait()) == to_dict(snap.best)
    assert "Tuned by" in app.doc.text()  # its provenance is in the file a download gives
    app.editor.history("Undo")
    assert to_dict(app.doc.gait()) == original


def test_stopping_keeps_the_best_so_far_and_ends_the_workers(studio):
    panel = studio.app.tuner
    panel.free["period"].value = True
    panel.budget.value = 400
    panel.seconds.value = 2.0
    run = panel.start(workers=2, popsize=4)
    assert wait_until(lambda: run.snapshot().generations >= 1 and len(run.worker_pids()) == 2, timeout=90)
    pids = run.worker_pids()
    panel._on_control(_click("Stop tuning"))
    assert wait_until(lambda: not run.running, timeout=30)
    snap = run.snapshot()
    assert snap.state == "stopped" and snap.evaluations < 400
    assert snap.best is not None  # the start at least (the library caterpillar is valid)
    assert wait_until(lambda: _gone(pids), timeout=10)
    assert "Tuned by" in run.provenance_text()


def test_closing_the_studio_ends_a_running_search(studio):
    panel = studio.app.tuner
    panel.free["amplitude"].value = True
    panel.budget.value = 400
    panel.workers.value = 1  # the tab's Workers field: one process, a core left to the robot
    run = panel.start(popsize=4)
    assert run.workers == 1
    assert wait_until(lambda: len(run.worker_pids()) == 1, timeout=90)
    pids = run.worker_pids()
    panel.close()
    assert not run.running
    assert wait_until(lambda: _gone(pids), timeout=10)


def test_a_bad_free_parameter_is_refused_before_anything_starts(studio):
    panel = studio.app.tuner
    with pytest.raises(ValueError, match="at least one free parameter"):
        panel.start()
    panel.other.value = "automata.nope.states[0].angle=-10:10"
    with pytest.raises(ValueError, match="no automaton 'nope'"):
        panel.start()
    panel.other.value = ""
    panel.free["period"].value = True
    for workers in (0, -2):  # (viser rounds a number to its step: no 1.5 reaches the panel)
        panel.workers.value = workers
        with pytest.raises(ValueError, match=f"Workers is a whole number of processes, 1 to .*, not {workers:g}"):
            panel.start()
    assert panel.run is None


def test_what_a_field_shows_is_what_runs_or_it_is_refused(studio):
    """issue 30's review, defect 14: a seed of -1 was shown while the run used cma's random seed, Workers went to 4 ×
    the cores, and "Other free" separated by commas was refused."""
    import os

    panel = studio.app.tuner
    panel.other.value = "modules[2].phase=0:1, period=0.5:1.5"
    assert [f.name for f in panel.frees()] == ["modules[2].phase", "period"]
    assert "commas" in panel.other.hint and panel.workers.max == (os.cpu_count() or 1)
    for field, value, says in ((panel.seed, -1, "Seed is a whole number, 0 to 2.14748e+09, not -1"),
                               (panel.budget, 100_001, "Budget is a whole number of simulations, 4 to 100000"),
                               (panel.workers, 4 * (os.cpu_count() or 1), "Workers is a whole number of processes"),
                               (panel.seconds, 0.1, "Seconds per candidate is 0.5 to 60, not 0.1")):  # fmt: skip
        before = field.value
        field.value = value
        with pytest.raises(ValueError, match=re.escape(says)):
            panel.start()
        field.value = before
    assert panel.run is None


def test_the_ground_picker_runs_the_preview_on_that_ground(studio):
    app = studio.app
    generation = app.loop.generation
    app.preview.ground.value = "slope:5"
    assert wait_until(lambda: app.loop.generation > generation, timeout=20)
    assert app.loop.terrain.spec.startswith("slope:angle=5")
    assert app.loop.sim.model.opt.gravity[0] < -0.5  # tilted: uphill along +x
    app.preview.refresh()
    assert "on slope:angle=5" in app.preview.metrics.content
    generation = app.loop.generation
    app.preview.ground.value = "rough:seed=1,roughness=0.02"
    assert wait_until(lambda: app.loop.generation > generation, timeout=30)
    assert app.loop.sim.model.nhfield == 1
    # the height field is drawn instead of the grid (the draw thread builds one, then hides the other)
    assert wait_until(lambda: len(app.view._terrain.handles) == 1 and not app.view._ground.visible, timeout=30)
    app.preview.ground.value = "step:0.03"
    assert wait_until(lambda: len(app.view._terrain.handles) == 1 and app.view._ground.visible, timeout=30)


@pytest.mark.parametrize("spec", ["flat", "slope:5", "rough:seed=3,roughness=0.03", "step:0.04", "patches"])
def test_the_view_draws_the_ground_the_model_has(spec):
    from gaits.mjcf import build_mjcf
    from gaits.model import LIBRARY, load
    from gaits.terrain import parse
    from web.ground import ground_meshes

    terrain = parse(spec)
    model = mujoco_model(build_mjcf(load(LIBRARY / "caterpillar.toml").robot, name="t", terrain=terrain))
    meshes = ground_meshes(model)
    if terrain.kind in ("flat", "slope"):
        assert meshes == []  # the grid is the floor
    elif terrain.kind == "rough":
        ((vertices, faces, _),) = meshes
        heights = terrain.elevations()
        assert len(vertices) == heights.size and len(faces) == 2 * (heights.shape[0] - 1) ** 2
        # the same bumps as the model's: highest at z = 0, as deep as the roughness
        assert vertices[:, 2].max() == pytest.approx(0.0, abs=1e-3)
        assert vertices[:, 2].max() - vertices[:, 2].min() == pytest.approx(0.03, abs=1e-3)
    elif terrain.kind == "step":
        ((vertices, _, _),) = meshes
        assert len(vertices) == 4 * 8 and vertices[:, 2].max() == pytest.approx(0.04)
        # the pit is 2 × 0.3 m wide: its inner edges are drawn where the model has them
        assert sorted(set(np.round(np.abs(vertices[:, 0]), 3))) == [0.3, 5.0]
        assert sorted(set(np.round(np.abs(vertices[:, 1]), 3))) == [0.3, 5.0]
    else:
        slippery = int(terrain.tiles().sum())
        assert sorted(len(v) // 8 for v, _, _ in meshes) == sorted([slippery, terrain.tiles().size - slippery])


def mujoco_model(mjcf: str):
    import mujoco

    return mujoco.MjModel.from_xml_string(mjcf)


def test_the_simulated_robot_is_rebuilt_on_the_previews_ground_at_a_deploy(studio):
    """The Preview tab's ground is the simulated robot's too: staging a deploy rebuilds the robot child on it."""
    app = studio.app
    gait = app.doc.gait()
    assert studio.ensure_robot(gait) is None  # the same gait on the same (flat) ground: nothing to rebuild
    app.preview.ground.value = "slope:5"
    assert wait_until(lambda: app.loop.terrain.kind == "slope", timeout=30)
    said = app.page.ensure_robot(gait)
    assert said is not None and "rebuilt on slope:angle=5" in said
    assert studio.robot_terrain == app.loop.terrain
    args = studio.child.args  # the robot process started (READY) with the preview's ground
    assert args[args.index("--terrain") + 1] == app.loop.terrain.spec
    assert app.page.ensure_robot(gait) is None  # and it stays there


def test_adopting_keeps_the_robot_file_the_gait_names(studio, tmp_path):
    """The tuned gait is the edited gait's robot, so Adopt names its robot file again (issue 30's review, defect 7:
    the description was written in, and the file no longer named)."""
    from gaits.model import LIBRARY

    (tmp_path / "robot.toml").write_text("[robot.module]\nmass = 0.25\n", encoding="utf-8")
    path = tmp_path / "mine.toml"
    path.write_text((LIBRARY / "caterpillar.toml").read_text(encoding="utf-8").replace(
        "module_size = 0.05\n", 'module_size = 0.05\nfile = "robot.toml"\n', 1), encoding="utf-8")  # fmt: skip
    app = studio.app
    app.editor.open_file(path)
    panel = app.tuner
    panel.free["amplitude"].value = True
    panel.budget.value = 4
    panel.seconds.value = 0.5
    run = panel.start(workers=1, popsize=3)
    assert wait_until(lambda: not run.running, timeout=120)
    panel._on_best(_click("Adopt"))
    assert not app.doc.problems and app.doc.gait().robot.file == "robot.toml"
    text = app.doc.text()
    assert 'file = "robot.toml"' in text and "[robot.module]" not in text and "mass = 0.25" not in text
    assert "Tuned by" in text and "(its modules described by the robot file robot.toml)" in text
    assert app.doc.gait().robot.module.mass == 0.25
