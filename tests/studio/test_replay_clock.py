"""The replay's clock (issue 29): play, pause, scrub, speed and the end, on a wall clock the test moves; stepping
between recorded frames."""

from __future__ import annotations

import threading
from pathlib import Path

import pytest

from web.replay import SPEEDS, ReplayClock, step_time

from ..helpers import FakeTime, wait_until

pytestmark = pytest.mark.timeout(120)


def test_the_clock_plays_at_its_speed_pauses_and_stops_at_the_end() -> None:
    wall = FakeTime()
    clock = ReplayClock(10.0, wall)
    assert clock.time() == 0.0 and not clock.playing
    wall.now += 5  # paused: time stands
    assert clock.time() == 0.0
    clock.play()
    wall.now += 2
    assert clock.time() == 2.0
    clock.set_speed(4.0)
    wall.now += 1
    assert clock.time() == 6.0
    clock.pause()
    wall.now += 3
    assert clock.time() == 6.0
    clock.set_speed(0.25)
    clock.play()
    wall.now += 2
    assert clock.time() == 6.5
    wall.now += 100  # past the end: it stops there, paused
    assert clock.time() == 10.0 and clock.ended and not clock.playing
    clock.play()  # Play at the end starts again
    assert clock.time() == 0.0 and clock.playing


def test_a_scrub_keeps_playing_or_paused_and_clamps_to_the_recording() -> None:
    wall = FakeTime()
    clock = ReplayClock(10.0, wall)
    clock.seek(7.5)
    assert clock.time() == 7.5 and not clock.playing
    clock.play()
    wall.now += 1
    clock.seek(2.0)  # a scrub backwards while playing: it plays on from there (not from the end)
    wall.now += 1
    assert clock.time() == 3.0 and clock.playing
    clock.seek(-3)
    assert clock.time() == 0.0
    clock.seek(1e9)
    assert clock.time() == 10.0


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), "3", None, True, [1.0]])
def test_a_scrub_to_something_not_a_time_is_refused(bad: object) -> None:
    clock = ReplayClock(10.0, FakeTime())
    clock.seek(4.0)
    with pytest.raises(ValueError, match="replay time"):
        clock.seek(bad)  # type: ignore[arg-type]
    assert clock.time() == 4.0


@pytest.mark.parametrize("speed", [0.0, -1.0, 0.3, 8.0, float("nan")])
def test_speeds_other_than_the_offered_ones_are_refused_not_clamped(speed: float) -> None:
    clock = ReplayClock(10.0, FakeTime())
    with pytest.raises(ValueError, match="not one of"):
        clock.set_speed(speed)
    assert clock.speed == 1.0
    for ok in SPEEDS:
        clock.set_speed(ok)
        assert clock.speed == ok


@pytest.mark.parametrize("duration", [-1.0, float("nan"), float("inf")])
def test_a_clock_of_no_sensible_length_is_refused(duration: float) -> None:
    with pytest.raises(ValueError):
        ReplayClock(duration)


def test_stepping_goes_to_the_neighbouring_recorded_frame() -> None:
    times = [0.0, 0.1, 0.25, 0.4]
    assert step_time(times, 0.1, 1) == 0.25
    assert step_time(times, 0.12, 1) == 0.25
    assert step_time(times, 0.25, -1) == 0.1
    assert step_time(times, 0.3, -1) == 0.25
    assert step_time(times, 0.4, 1) == 0.4  # the last: stays
    assert step_time(times, 0.0, -1) == 0.0


def test_the_page_reads_the_replay_time_and_state_shown_together(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    """A fresh-clone run's page test read "t = 2.22 s · paused", then 2.23: the loop had paused the clock at 2.23 and
    not yet shown that time, and the page read the time shown before beside the clock's new state. The pair the
    page reads (``shown()``) is the time shown and the state it was shown in."""
    from web.recording import open_recording
    from web.replay import ReplaySource

    from .test_replay import write_recording

    path = tmp_path / "run.mcap"
    write_recording(path)
    real_show = ReplaySource._show  # pyright: ignore[reportPrivateUsage]
    armed, held, gate = threading.Event(), threading.Event(), threading.Event()

    def show(self: ReplaySource, t: float) -> None:
        if armed.is_set():  # the loop has handled a request and is about to show its time: held here
            held.set()
            gate.wait(10)
        real_show(self, t)

    monkeypatch.setattr(ReplaySource, "_show", show)
    monkeypatch.setattr(ReplaySource, "_until_next_frame", lambda self: 30.0)  # the loop wakes for requests only
    wall = FakeTime()
    source = ReplaySource(open_recording(path), wall)
    try:
        source.request("play")
        assert wait_until(lambda: source.shown() == (0.0, True), 10)
        wall.now += 1.0
        armed.set()
        source.request("pause")  # the clock pauses at 1.0; its showing is held
        assert held.wait(10)
        t, playing = source.shown()
        assert playing or t == 1.0, (t, playing)  # never "paused" beside a time before the pause
        armed.clear()
        gate.set()
        assert wait_until(lambda: source.shown() == (1.0, False), 10)
    finally:
        gate.set()
        source.close()
