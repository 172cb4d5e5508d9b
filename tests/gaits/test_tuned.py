"""The tuned gaits bench/tune.py wrote (gaits/tuned/): they say how they were made, and they hold up as the library
gaits do (tests/gaits/test_sim.py) — direction -1 runs them the other way as far, and a 1 N sideways push neither
stops nor topples them — so a tuned gait is not a fragile one found at the edge of the simulation."""

from __future__ import annotations

from pathlib import Path

import pytest

from gaits.model import LIBRARY, load
from gaits.sim import Simulation

pytestmark = pytest.mark.timeout(120)
TUNED = sorted((Path(__file__).resolve().parents[2] / "gaits" / "tuned").glob("*.toml"))
MINIMUM = 3.0
"""Body lengths in 10 s after 2 s, as for the library caterpillar they were tuned from."""


def _run(path: Path, **options):
    with Simulation(load(path), direction=options.pop("direction", 1)) as sim:
        return sim.run(10.0, warmup=2.0, **options)


def test_there_are_tuned_gaits():
    assert {p.name for p in TUNED} >= {"caterpillar_flat.toml", "caterpillar_rough.toml"}


@pytest.mark.parametrize("path", TUNED, ids=lambda p: p.stem)
def test_a_tuned_gait_says_how_it_was_made_and_beats_its_start(path):
    lines = path.read_text(encoding="utf-8").splitlines()
    assert lines[0].startswith("# Tuned by `gaits tune` from caterpillar.toml: objective speed")
    assert any(line.startswith("# free amplitude=20:85 = ") for line in lines)
    assert load(path).description.startswith("Tuned for speed (")
    ahead, library = _run(path), _run(LIBRARY / "caterpillar.toml")
    assert ahead.speed > 1.2 * library.speed, (ahead.summary(), library.summary())
    assert ahead.body_lengths >= MINIMUM and not ahead.fell and ahead.peak_torque <= 1.5 + 1e-6


@pytest.mark.parametrize("path", TUNED, ids=lambda p: p.stem)
def test_direction_minus_one_runs_a_tuned_gait_the_other_way(path):
    ahead, back = _run(path), _run(path, direction=-1)
    dot = back.displacement[0] * ahead.displacement[0] + back.displacement[1] * ahead.displacement[1]
    assert dot < 0, (ahead.summary(), back.summary())
    assert back.body_lengths >= MINIMUM and not back.fell, back.summary()


@pytest.mark.parametrize("path", TUNED, ids=lambda p: p.stem)
def test_a_sideways_push_does_not_stop_a_tuned_gait(path):
    ahead = _run(path)
    pushed = _run(path, push_at=6.0, push=(0.0, 1.0, 0.0), push_seconds=0.1)
    assert pushed.body_lengths >= MINIMUM and not pushed.fell, pushed.summary()
    assert pushed.displacement[0] * ahead.displacement[0] + pushed.displacement[1] * ahead.displacement[1] > 0
