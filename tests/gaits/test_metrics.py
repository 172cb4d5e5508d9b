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
