"""The gaits in MuJoCo: every library gait locomotes on the modules' own runtime, as the acceptance figures demand,
and the joint goals the simulation sees are the ones modules produce on a real-time CAN bus."""

from __future__ import annotations

import subprocess
import sys
import threading
import time

import mujoco
import pytest

from asm_module import FakeDriver, ModuleRuntime
from asm_py import Node
from asm_py.clock import WallClock
from asm_py.transport.can import CanTransport
from gaits.deploy import activate, deploy, stop_all
from gaits.model import Robot, load
from gaits.serpenoid import sine, wave_gait
from gaits.sim import Simulation
from tests.helpers import wait_until
from tests.transports import FAST_BEATS, fresh_name

from .preview import assert_follows_preview

pytestmark = pytest.mark.timeout(120)
LIBRARY = "gaits/library"
# gait: (minimum body lengths in 10 s after 2 s warm-up, intended heading or None for "its own heading")
ACCEPTANCE = {
    "caterpillar": (3.0, 0.0),
    "sidewinding": (3.0, None),
    "rolling_loop": (3.0, 0.0),
    "inchworm": (2.0, 0.0),
    "legged_walk": (2.0, 0.0),
    "lateral_undulation": (3.0, 0.0),
}


def _run(name: str, **options):
    with Simulation(load(f"{LIBRARY}/{name}.toml"), direction=options.pop("direction", 1)) as sim:
        return sim.run(10.0, warmup=2.0, **options)


@pytest.fixture(scope="module")
def forward():
    return {name: _run(name) for name in ACCEPTANCE}


@pytest.mark.parametrize("name", sorted(ACCEPTANCE))
def test_library_gait_locomotes(name, forward):
    minimum, heading = ACCEPTANCE[name]
    m = forward[name]
    assert m.body_lengths >= minimum, m.summary()
    axis = m.heading if heading is None else heading
    progress = abs(m.along(axis))
    assert progress >= minimum * m.body_length, m.summary()
    assert m.across(axis) < progress, m.summary()
    assert not m.fell and not m.stuck
    assert m.peak_torque <= 1.5 + 1e-6  # the actuators' limit holds


@pytest.mark.parametrize("name", sorted(ACCEPTANCE))
def test_direction_minus_one_moves_the_other_way(name, forward):
    back = _run(name, direction=-1)
    ahead = forward[name]
    dot = back.displacement[0] * ahead.displacement[0] + back.displacement[1] * ahead.displacement[1]
    assert dot < 0, (ahead.summary(), back.summary())
    assert back.body_lengths >= ACCEPTANCE[name][0], back.summary()


@pytest.mark.parametrize("name", sorted(ACCEPTANCE))
def test_a_sideways_push_does_not_stop_it(name, forward):
    pushed = _run(name, push_at=6.0, push=(0.0, 1.0, 0.0), push_seconds=0.1)
    assert pushed.body_lengths >= ACCEPTANCE[name][0], pushed.summary()
    assert not pushed.fell
    # and it still goes the same way
    ahead = forward[name]
    assert pushed.displacement[0] * ahead.displacement[0] + pushed.displacement[1] * ahead.displacement[1] > 0


def test_push_really_pushes():
    """The push is real: applied to a robot standing still, it moves it sideways."""
    gait = load(f"{LIBRARY}/legged_walk.toml")
    for automaton in gait.automata.values():
        for state in automaton.states:
            state.angle = 0.0
    with Simulation(gait) as sim:
        still = sim.run(1.0, warmup=0.5)
    with Simulation(gait) as sim:
        pushed = sim.run(1.0, warmup=0.5, push_at=0.6, push=(0.0, 20.0, 0.0), push_seconds=0.1)
    assert abs(still.displacement[1]) < 1e-3
    assert pushed.displacement[1] > 0.005


def test_the_simulation_runs_the_modules_runtime():
    """No trajectory shortcut: the goals MuJoCo gets are the modules' joint.goal, which obeys the module limits."""
    gait = load(f"{LIBRARY}/caterpillar.toml")
    with Simulation(gait, trace=True) as sim:
        sim.start()
        sim.modules[3].limits.set((-20.0, 20.0))
        sim.advance(3.0)
        column = [row[2] for row in sim.trace.goals]
        assert max(column) == 20.0 and min(column) == -20.0
        assert sim.modules[3].gait.state.peek() in range(16)
        assert all(r.gait.running for r in sim.modules.values())
        # e-stop on one module: it holds its angle while the physics goes on
        sim.modules[5].emergency_stop("test")
        held = sim.modules[5].goal.peek()
        sim.advance(0.5)
        assert sim.modules[5].goal.peek() == held and not sim.modules[5].gait.started


def test_model_exports_as_mjcf_that_mujoco_loads(tmp_path):
    out = tmp_path / "loop.xml"
    result = subprocess.run([sys.executable, "-m", "gaits.cli", "simulate", f"{LIBRARY}/rolling_loop.toml",
                             "--seconds", "1", "--warmup", "0.5", "--mjcf", str(out)],
                            capture_output=True, text=True, timeout=120)  # fmt: skip
    assert result.returncode == 0, result.stderr
    assert "distance" in result.stdout and "heading" in result.stdout and "peak torque" in result.stdout
    model = mujoco.MjModel.from_xml_path(str(out))
    assert model.nu == 12 and model.neq == 1  # twelve actuators, the weld closing the loop


def test_loop_stays_closed():
    with Simulation(load(f"{LIBRARY}/rolling_loop.toml")) as sim:
        sim.run(3.0, warmup=1.0)
        gap = sim.data.xpos[sim.model.body("b0").id] - sim.data.site("loop_end").xpos
        assert (gap**2).sum() ** 0.5 < 0.002


def test_a_128_module_chain_simulates_headless_and_moves():
    robot = Robot("chain", 128, "pitch")
    gait = wave_gait("long", "", robot, {"wave": (sine(30.0), 0.0)}, role_of=lambda n: "wave",
                     offset_of=lambda n: -n / 8)  # fmt: skip
    with Simulation(gait) as sim:
        metrics = sim.run(1.0, warmup=1.0)
    assert metrics.distance > 0.02 and not metrics.fell
    assert metrics.real_time_factor > 0.0  # how fast is bench/sim.py's (≥ 2×): a test asserts no timing (it failed
    # here at 0.37 with the two cores loaded)


class _Told(threading.local):
    now = float("nan")


class StampingClock(WallClock):
    """The wall clock, remembering per thread the time it last told. A module's tick reads the time, then sets its
    goal: the goal is stamped with the time it was computed for, not with when a loaded machine let the goal's
    callback run (stamped by ``time.monotonic()`` in the callback, a fresh clone's suite on three workers put a goal
    of 39.9° at a time the preview says 5-17°)."""

    def __init__(self) -> None:
        self.told = _Told()

    def now(self) -> float:
        self.told.now = now = super().now()
        return now


@pytest.mark.realtime  # its modules run on the wall clock: `make test` runs it after the rest
def test_preview_equals_deployment_over_virtual_can():
    """The same gait on module runtimes talking over a virtual CAN bus in real time commands, at every tick, what
    the simulation commanded at that time since the start, within one control tick."""
    gait = load(f"{LIBRARY}/caterpillar.toml")
    with Simulation(gait, trace=True) as sim:
        sim.start()
        sim.advance(2.5)
        sim_times, sim_goals = sim.trace.times, sim.trace.goals
    channel = fresh_name("asm-preview")
    stamps = StampingClock()
    runtimes, nodes = [], []
    records: list[list[tuple[float, float]]] = []
    try:
        for a in gait.modules:
            node = Node(f"m{a.id}", CanTransport(a.id, interface="virtual", channel=channel, **FAST_BEATS))
            nodes.append(node)
            runtime = ModuleRuntime(FakeDriver(), node=node, control_rate=50.0, clock=stamps)
            runtimes.append(runtime)
            record: list[tuple[float, float]] = []
            runtime.goal.on_change(lambda v, record=record: record.append((stamps.told.now, v)))
            records.append(record)
        tool = Node("tool", CanTransport(200, interface="virtual", channel=channel, **FAST_BEATS))
        nodes.append(tool)
        report = deploy(tool, gait, start=False)
        for record in records:
            record.clear()
        activate(tool, report)
        assert wait_until(lambda: all(r.gait.started for r in runtimes))
        time.sleep(2.2)
        stop_all(tool)
        assert wait_until(lambda: not any(r.gait.started for r in runtimes))
    finally:
        for runtime in runtimes:
            runtime.close()
        for node in nodes:
            node.close()
    for column, (runtime, record) in enumerate(zip(runtimes, records, strict=True)):
        assert_follows_preview(sim_times, sim_goals, column, record, runtime._ramp_start)


def test_a_diverging_simulation_writes_no_log_file_where_it_runs(tmp_path, monkeypatch, caplog):
    """MuJoCo's own warning handler wrote MUJOCO_LOG.TXT into the current folder (and printed to stdout); the
    divergence is a FloatingPointError, and MuJoCo's words go to the log (issue 30's review, defect 15)."""
    from gaits.model import LIBRARY as FOLDER
    from gaits.model import loads

    text = (FOLDER / "caterpillar.toml").read_text(encoding="utf-8").replace(
        "module_size = 0.05\n", "[robot.module]\nstall_torque = 10000\nkp = 100000\nmass = 0.001\n", 1)  # fmt: skip
    monkeypatch.chdir(tmp_path)
    with Simulation(loads(text)) as sim, pytest.raises(FloatingPointError, match="diverged"):
        sim.run(1.0, warmup=0.1)
    assert list(tmp_path.iterdir()) == []
    assert "Nan, Inf or huge value in QACC" in caplog.text
