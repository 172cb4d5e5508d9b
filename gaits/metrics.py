"""What a simulated run achieved (:class:`Metrics`): the numbers `gaits simulate`, the tuner and the benches judge a
gait by, apart from the simulation that measures them (gaits/sim.py)."""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass
class Metrics:
    """What a run achieved, measured on the centre of mass after the warm-up."""

    seconds: float
    """Simulated seconds measured (after the warm-up)."""
    displacement: tuple[float, float]
    """Centre-of-mass travel (x, y), metres."""
    body_length: float
    """The modules' lengths laid end to end, metres."""
    peak_torque: float
    """Largest absolute actuator torque seen, N·m."""
    fell: bool
    """The robot lay on its side (chains, loops) or upside down (legged) at any instant measured (a tumble it
    rolled out of counts), sampled as the peak torque is."""
    real_time_factor: float = 0.0
    """Simulated seconds per wall-clock second of the whole run."""
    energy: float = 0.0
    """Mechanical work of the joints, J: Σ|τ·ω| over the joints, integrated (sampled once per physics block, as
    the peak torque is, the torque and velocity of the same instant): what the servos spend, negative work counted
    too since a servo does not recover it."""
    mass: float = 0.0
    """The robot's mass, kg."""
    turned: float = 0.0
    """How far the robot's heading turned, degrees counter-clockwise (unwrapped: two turns are 720)."""
    peak_load: float = 0.0
    """The largest share of its own servo's stall torque any module exerted (1: at stall), sampled as the peak
    torque is: what judges a robot whose module types have different servos."""

    @property
    def distance(self) -> float:
        return math.hypot(*self.displacement)

    @property
    def body_lengths(self) -> float:
        return self.distance / self.body_length

    @property
    def speed(self) -> float:
        """Mean speed, m/s."""
        return self.distance / self.seconds if self.seconds > 0 else 0.0

    @property
    def heading(self) -> float:
        """Direction of travel, degrees from +x (the chain's axis, the legged body's front) counter-clockwise."""
        return math.degrees(math.atan2(self.displacement[1], self.displacement[0]))

    @property
    def body_lengths_per_10s(self) -> float:
        """Progress in body lengths per 10 s (the default run); 0 over no time."""
        return self.body_lengths / self.seconds * 10.0 if self.seconds > 0 else 0.0

    @property
    def stuck(self) -> bool:
        """Less than half a body length of progress per 10 s: a rate, so that a short run of a gait that crawls is
        not called stuck, nor a long run of one that hardly moves free (a user review: 0.2 m in 1 s was "stuck")."""
        return self.body_lengths_per_10s < 0.5

    @property
    def moved(self) -> bool:
        """At least a hundredth of a body length: below it a heading is the direction of noise and a cost of
        transport a meaningless huge number (or a misleading 0.00)."""
        return self.body_lengths >= 0.01

    def heading_text(self) -> str:
        """The direction of travel for a person: "n/a" for a robot that did not move (``moved``)."""
        if not self.moved:
            return "n/a (did not move)"
        return f"{unsigned_zero(self.heading, 1)} degrees from +x"

    @property
    def cost_of_transport(self) -> float:
        """Energy / (mass · g · distance): dimensionless, lower is better; inf when the robot did not move."""
        distance = self.distance
        return self.energy / (self.mass * 9.81 * distance) if distance > 0 and self.mass > 0 else math.inf

    def cost_text(self) -> str:
        """The cost of transport for a person: "n/a" for a robot that hardly moved (under a hundredth of a body
        length), whose energy over a near-zero distance is a meaningless huge number (or a misleading 0.00)."""
        if not self.moved or not math.isfinite(self.cost_of_transport):
            return "n/a (did not move)"
        return f"{self.cost_of_transport:.2f}"

    @property
    def heading_rate(self) -> float:
        """Mean turning rate, degrees per second counter-clockwise (the heading drift of a straight gait)."""
        return self.turned / self.seconds if self.seconds > 0 else 0.0

    def along(self, heading_deg: float) -> float:
        """Progress along a direction, metres (negative: it went the other way)."""
        a = math.radians(heading_deg)
        return self.displacement[0] * math.cos(a) + self.displacement[1] * math.sin(a)

    def across(self, heading_deg: float) -> float:
        """Drift across a direction, metres (absolute)."""
        a = math.radians(heading_deg)
        return abs(-self.displacement[0] * math.sin(a) + self.displacement[1] * math.cos(a))

    def summary(self) -> str:
        return (f"distance {self.distance:.3f} m = {self.body_lengths:.2f} BL in {self.seconds:g} s, "
                f"speed {self.speed:.3f} m/s, heading {self.heading:.1f}°, peak torque {self.peak_torque:.2f} N·m, "
                f"heading drift {self.turned:.1f}°, cost of transport {self.cost_text()}, "
                f"fell {'yes' if self.fell else 'no'}, stuck {'yes' if self.stuck else 'no'}, "
                f"real-time factor {self.real_time_factor:.1f}")  # fmt: skip


def unsigned_zero(value: float, digits: int) -> str:
    """``value`` to ``digits`` decimals, never "-0" (a heading of -0.3° is shown as 0°, not -0°)."""
    return f"{round(value, digits) + 0.0:.{digits}f}"
