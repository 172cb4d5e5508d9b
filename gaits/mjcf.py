"""The MuJoCo model of a gait's robot, generated as MJCF from the robot configuration.

PolyBot-like modules: cubes of ``module_size`` with one hinge through their centre, so a module is two halves and
neighbouring halves are rigidly joined. A chain of n modules is therefore n + 1 bodies (two half-cube end bodies
and n - 1 cubes) and n hinges, and ``joint m<i>`` / ``actuator m<i>`` belong to module i. The free joint sits on the
middle body: every contact then couples half as many joints back to the root. Chains of 32 modules or more collide
with capsules (half the contacts of boxes, about twice the speed).

Chains lie along +x; a pitch hinge turns about y (bending up and down), a yaw hinge about z. A loop is built
already closed, as a regular polygon standing in the x-z plane, and closed with a weld between its two end halves;
its joint angles are deviations from the polygon's bend. A legged robot is a central body with ``legs`` legs of
modules around it (hip yaw, then pitch joints), each leg ending in a foot that points down.

The text is plain MJCF: ``gaits simulate FILE --mjcf OUT.xml`` writes it, and MuJoCo's own viewer opens it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from .robot import Robot
from .terrain import FLAT, Ground, Terrain


@dataclass(frozen=True)
class Physics:
    """The simulated world around a robot: the ground's friction, the integrator, how contacts are modelled. What a
    module is — its size, mass, servo — is the gait's robot description (gaits/robot.py), module by module; the
    defaults are SIMULATION.md's measured model."""

    armature: float = 0.005
    friction: float = 1.0
    """Coulomb friction μ between modules and the ground."""
    anisotropic: tuple[float, float] | None = None
    """(μ along the module, μ across it): capsule contacts with explicit pairs, for snake-like undulation."""
    timestep: float = 0.002
    body_mass: float = 0.4
    """kg of a legged robot's central body."""
    capsules: bool | None = None
    """Collide with capsules along each module instead of boxes: half the contacts, about twice the speed, and
    what anisotropic friction needs. None: capsules for anisotropic ground and for chains of 32 modules or more."""


@dataclass(frozen=True)
class _Half:
    """Half a module, from its hinge to one end: a body is one or two of them (the halves on either side of a
    hinge are rigidly joined)."""

    length: float
    width: float
    height: float
    mass: float
    inertia: tuple[float, float, float] | None
    """kg·m² about the half's own centre when its type gives the module's inertia (else a solid box's)."""

    def moments(self) -> tuple[float, float, float]:
        if self.inertia is not None:
            return self.inertia
        m, x, y, z = self.mass, self.length, self.width, self.height
        return m * (y * y + z * z) / 12, m * (x * x + z * z) / 12, m * (x * x + y * y) / 12


def half_of(robot: Robot, module_id: int) -> _Half:
    """Either half of module ``module_id``: half its length and mass. A given inertia is split so that the two
    halves, each's mass a quarter of the length from the centre, add up to it (gaits/robot.py checks it can be)."""
    t = robot.module_type(module_id)
    length, width, height = robot.size_of(module_id)
    inertia = None
    if t.inertia is not None:
        ixx, iyy, izz = t.inertia
        spread = t.mass * length * length / 32  # (m/2)·(L/4)²: a half's mass off the module's centre
        inertia = (ixx / 2, iyy / 2 - spread, izz / 2 - spread)
    return _Half(length / 2, width, height, t.mass / 2, inertia)


def _f(x: float) -> str:
    return f"{x:.6g}"


def _v(*xs: float) -> str:
    return " ".join(_f(x) for x in xs)


def _quat_y(angle: float) -> str:
    """Quaternion for a rotation of ``angle`` rad about +y."""
    return _v(math.cos(angle / 2), 0.0, math.sin(angle / 2), 0.0)


def _quat_z(angle: float) -> str:
    return _v(math.cos(angle / 2), 0.0, 0.0, math.sin(angle / 2))


class _Writer:
    def __init__(self, robot: Robot, physics: Physics, ground: Ground) -> None:
        self.robot = robot
        self.ground = ground
        self.p = physics
        self.lines: list[str] = []
        self.pairs: list[str] = []
        self.excludes: list[tuple[str, str]] = []
        self.actuators: dict[int, str] = {}
        """Module number → its actuator (written in module order, so actuator i - 1 drives module i)."""
        self.capsules = physics.capsules
        if self.capsules is None:
            self.capsules = physics.anisotropic is not None or robot.modules >= 32

    def emit(self, depth: int, text: str) -> None:
        self.lines.append("  " * depth + text)

    def close_bodies(self, depth: int, count: int) -> None:
        """End ``count`` nested bodies opened at depths ``depth`` … ``depth + count - 1``."""
        for level in reversed(range(count)):
            self.emit(depth + level, "</body>")

    def segment(self, depth: int, name: str, parts: list[_Half], sign: float) -> None:
        """The geometry of one body: its module halves laid along ±x (``sign``) from the body frame. One box (or
        capsule) when they share a cross-section, one each otherwise; an explicit inertial when a type gives its
        inertia (MuJoCo then ignores the geoms' masses)."""
        first = parts[0]
        if all((p.width, p.height) == (first.width, first.height) for p in parts):
            self.piece(depth, name, sum(p.length for p in parts), first, sum(p.mass for p in parts), 0.0, sign)
        else:
            start = 0.0
            for k, p in enumerate(parts):
                self.piece(depth, name if k == 0 else f"{name}_{k + 1}", p.length, p, p.mass, start, sign)
                start += p.length
        if any(p.inertia is not None for p in parts):
            self.inertial(depth, parts, sign)

    def piece(self, depth: int, name: str, length: float, section: _Half, mass: float, start: float,
              sign: float) -> None:  # fmt: skip
        """A box of ``length`` and ``section``'s cross-section from ``start`` along ±x: a box geom, or a capsule
        colliding inside a visual box."""
        w, h = section.width / 2, section.height / 2
        cx = sign * (start + length / 2)
        if not self.capsules:
            self.emit(depth, f'<geom name="{name}" type="box" size="{_v(length / 2, w, h)}" pos="{_f(cx)} 0 0" '
                             f'mass="{_f(mass)}" class="module"/>')  # fmt: skip
        else:
            radius = min(w, h) * 0.9
            half = max(length / 2 - radius, 1e-3)
            self.emit(
                depth,
                f'<geom name="{name}" type="capsule" size="{_f(radius)}" '
                f'fromto="{_v(cx - half, 0, 0, cx + half, 0, 0)}" mass="{_f(mass)}" class="module"/>',
            )
            self.emit(depth, f'<geom type="box" size="{_v(length / 2, w, h)}" pos="{_f(cx)} 0 0" class="visual"/>')
            if self.p.anisotropic is None:
                return
            along, across = self.p.anisotropic
            for floor in self.ground.names:  # an explicit pair per ground geom: it overrides the geoms' friction
                self.pairs.append(f'<pair geom1="{name}" geom2="{floor}" condim="3" '
                                  f'friction="{_v(along, across, 0.005, 0.0001, 0.0001)}"/>')  # fmt: skip

    def inertial(self, depth: int, parts: list[_Half], sign: float) -> None:
        """The body's mass, centre and principal moments from its halves' (parallel axes along x)."""
        centres, start = [], 0.0
        for p in parts:
            centres.append(sign * (start + p.length / 2))
            start += p.length
        mass = math.fsum(p.mass for p in parts)
        xc = math.fsum(p.mass * x for p, x in zip(parts, centres, strict=True)) / mass
        moments = [p.moments() for p in parts]
        offsets = [p.mass * (x - xc) ** 2 for p, x in zip(parts, centres, strict=True)]
        ixx = math.fsum(i[0] for i in moments)
        iyy = math.fsum(i[1] + d for i, d in zip(moments, offsets, strict=True))
        izz = math.fsum(i[2] + d for i, d in zip(moments, offsets, strict=True))
        self.emit(depth, f'<inertial pos="{_f(xc)} 0 0" mass="{_f(mass)}" '
                         f'diaginertia="{ixx:.9g} {iyy:.9g} {izz:.9g}"/>')  # fmt: skip

    def hinge(self, depth: int, module: int, axis: tuple[float, float, float], bend: float = 0.0) -> None:
        """Module ``module``'s joint and actuator, from its type's range and servo (a loop's range shifted by its
        ``bend``, rad, to keep the mechanical ±range absolute)."""
        t = self.robot.module_type(module)
        limits = (-t.range + math.degrees(bend), t.range + math.degrees(bend)) if bend else (-t.range, t.range)
        lo, hi = (math.radians(v) for v in limits)
        self.emit(depth, f'<joint name="m{module}" type="hinge" axis="{_v(*axis)}" range="{_v(lo, hi)}"/>')
        self.actuators[module] = (f'<position name="m{module}" joint="m{module}" kp="{_f(t.kp)}" '
                                  f'kv="{_f(t.damping)}" ctrlrange="{_v(lo, hi)}" '
                                  f'forcerange="{_v(-t.stall_torque, t.stall_torque)}"/>')  # fmt: skip

    def axis(self, module_index: int) -> tuple[float, float, float]:
        return (0.0, 1.0, 0.0) if self.robot.axis(module_index) == "pitch" else (0.0, 0.0, 1.0)

    # -- chains and loops ---------------------------------------------------------------------------------------

    def chain(self, depth: int, bend: float) -> None:
        """Bodies b0..bn with hinges m1..mn; ``bend`` (rad) pre-bends every hinge about -y (loops)."""
        n = self.robot.modules
        half = [half_of(self.robot, k) for k in range(1, n + 1)]
        parts = [[half[0]], *([half[k - 1], half[k]] for k in range(1, n)), [half[n - 1]]]
        lengths = [sum(p.length for p in body) for body in parts]
        root = 0 if bend else n // 2
        # a chain is centred on the origin; a loop stands on its bottom edge (the two welded end halves)
        x = 0.0 if bend else -self.robot.length / 2 + sum(lengths[:root])
        self.emit(depth, f'<body name="b{root}" pos="{_v(x, 0, max(h.height for h in half) / 2)}">')
        self.emit(depth + 1, '<freejoint name="root"/>')
        self.segment(depth + 1, f"b{root}", parts[root], 1.0)
        # forward branch: b(k) is a child of b(k-1), framed at hinge k, extending +x
        forward = range(root + 1, n + 1)
        for level, k in enumerate(forward, start=depth + 1):
            rotation = f' quat="{_quat_y(-bend)}"' if bend else ""
            self.emit(level, f'<body name="b{k}" pos="{_f(lengths[k - 1])} 0 0"{rotation}>')
            self.hinge(level + 1, k, self.axis(k - 1), bend)
            self.segment(level + 1, f"b{k}", parts[k], 1.0)
        if bend:  # where the loop's last half ends: the weld brings it onto b0's start
            self.emit(depth + len(forward) + 1, f'<site name="loop_end" pos="{_f(lengths[n])} 0 0"/>')
        self.close_bodies(depth + 1, len(forward))
        # backward branch: b(k-1) is a child of b(k), framed at hinge k, extending -x, axis negated
        backward = range(root, 0, -1)
        for level, k in enumerate(backward, start=depth + 1):
            back = 0.0 if k == root else -lengths[k]  # b(k) is framed at hinge k + 1, except the root
            self.emit(level, f'<body name="b{k - 1}" pos="{_f(back)} 0 0">')
            x, y, z = self.axis(k - 1)
            self.hinge(level + 1, k, (-x, -y, -z), bend)
            self.segment(level + 1, f"b{k - 1}", parts[k - 1], -1.0)
        self.close_bodies(depth + 1, len(backward))
        self.emit(depth, "</body>")

    # -- legged -------------------------------------------------------------------------------------------------

    def legged(self, depth: int) -> None:
        """A central body with ``legs`` legs, half on each side (left legs point +y, right legs -y, numbered
        counter-clockwise from the front left). Each leg's first module is a hip (yaw), the others pitch (positive
        lifts the foot); the last module's distal half carries a foot post pointing down. The central body is
        sized by the default module type."""
        robot = self.robot
        s = robot.size[0]
        legs = robot.legs or 4
        per_leg = robot.modules // legs
        per_side = max(1, legs // 2)
        half = [half_of(robot, k) for k in range(1, robot.modules + 1)]
        length, width = 1.5 * s * per_side, s  # half extents of the central body
        foot = 1.2 * s
        self.emit(depth, f'<body name="body" pos="0 0 {_f(foot + 0.002)}">')
        self.emit(depth + 1, '<freejoint name="root"/>')
        self.emit(depth + 1, f'<geom name="body" type="box" size="{_v(length, width, s / 2)}" '
                             f'mass="{_f(self.p.body_mass)}" class="module"/>')  # fmt: skip
        module = 0
        for leg in range(legs):
            left = leg < per_side
            slot = leg if left else legs - 1 - leg  # 0 = frontmost on either side
            x = length * (1 - (2 * slot + 1) / per_side) if per_side > 1 else 0.0
            y, yaw = (width, math.pi / 2) if left else (-width, -math.pi / 2)
            d = depth + 1
            self.emit(d, f'<body name="leg{leg}" pos="{_v(x, y, 0)}" quat="{_quat_z(yaw)}">')
            self.segment(d + 1, f"leg{leg}", [half[module]], 1.0)  # the hip module's proximal half, on the body
            for j in range(per_leg):
                module += 1
                d += 1
                last = j == per_leg - 1
                mine = half[module - 1]
                hinge = mine.length if j == 0 else half[module - 2].length + mine.length  # from the last hinge
                self.emit(d, f'<body name="b{module}" pos="{_f(hinge)} 0 0">')
                self.hinge(d + 1, module, (0.0, 0.0, 1.0) if j == 0 else (0.0, -1.0, 0.0))
                self.segment(d + 1, f"b{module}", [mine] if last else [mine, half[module]], 1.0)
                if last:
                    self.emit(d + 1, f'<geom name="foot{leg}" type="capsule" size="{_f(mine.length / 2)}" '
                                     f'fromto="{_v(mine.length, 0, 0, mine.length, 0, -foot + mine.length / 2)}" '
                                     f'mass="0.01" class="module"/>')  # fmt: skip
            self.close_bodies(depth + 1, per_leg + 1)
        self.emit(depth, "</body>")


def build_mjcf(robot: Robot, physics: Physics | None = None, *, name: str = "robot", terrain: Terrain = FLAT) -> str:
    """The MJCF text of ``robot``: modules, actuators, the ground of ``terrain`` and (for loops) the closing weld."""
    p = physics or Physics()
    if p.anisotropic is not None and terrain.kind == "patches":
        # anisotropic friction is an explicit pair per module and ground geom, whose friction overrides the tile's
        raise ValueError("friction patches need isotropic ground friction; this gait's [ground] is anisotropic")
    ground = terrain.ground(p.friction)
    w = _Writer(robot, p, ground)
    if robot.shape == "legged":
        w.legged(2)
    elif robot.shape == "loop":
        w.chain(2, 2 * math.pi / robot.modules)
    else:
        w.chain(2, 0.0)
    n = robot.modules
    extras: list[str] = []
    if robot.shape == "loop":
        extras.append("  <equality>")
        extras.append(f'    <weld body1="b{n}" body2="b0" solref="0.004 1"/>')
        extras.append("  </equality>")
        w.excludes.append((f"b{n}", "b0"))
    contact = [f'    <exclude body1="{a}" body2="{b}"/>' for a, b in w.excludes] + [f"    {p_}" for p_ in w.pairs]
    # SIMULATION.md recommends jacobian="dense" and cone="elliptic" for 128 modules; on this build of MuJoCo both
    # measured slower for a moving 128-module capsule chain (1 730 steps/s vs 3 670 with the defaults), so the
    # defaults stay: bench/sim.py keeps the figures honest.
    option = f'<option timestep="{_f(p.timestep)}" integrator="implicitfast" gravity="{_v(*ground.gravity)}"/>'
    parts = [
        f'<mujoco model="{name}">',
        '  <compiler angle="radian"/>',
        f"  {option}",
        "  <default>",
        f'    <joint armature="{_f(p.armature)}" damping="0.01"/>',
        '    <default class="module">',
        f'      <geom condim="3" solref="0.004 1" friction="{_v(p.friction, 0.005, 0.0001)}" rgba="0.85 0.55 0.15 1"/>',
        "    </default>",
        '    <default class="visual">',
        '      <geom contype="0" conaffinity="0" group="1" mass="0" rgba="0.85 0.55 0.15 1"/>',
        "    </default>",
        "  </default>",
        "  <visual>",
        '    <global offwidth="1280" offheight="720"/>',
        "  </visual>",
        *(["  <asset>", *(f"    {a}" for a in ground.assets), "  </asset>"] if ground.assets else []),
        "  <worldbody>",
        '    <light pos="0 0 3" dir="0 0 -1" directional="true"/>',
        *(f"    {g}" for g in ground.geoms),
        *w.lines,
        "  </worldbody>",
    ]
    if contact:
        parts += ["  <contact>", *contact, "  </contact>"]
    parts += extras
    actuators = (f"    {w.actuators[module]}" for module in sorted(w.actuators))
    parts += ["  <actuator>", *actuators, "  </actuator>", "</mujoco>"]
    return "\n".join(parts) + "\n"
