"""What a run's metrics say to a person (gaits/metrics.py)."""

from __future__ import annotations

from gaits.metrics import Metrics


def _metrics(displacement: tuple[float, float], energy: float) -> Metrics:
    return Metrics(10.0, displacement, 0.4, 1.0, False, energy=energy, mass=1.6)


def test_the_cost_of_transport_of_a_robot_that_did_not_move_is_not_a_number_to_compare():
    """A user review found 48721172796711832.00 (a stall torque of 1e-9) and 0.00 (a servo of 1e-300 N·m) printed
    as costs: over a near-zero distance the ratio means nothing, so it says so."""
    assert _metrics((1e-12, 0.0), 5.0).cost_text() == "n/a (did not move)"
    assert _metrics((0.0, 0.0), 0.0).cost_text() == "n/a (did not move)"
    assert _metrics((0.003, 0.0), 0.0).cost_text() == "n/a (did not move)"  # under a hundredth of a body length
    moved = _metrics((2.0, 0.0), 31.392)
    assert moved.cost_text() == "1.00" and "cost of transport 1.00" in moved.summary()


def test_validate_says_each_problem_once(tmp_path, capsys):
    """A document missing every field broke the schema's alternatives alike, each saying "missing" again."""
    from gaits.cli import main

    bad = tmp_path / "e.toml"
    bad.write_text("x = 1\n", encoding="utf-8")
    assert main(["validate", str(bad)]) == 1
    captured = capsys.readouterr()
    out = captured.out + captured.err
    for field in ("name", "robot", "automata", "modules"):
        assert out.count(f"{field}: missing") == 1, out


def test_stuck_is_a_rate_so_a_short_run_of_a_crawling_gait_is_not_stuck():
    """A second review: 0.2 m in 1 s (a 0.4 m caterpillar at its usual speed) was "stuck", because stuck was half a
    body length over the run, however long; it is half a body length per 10 s now, as a 10 s run always had it."""
    crawl = Metrics(1.0, (0.199, 0.0), 0.4, 1.0, False)
    assert not crawl.stuck
    assert Metrics(10.0, (0.199, 0.0), 0.4, 1.0, False).stuck  # the same distance over 10 s: as before
    assert Metrics(100.0, (1.0, 0.0), 0.4, 1.0, False).stuck  # 1 m in 100 s: a long run no longer hides it
    assert Metrics(0.0, (0.0, 0.0), 0.4, 1.0, False).stuck


def test_the_heading_of_a_robot_that_did_not_move_is_not_a_number_either():
    """A second review: a robot that did not move said "heading -90.0 degrees" (the direction of noise)."""
    assert _metrics((0.0, -1e-9), 0.0).heading_text() == "n/a (did not move)"
    assert _metrics((0.0, 2.0), 0.0).heading_text() == "90.0 degrees from +x"


def test_a_run_shorter_than_a_tick_measures_one_tick_and_the_commands_refuse_it(capsys):
    """A second review: --seconds 1e-9 ran no tick, measured 0 s and divided by it (a traceback in simulate and
    tune). The commands refuse less than one 20 ms tick; the library measures at least one."""
    import pytest

    from gaits.cli import main
    from gaits.model import LIBRARY, load
    from gaits.sim import Simulation

    for command in ("simulate", "tune"):
        with pytest.raises(SystemExit) as refused:
            main([command, str(LIBRARY / "caterpillar.toml"), "--seconds", "1e-9"])
        assert refused.value.code == 2
        assert "the measured time must be >= 0.02" in capsys.readouterr().err
    with Simulation(load(LIBRARY / "caterpillar.toml")) as sim:
        metrics = sim.run(1e-9, warmup=0.1)
    assert metrics.seconds == 0.02 and metrics.speed > 0
    import inspect

    from gaits.cli import TICK

    rate = inspect.signature(Simulation.__init__).parameters["control_rate"].default
    assert 1 / rate == TICK  # stated twice (the command line does not import MuJoCo to parse its flags)
