"""The gait generator and the whole-gait operations: what they make is a valid gait that locomotes, and what they
cannot do changes nothing."""

from __future__ import annotations

import pytest

from gaits.generate import FAMILIES, WaveSpec, generate
from gaits.model import dumps, loads
from gaits.sim import Simulation
from web.document import GaitDocument


@pytest.mark.parametrize("family", FAMILIES)
def test_each_family_makes_a_valid_gait_that_round_trips(family: str) -> None:
    gait = generate(WaveSpec(family=family, modules=12, states=24))
    again = loads(dumps(gait))
    assert again == gait
    assert again.robot.modules == 12 and {len(a.states) for a in again.automata.values()} == {24}
    assert again.period == pytest.approx(1.0)


def test_a_generated_12_module_sidewinding_gait_locomotes() -> None:
    gait = generate(WaveSpec(family="sidewinding", modules=12, amplitude=60.0, wavelength=12.0))
    assert gait.robot.axes == "alternating" and set(gait.automata) == {"pitch", "yaw"}
    with Simulation(gait) as sim:
        metrics = sim.run(3.0, warmup=1.0)
    assert metrics.distance > 0.3  # about 1.3 m in 4 s on this machine's measurement; generous


def test_the_wave_travels_one_wavelength_per_neighbour_step() -> None:
    gait = generate(WaveSpec(modules=8, wavelength=4.0))
    phases = [m.phase for m in gait.modules]
    assert phases[:5] == pytest.approx([0.0, 0.75, 0.5, 0.25, 0.0])


@pytest.mark.parametrize(
    ("spec", "message"),
    [
        (WaveSpec(modules=1), "modules"),
        (WaveSpec(modules=300), "modules"),
        (WaveSpec(family="rolling_loop", modules=12, wavelength=5.0), "whole number of waves"),
        (WaveSpec(amplitude=120.0), "amplitude"),
        (WaveSpec(amplitude=80.0, offset=20.0), "beyond"),
        (WaveSpec(period=0.0), "period"),
        (WaveSpec(period=float("nan")), "period"),
        (WaveSpec(states=1), "states"),
        (WaveSpec(states=5000), "states"),
        (WaveSpec(wavelength=0.0), "wavelength"),
        (WaveSpec(family="hopping"), "family"),
        (WaveSpec(axes="roll"), "axes"),
    ],
)
def test_a_spec_that_cannot_be_made_is_refused_with_its_reason(spec: WaveSpec, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        generate(spec)


def test_whole_gait_operations_are_one_undo_step_each_and_refuse_what_breaks_limits() -> None:
    doc = GaitDocument(generate(WaveSpec(modules=6, amplitude=40.0)))
    doc.shift_phases(0.25)
    assert [m.phase for m in doc.gait().modules][:2] == pytest.approx([0.25, (5 / 6 + 0.25) % 1], abs=1e-6)
    doc.spread_phases()
    assert [m.phase for m in doc.gait().modules] == pytest.approx([0.0, 5 / 6, 4 / 6, 3 / 6, 2 / 6, 1 / 6], abs=1e-6)
    peak = max(abs(s.angle) for s in doc.gait().automata["wave"].states)
    doc.scale_amplitude(2.0)
    assert max(abs(s.angle) for s in doc.gait().automata["wave"].states) == pytest.approx(2 * peak, abs=0.01)
    before = doc.data()
    with pytest.raises(ValueError, match="outside the limits"):
        doc.scale_amplitude(3.0)  # 240° would leave ±90°
    assert doc.data() == before
    doc.set_meta("name", "my_wave")
    doc.set_meta("description", "mine")
    assert doc.gait().name == "my_wave" and 'name = "my_wave"' in doc.text()
    assert doc.undo() and doc.undo() and doc.gait().name == "travelling_wave"
    assert doc.undo() and doc.undo() and doc.undo() and not doc.undo()
