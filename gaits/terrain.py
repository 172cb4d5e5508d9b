"""The ground a gait is simulated on: flat (the default), a slope, a step, rough ground, friction patches.

A gait that works on the flat floor of the preview may not work on the robot's floor; simulating it on a few
harder grounds (and tuning it there, gaits/tune.py) is how a user finds out before deploying. A terrain is written
as a short spec, so a command line can name several::

    flat
    slope:5                                  uphill along +x, degrees (negative: downhill); slope:5,heading=90
    step:0.03                                a square pit 2·at wide (at=0.3 m), 3 cm deep: a step up every way out
    rough:seed=3,roughness=0.02              a height field, random bumps up to 2 cm (cell=0.05 m), fixed by the seed
    patches:friction=0.3                     tiles of μ 0.3 among the ground's μ (fraction=0.5, size=0.25, seed=0)

:func:`parse` checks every number and names what is wrong in one ``ValueError``; :meth:`Terrain.ground` gives the
MJCF that gaits/mjcf.py puts in the model. Everything is generated (the height field's elevations are written in
the MJCF itself), so a terrain needs no file and the same spec always gives the same model.

A slope tilts gravity rather than the floor: physically the same for a plane, and the robot starts lying on it
without having to be placed on an incline; the metrics are then measured along the slope's surface.
"""

from __future__ import annotations

import argparse
import math
from dataclasses import dataclass, field

import numpy as np

KINDS = ("flat", "slope", "step", "rough", "patches")
GRAVITY = 9.81
"""m/s², MuJoCo's default gravity."""

_PARAMETERS: dict[str, dict[str, tuple[float, float]]] = {
    # kind → parameter → (lowest, highest) allowed; the first one is what a bare number after the colon sets
    "flat": {},
    "slope": {"angle": (-45.0, 45.0), "heading": (-360.0, 360.0)},
    "step": {"height": (0.001, 0.2), "at": (0.05, 10.0)},
    "rough": {"roughness": (0.0, 0.1), "seed": (0, 2**31 - 1), "cell": (0.01, 0.5), "extent": (0.5, 20.0)},
    "patches": {
        "friction": (0.001, 5.0),  # μ 0 (as the [ground] table refuses): the robot diverged on it
        "fraction": (0.0, 1.0),
        "size": (0.05, 2.0),
        "seed": (0, 2**31 - 1),
        "extent": (0.5, 10.0),
    },
}
_DEFAULTS: dict[str, dict[str, float]] = {
    "flat": {},
    "slope": {"angle": 5.0, "heading": 0.0},
    "step": {"height": 0.03, "at": 0.3},
    "rough": {"roughness": 0.02, "seed": 0, "cell": 0.05, "extent": 4.0},
    "patches": {"friction": 0.3, "fraction": 0.5, "size": 0.25, "seed": 0, "extent": 4.0},
}
_INTEGERS = {"seed"}
MAX_HFIELD_CELLS = 250_000
"""A rough ground's height field has at most this many cells (500 × 500): the MJCF text stays a few MB."""
MAX_TILES = 4096
"""Friction patches are at most this many tiles: every tile is a geom the collision detection looks at."""


@dataclass(frozen=True)
class Ground:
    """The MJCF of a terrain: what goes in ``<asset>``, the ground geoms in ``<worldbody>`` and the gravity."""

    assets: list[str] = field(default_factory=list)
    geoms: list[str] = field(default_factory=list)
    """Each ground geom's name starts with "floor": the contact sensors and anisotropic pairs look for it."""
    gravity: tuple[float, float, float] = (0.0, 0.0, -GRAVITY)
    names: list[str] = field(default_factory=list)
    """The ground geoms' names."""


@dataclass(frozen=True)
class Terrain:
    """One ground: its kind and its parameters (all checked by :func:`parse`, which is the way to make one)."""

    kind: str = "flat"
    params: tuple[tuple[str, float], ...] = ()
    """(name, value) in the order of _PARAMETERS: every parameter of the kind, defaults filled in."""

    def __getitem__(self, name: str) -> float:
        return dict(self.params)[name]

    @property
    def spec(self) -> str:
        """The spec that parses back to this terrain (every parameter written out)."""
        if not self.params:
            return self.kind
        return f"{self.kind}:" + ",".join(f"{k}={_number(v)}" for k, v in self.params)

    def __str__(self) -> str:
        return self.spec

    def ground(self, friction: float = 1.0) -> Ground:
        """The ground geoms of this terrain for a robot whose default ground friction is ``friction``."""
        plane = _plane("floor", 0.0, friction)
        if self.kind == "flat":
            return Ground(geoms=[plane], names=["floor"])
        if self.kind == "slope":
            a, h = math.radians(self["angle"]), math.radians(self["heading"])
            # uphill along the heading: gravity gets a component pointing downhill, -heading
            down = GRAVITY * math.sin(a)
            gravity = (-down * math.cos(h), -down * math.sin(h), -GRAVITY * math.cos(a))
            return Ground(geoms=[plane], gravity=gravity, names=["floor"])
        if self.kind == "step":
            return self._step(friction)
        if self.kind == "rough":
            return self._rough(friction)
        return self._patches(friction)

    def _step(self, friction: float) -> Ground:
        """A square pit around the start: four raised boxes whose inner edges are ``at`` from the origin."""
        height, at = self["height"], self["at"]
        far = 50.0  # half-length of each raised slab: beyond any run
        hz = height / 2
        slabs = [((at + far) / 2 * sx, 0.0, (far - at) / 2, far) for sx in (1, -1)]  # ±x, the whole width
        slabs += [(0.0, (at + far) / 2 * sy, at, (far - at) / 2) for sy in (1, -1)]  # ±y, between the x slabs
        geoms, names = [_plane("floor", 0.0, friction)], ["floor"]
        for k, (x, y, hx, hy) in enumerate(slabs, start=1):
            names.append(f"floor_step{k}")
            geoms.append(f'<geom name="floor_step{k}" type="box" pos="{_v(x, y, hz)}" size="{_v(hx, hy, hz)}" '
                         f'condim="3" friction="{_v(friction, 0.005, 0.0001)}" rgba="0.7 0.7 0.75 1"/>')  # fmt: skip
        return Ground(geoms=geoms, names=names)

    def elevations(self) -> np.ndarray:
        """The rough ground's heights, metres (rows along y, columns along x), from its seed alone.

        Uniform noise on a ``cell`` grid, then the 3×3 mean of it: bumps a module can climb rather than spikes, and
        still nothing but the seed decides them."""
        n = self._cells()
        rng = np.random.default_rng(int(self["seed"]))
        noise = rng.random((n + 2, n + 2))
        smooth = np.zeros((n, n))
        for i in range(3):
            for j in range(3):
                smooth += noise[i : i + n, j : j + n] / 9.0
        low, high = float(smooth.min()), float(smooth.max())
        unit = (smooth - low) / (high - low) if high > low else np.zeros_like(smooth)
        return unit * self["roughness"]

    def _cells(self) -> int:
        return round(self["extent"] / self["cell"]) + 1

    def _rough(self, friction: float) -> Ground:
        """A height field ``extent`` wide, its highest bump at z = 0 (the robot settles onto it), over a plane at
        its base so a robot that walks off it does not fall for ever."""
        roughness, half = self["roughness"], self["extent"] / 2
        n = self._cells()
        heights = self.elevations()
        top = max(roughness, 1e-4)  # MuJoCo needs a positive elevation scale even for a flat field
        data = " ".join(f"{h / top:.4f}" for h in heights.ravel())
        assets = [f'<hfield name="rough" nrow="{n}" ncol="{n}" size="{_v(half, half, top, 0.01)}" '
                  f'elevation="{data}"/>']  # fmt: skip
        geoms = [
            f'<geom name="floor" type="hfield" hfield="rough" pos="0 0 {_f(-top)}" condim="3" '
            f'friction="{_v(friction, 0.005, 0.0001)}" rgba="0.6 0.55 0.5 1"/>',
            _plane("floor_base", -top, friction),
        ]
        return Ground(assets=assets, geoms=geoms, names=["floor", "floor_base"])

    def tiles(self) -> np.ndarray:
        """Which tiles of the patches are slippery (True), from the seed alone (rows along y, columns along x)."""
        n = max(1, round(self["extent"] / self["size"]))
        return np.random.default_rng(int(self["seed"])).random((n, n)) < self["fraction"]

    def _patches(self, friction: float) -> Ground:
        """Square tiles ``size`` wide over ``extent``, each of the patch friction or the ground's, with their tops at
        z = 0. The plain floor lies 1 cm lower: were it at z = 0 too, a module on a tile would touch both and feel
        a mix of the two frictions. Beyond the tiles, then, the ground is 1 cm lower."""
        slippery = self.tiles()
        n, size = slippery.shape[0], self["size"]
        start = -n * size / 2 + size / 2
        geoms, names = [_plane("floor", -0.01, friction)], ["floor"]
        for (row, col), low in np.ndenumerate(slippery):
            mu = self["friction"] if low else friction
            name = f"floor_tile{row}_{col}"
            names.append(name)
            colour = "0.55 0.7 0.85 1" if low else "0.8 0.8 0.8 1"
            geoms.append(f'<geom name="{name}" type="box" pos="{_v(start + col * size, start + row * size, -0.01)}" '
                         f'size="{_v(size / 2, size / 2, 0.01)}" condim="3" friction="{_v(mu, 0.005, 0.0001)}" '
                         f'{TILE_CONTACT} rgba="{colour}"/>')  # fmt: skip
        return Ground(geoms=geoms, names=names)


FLAT = Terrain()

TILE_CONTACT = 'priority="1" solref="0.012 1"'
"""A tile's contact with a module is the tile's own: MuJoCo takes the larger friction of two geoms of one priority,
so a slippery tile under the modules' μ (their default class's, the ground's) slid nothing at all. With priority the
tile's parameters win, so its solref is the one the two geoms mixed before (solmix 1 each: the mean of the modules'
0.004 and the default 0.02), and a tile of the ground's own μ touches exactly as before."""


def parse(spec: str) -> Terrain:
    """The terrain a spec names (see the module docstring); ValueError saying what is wrong and what is allowed."""
    if not isinstance(spec, str):
        raise ValueError(f"a terrain spec is a string, not {type(spec).__name__}")
    text = spec.strip()
    kind, colon, rest = text.partition(":")
    kind = kind.strip().lower()
    if kind not in KINDS:
        raise ValueError(f"terrain {spec!r}: unknown kind {kind!r}; one of {', '.join(KINDS)} "
                         "(e.g. slope:5, step:0.03, rough:seed=3,roughness=0.02, patches:friction=0.3)")  # fmt: skip
    allowed = _PARAMETERS[kind]
    values = dict(_DEFAULTS[kind])
    if colon and not rest.strip():  # "slope:" is a spec cut short, not the default slope
        if kind == "flat":
            raise ValueError(f"terrain {spec!r}: flat takes no parameters")
        example = f"{kind}:{_number(next(iter(_DEFAULTS[kind].values())))}"
        raise ValueError(f"terrain {spec!r}: nothing after the colon (e.g. {example})")
    items = [item.strip() for item in rest.split(",")] if rest.strip() else []
    if kind == "flat" and items:
        raise ValueError(f"terrain {spec!r}: flat takes no parameters")
    given: set[str] = set()
    for k, item in enumerate(items):
        name, equals, value = item.partition("=")
        if not equals:  # a bare number: the kind's first parameter
            if k:
                raise ValueError(f"terrain {spec!r}: {item!r} needs a name (name=value); only the first may be bare")
            name, value = next(iter(allowed)), item
        name = name.strip()
        if name not in allowed:
            raise ValueError(f"terrain {spec!r}: {kind} has no parameter {name!r} (it has {', '.join(allowed)})")
        if name in given:  # slope:5,angle=6 gives the angle twice: which was meant is not for us to guess
            raise ValueError(f"terrain {spec!r}: {name} is given twice")
        given.add(name)
        values[name] = _value(spec, name, value.strip(), allowed[name])
    if kind == "rough" and (round(values["extent"] / values["cell"]) + 1) ** 2 > MAX_HFIELD_CELLS:
        raise ValueError(f"terrain {spec!r}: extent / cell gives more than {MAX_HFIELD_CELLS} height-field cells")
    if kind == "patches" and round(values["extent"] / values["size"]) ** 2 > MAX_TILES:
        raise ValueError(f"terrain {spec!r}: extent / size gives more than {MAX_TILES} tiles")
    return Terrain(kind, tuple((name, values[name]) for name in allowed))


def _value(spec: str, name: str, text: str, bounds: tuple[float, float]) -> float:
    low, high = bounds
    try:
        value = int(text) if name in _INTEGERS else float(text)
    except ValueError:
        kind = "an integer" if name in _INTEGERS else "a number"
        raise ValueError(f"terrain {spec!r}: {name} must be {kind}, not {text!r}") from None
    if not math.isfinite(value) or not low <= value <= high:
        raise ValueError(f"terrain {spec!r}: {name} must be in [{_number(low)}, {_number(high)}], not {text}")
    return value


def argument(spec: str) -> Terrain:
    """argparse's view of :func:`parse`: a bad spec is a usage error (exit 2) naming what is wrong."""
    try:
        return parse(spec)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _number(x: float) -> str:
    return str(int(x)) if float(x).is_integer() else f"{x:g}"


def _f(x: float) -> str:
    return f"{x:.6g}"


def _v(*xs: float) -> str:
    return " ".join(_f(x) for x in xs)


def _plane(name: str, z: float, friction: float) -> str:
    return (f'<geom name="{name}" type="plane" size="0 0 0.05" pos="0 0 {_f(z)}" condim="3" '
            f'friction="{_v(friction, 0.005, 0.0001)}" rgba="0.8 0.8 0.8 1"/>')  # fmt: skip
