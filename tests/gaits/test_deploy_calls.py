"""gaits.calls: a call's timeout follows the round trips measured, and doubles after each timeout (RFC 6298 §5.5).

Reproduces a drive refused on a busy machine: three attempts of ~60 ms each (the old backoff doubled a variation of
a millisecond, so the timeout barely grew) gave up after 0.18 s while the robot was only slow."""

from __future__ import annotations

from gaits.calls import MIN_TIMEOUT, RoundTrips


def test_each_timeout_doubles_the_next_wait_until_a_reply_is_measured() -> None:
    trips = RoundTrips(limit=2.0)
    for _ in range(20):
        trips.measured(0.002)  # a quiet robot: 2 ms round trips
    first = trips.timeout()
    assert first == MIN_TIMEOUT
    trips.timed_out()
    assert trips.timeout() == 2 * first
    trips.timed_out()
    assert trips.timeout() == 4 * first
    for _ in range(10):
        trips.timed_out()
    assert trips.timeout() == 2.0  # never past the caller's bound
    trips.measured(0.002)
    assert trips.timeout() == MIN_TIMEOUT  # a reply ends the backoff


def test_three_attempts_wait_long_enough_for_a_robot_busy_for_a_third_of_a_second() -> None:
    trips = RoundTrips(limit=2.0)
    for _ in range(20):
        trips.measured(0.002)
    waited = 0.0
    for _ in range(3):
        waited += trips.timeout()
        trips.timed_out()
    assert waited >= 0.35
