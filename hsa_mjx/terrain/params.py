"""Parameters of the eleven terrain generators and the ``terrain:`` config section, with validation.

Defaults are the original dispatcher's (``generate_terrain``), converted to world units: lengths
and heights in metres (the original's height "values" times its 0.5 m elevation scale, its cell
counts times its assumed 0.2 m cell), fractions of the field as fractions, angles in degrees of
**physical** slope. ``docs/terrain.md`` lists each conversion.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from typing import Any

TERRAIN_TYPES = (
    "wavy",
    "perlin",
    "stairs",
    "flat",
    "incline",
    "craters",
    "poles",
    "flat_with_incline",
    "flat_with_ramp",
    "corridor",
    "spiral",
)
RANDOM_TYPES = ("perlin", "craters", "poles")  # the others ignore the key
AXES = ("x", "y")
INCLINE_DIRECTIONS = ("x", "y", "diagonal")
RAMP_DIRECTIONS = ("x", "-x", "y", "-y")
POLE_GRADES = ("height", "count")
MAX_LEVELS = 64


@dataclasses.dataclass(frozen=True)
class WavyParams:
    """amplitude * sin(scale x) * cos(scale y)."""

    scale: float = 1.5  # rad per metre (original 0.3 per 0.2 m cell)
    amplitude: float = 0.075  # m (original 0.15 x 0.5 m)


@dataclasses.dataclass(frozen=True)
class PerlinParams:
    """Fractal Perlin noise, a new random field per key (the original's was the same every time)."""

    scale: float = 0.5  # noise frequency per metre (original 0.1 per cell)
    octaves: int = 2
    persistence: float = 0.5
    lacunarity: float = 2.0
    amplitude: float = 0.5  # m per unit of noise (original: noise value x 0.5 m)


@dataclasses.dataclass(frozen=True)
class StairsParams:
    """Steps rising along +x; the step under the spawn point (|x| < step_length / 2) is at 0."""

    step_height: float = 0.04  # m (original 0.08 x 0.5 m)
    step_length: float = 1.0  # m (original pixels_per_step 5 x 0.2 m)


@dataclasses.dataclass(frozen=True)
class InclineParams:
    """A plane through the spawn point with the given physical slope."""

    angle: float = 1.04  # degrees; the slope the original's "angle 20" actually produced
    direction: str = "x"  # x | y | diagonal (the original's default 'y' rose along world x)


@dataclasses.dataclass(frozen=True)
class CratersParams:
    """Gaussian dips -depth exp(-d^2 / (2 (r/3)^2)) inside radius r at random vertices; overlaps add."""

    num: int = 25
    radius: tuple[float, float] = (0.6, 1.0)  # m (original 3-5 cells)
    depth: tuple[float, float] = (0.05, 0.1)  # m (original 0.10-0.20 x 0.5 m)


@dataclasses.dataclass(frozen=True)
class PolesParams:
    """Up to ``num`` poles at random vertices, no two closer than ``min_spacing``.

    ``grade`` is what the difficulty scales: ``height`` (the original's poles, lower at lower levels) or
    ``count`` (full-height poles, ``ceil(difficulty x num)`` of them: open ground grows into the full
    maze, the gaps closing towards ``min_spacing`` less a pole's width).
    """

    num: int = 75
    radius: tuple[float, float] = (0.2, 0.2)  # m (original 1 cell: a single-vertex spike)
    height: tuple[float, float] = (0.75, 1.25)  # m (original 1.5-2.5 x 0.5 m), at most max_height
    min_spacing: float = 0.6  # m (original 3 cells)
    grade: str = "height"  # height | count
    # m: the original's poles end at its height field's top, 0.5 m above the ground (taller ones were cut there)
    max_height: float = 0.5


@dataclasses.dataclass(frozen=True)
class FlatWithInclineParams:
    """Flat ground with one inclined rectangle rising from 0 at its start edge (then a drop)."""

    x_range: tuple[float, float] = (0.3, 0.7)  # fractions of the field along x
    y_range: tuple[float, float] = (0.3, 0.7)  # fractions of the field along y
    angle: float = 1.92  # degrees of physical slope (original "15": 0.127 m over 4 m)
    direction: str = "x"  # x | y | diagonal


@dataclasses.dataclass(frozen=True)
class FlatWithRampParams:
    """Flat ground with one ramp rising linearly to ``height`` along ``direction``."""

    center: tuple[float, float] = (0.5, 0.5)  # fractions of the field (x, y)
    length: float = 0.3  # fraction of the field along the ramp
    width: float = 0.3  # fraction of the field across the ramp
    height: float = 0.1  # m (original 0.2 x 0.5 m)
    direction: str = "x"  # x | -x | y | -y
    smooth_edges: bool = True  # fade the outer 30 % of each half-width to 0


@dataclasses.dataclass(frozen=True)
class CorridorParams:
    """A floor between two walls, ``corridor_width`` wide at half the wall height (measured across it).

    The difficulty grades it in up to three stages: the walls grow to ``wall_height`` until difficulty
    ``wall_until``; the floor narrows from ``start_width`` to ``corridor_width`` until ``width_until``;
    then the centre line bends, ``bend_amplitude x sin(2 pi s / bend_wavelength)`` across it at ``s``
    along it, growing to full amplitude at difficulty 1. The defaults are the original's straight
    corridor with the walls scaled by the difficulty.
    """

    corridor_width: float = 0.6  # m (dispatcher default; the function's own default was 0.85)
    axis: str = "x"  # direction the corridor runs (the original's 'y' ran along world x)
    center: float = 0.5  # fraction of the field across the corridor (0.5: centred on the origin)
    wall_height: float = 0.25  # m (original 0.5 x 0.5 m)
    wall_until: float = 1.0  # difficulty at which the walls reach full height
    start_width: float = 0.0  # m, the floor's width until wall_until (0: corridor_width throughout)
    width_until: float = 1.0  # difficulty at which the floor has narrowed to corridor_width
    bend_amplitude: float = 0.0  # m across the corridor (0: straight, the original)
    bend_wavelength: float = 5.0  # m along it


@dataclasses.dataclass(frozen=True)
class SpiralParams:
    """A walled track along the spiral checkpoint path (clockwise from angle pi), plus a start disc."""

    start_radius: float = 0.5  # m; the spiral goal mode's checkpoints lie on this path too
    end_radius: float = 4.0  # m
    turns: float = 2.0
    track_width: float = 0.8  # m, at half the wall height
    wall_height: float = 0.25  # m (original 0.5 x 0.5 m)


@dataclasses.dataclass(frozen=True)
class FlatSpawnConfig:
    """The flat spawn zone: a disc levelled around ``center``, blended out to 1.2 x its radius."""

    enabled: bool = True  # original env default ensure_flat_spawn = true
    center: tuple[float, float] = (0.5, 0.5)  # fractions of the field (x, y)
    radius: float = 0.085  # fraction of the field width (0.85 m)


@dataclasses.dataclass(frozen=True)
class ReachabilityConfig:
    """Goals only where the robot can get (``hsa_mjx.terrain.reachability``).

    With ``enabled``, building the atlas maps on every tile the ground the robot reaches from its spawn
    (``traversability.ROBOT``'s limits, on a map of ``resolution`` cells), re-draws a random tile up to
    ``redraws`` times while less than ``min_area`` of it lies at a path distance inside ``goal_range``
    (and refuses the build when a tile still fails), and radial goals are drawn on reachable cells at
    their requested distance measured along the path.

    ``goal_sites`` > 0 also gives every tile that many goal sites, spread evenly in path distance over
    ``goal_range``, each with its distance field at every ``field_stride``-th map cell
    (``hsa_mjx.terrain.geodesic``): what ``reward.progress: geodesic`` reads; radial goals are then drawn
    among the sites.
    """

    enabled: bool = False
    resolution: float = 0.1  # m
    goal_range: tuple[float, float] = (1.5, 4.5)  # m along the path: the goals the tiles must hold
    min_area: float = 0.25  # m^2 (a corridor's reachable strip at 1.5-4.5 m: about 0.6 m^2)
    redraws: int = 8
    goal_sites: int = 0  # per tile (0: none)
    field_stride: int = 2  # the fields' cells: every second map cell (0.2 m)


@dataclasses.dataclass(frozen=True)
class TerrainConfig:
    """Which terrains a batch uses, in which proportions, and every generator's parameters.

    ``types`` and ``proportions`` (summing to 1) give the distribution each env's terrain type is
    drawn from at every reset; each env then takes one of the run's ``tiles_per_type`` terrains of
    that type (drawn once from ``seed``; deterministic types have one). ``per_env: false`` generates
    one terrain (from ``seed``) shared by every env instead. ``spawn_clearance`` is the gap left
    under the lowest robot geom at reset; ``edge_margin`` how far inside the field's edge the robot
    must stay.

    ``levels`` difficulty levels of every type (each with its own tiles): level ``l`` of ``L`` has
    difficulty ``difficulty x l / (L - 1)`` (level 0 is level ground); with one level the terrain
    has difficulty ``difficulty``. Without the terrain curriculum every reset draws a level
    uniformly; with it (``train``'s ``terrain_curriculum``) each env keeps its own level.
    """

    types: tuple[str, ...] = ("flat",)
    proportions: tuple[float, ...] = (1.0,)
    per_env: bool = True
    tiles_per_type: int = 16  # per level
    levels: int = 1
    difficulty: float = 1.0  # of the top level, in [0, 1]
    seed: int = 0
    spawn_clearance: float = 0.003
    edge_margin: float = 0.3
    flat_spawn: FlatSpawnConfig = FlatSpawnConfig()
    reachability: ReachabilityConfig = ReachabilityConfig()
    wavy: WavyParams = WavyParams()
    perlin: PerlinParams = PerlinParams()
    stairs: StairsParams = StairsParams()
    incline: InclineParams = InclineParams()
    craters: CratersParams = CratersParams()
    poles: PolesParams = PolesParams()
    flat_with_incline: FlatWithInclineParams = FlatWithInclineParams()
    flat_with_ramp: FlatWithRampParams = FlatWithRampParams()
    corridor: CorridorParams = CorridorParams()
    spiral: SpiralParams = SpiralParams()

    @property
    def level_difficulties(self) -> tuple[float, ...]:
        """The difficulty of each level, easiest first."""
        if self.levels == 1:
            return (float(self.difficulty),)
        return tuple(float(self.difficulty) * level / (self.levels - 1) for level in range(self.levels))

    def params(self, terrain_type: str) -> Any:
        """The parameter section of ``terrain_type`` (None for flat)."""
        check_type(terrain_type)
        return getattr(self, terrain_type, None)


def check_type(terrain_type: str) -> str:
    """Return ``terrain_type`` or raise ValueError listing the valid types."""
    if terrain_type not in TERRAIN_TYPES:
        raise ValueError(f"unknown terrain type {terrain_type!r}; valid types: {list(TERRAIN_TYPES)}")
    return terrain_type


def _fail(key: str, message: str, value: Any) -> None:
    """Raise the ValueError for config key ``terrain.<key>``."""
    raise ValueError(f"config key 'terrain.{key}' {message}, got {value!r}")


def _check_range(
    key: str,
    pair: tuple[float, float],
    low: float,
    strict_low: bool = False,
    high: float = math.inf,
    strict: bool = False,
) -> None:
    """``pair`` = (lo, hi) with low <= lo <= hi <= high (lo > low if strict_low; lo < hi if strict)."""
    lo, hi = pair
    if lo < low or (strict_low and lo == low) or hi > high or hi < lo or (strict and hi == lo):
        rule = f"min {'>' if strict_low else '>='} {low}, min {'<' if strict else '<='} max"
        rule += f", max <= {high}" if high < math.inf else ""
        _fail(key, f"must be (min, max) with {rule}", pair)


def _check_choice(key: str, value: str, choices: tuple[str, ...]) -> None:
    """``value`` must be one of ``choices`` (the message lists them)."""
    if value not in choices:
        raise ValueError(f"config key 'terrain.{key}' = {value!r} is not valid; choose one of {list(choices)}")


def _check_sign(section: Any, prefix: str, positive: tuple[str, ...] = (), non_negative: tuple[str, ...] = ()) -> None:
    """Named fields of ``section`` must be > 0 / >= 0."""
    for name in positive:
        if not getattr(section, name) > 0:
            _fail(f"{prefix}.{name}" if prefix else name, "must be > 0", getattr(section, name))
    for name in non_negative:
        if not getattr(section, name) >= 0:
            _fail(f"{prefix}.{name}" if prefix else name, "must be >= 0", getattr(section, name))


def _check_angle(key: str, angle: float) -> None:
    """A slope in degrees strictly between -90 and 90."""
    if not -90.0 < angle < 90.0:
        _fail(key, "must be a slope in degrees strictly between -90 and 90", angle)


def _check_mixture(config: TerrainConfig) -> None:
    """Types known and unique; proportions one per type, non-negative, summing to 1."""
    if not config.types:
        _fail("types", "must list at least one terrain type", config.types)
    for name in config.types:
        if name not in TERRAIN_TYPES:
            raise ValueError(
                f"config key 'terrain.types' has unknown terrain type {name!r}; valid types: {list(TERRAIN_TYPES)}"
            )
    if len(set(config.types)) != len(config.types):
        _fail("types", "must not repeat a type", config.types)
    if len(config.proportions) != len(config.types):
        _fail("proportions", f"must have one entry per type ({len(config.types)})", config.proportions)
    if any(p < 0 for p in config.proportions) or abs(sum(config.proportions) - 1.0) > 1e-6:
        _fail("proportions", "must be >= 0 and sum to 1", config.proportions)


def _check_generators(c: TerrainConfig) -> None:
    """Value ranges of every generator's parameters."""
    _check_sign(c.wavy, "wavy", non_negative=("scale", "amplitude"))
    _check_sign(c.perlin, "perlin", positive=("scale", "persistence"), non_negative=("amplitude",))
    if not 1 <= c.perlin.octaves <= 8:
        _fail("perlin.octaves", "must be between 1 and 8", c.perlin.octaves)
    if c.perlin.lacunarity < 1:
        _fail("perlin.lacunarity", "must be >= 1", c.perlin.lacunarity)
    _check_sign(c.stairs, "stairs", positive=("step_length",), non_negative=("step_height",))
    _check_angle("incline.angle", c.incline.angle)
    _check_choice("incline.direction", c.incline.direction, INCLINE_DIRECTIONS)
    _check_sign(c.craters, "craters", non_negative=("num",))
    _check_range("craters.radius", c.craters.radius, 0.0, strict_low=True)
    _check_range("craters.depth", c.craters.depth, 0.0)
    _check_sign(c.poles, "poles", positive=("max_height",), non_negative=("num", "min_spacing"))
    _check_range("poles.radius", c.poles.radius, 0.0, strict_low=True)
    _check_range("poles.height", c.poles.height, 0.0)
    _check_choice("poles.grade", c.poles.grade, POLE_GRADES)
    _check_range("flat_with_incline.x_range", c.flat_with_incline.x_range, 0.0, high=1.0, strict=True)
    _check_range("flat_with_incline.y_range", c.flat_with_incline.y_range, 0.0, high=1.0, strict=True)
    _check_angle("flat_with_incline.angle", c.flat_with_incline.angle)
    _check_choice("flat_with_incline.direction", c.flat_with_incline.direction, INCLINE_DIRECTIONS)
    ramp = c.flat_with_ramp
    _check_sign(ramp, "flat_with_ramp", positive=("length", "width"), non_negative=("height",))
    if not all(0.0 <= f <= 1.0 for f in ramp.center):
        _fail("flat_with_ramp.center", "must be fractions of the field in [0, 1]", ramp.center)
    _check_choice("flat_with_ramp.direction", ramp.direction, RAMP_DIRECTIONS)
    _check_sign(c.corridor, "corridor", positive=("corridor_width",), non_negative=("wall_height",))
    _check_choice("corridor.axis", c.corridor.axis, AXES)
    if not 0.0 <= c.corridor.center <= 1.0:
        _fail("corridor.center", "must be a fraction of the field in [0, 1]", c.corridor.center)
    _check_corridor_stages(c.corridor)
    _check_sign(c.spiral, "spiral", positive=("turns", "track_width"), non_negative=("start_radius", "wall_height"))
    if c.spiral.end_radius < c.spiral.start_radius:
        _fail("spiral.end_radius", "must be >= spiral.start_radius", c.spiral.end_radius)


def _check_corridor_stages(p: CorridorParams) -> None:
    """0 < wall_until <= width_until <= 1, a positive start width and wavelength, a non-negative bend."""
    if not 0.0 < p.wall_until <= p.width_until <= 1.0:
        _fail(
            "corridor.wall_until",
            "and corridor.width_until must satisfy 0 < wall_until <= width_until <= 1",
            (p.wall_until, p.width_until),
        )
    _check_sign(p, "corridor", positive=("bend_wavelength",), non_negative=("start_width", "bend_amplitude"))


def validate_terrain(config: TerrainConfig) -> TerrainConfig:
    """Check the mixture, the spawn settings and every generator's parameters (ValueError)."""
    _check_mixture(config)
    _check_sign(config, "", non_negative=("spawn_clearance", "edge_margin"))
    if not 1 <= config.tiles_per_type <= 256:
        _fail("tiles_per_type", "must be between 1 and 256", config.tiles_per_type)
    if isinstance(config.levels, bool) or not 1 <= config.levels <= MAX_LEVELS:
        _fail("levels", f"must be an integer between 1 and {MAX_LEVELS}", config.levels)
    if not 0.0 <= config.difficulty <= 1.0:
        _fail("difficulty", "must be in [0, 1] (0: level ground, 1: the configured parameters)", config.difficulty)
    if config.levels > 1 and not config.per_env:
        _fail("levels", "> 1 needs terrain.per_env: true (one shared terrain has one level)", config.levels)
    spawn = config.flat_spawn
    if spawn.radius < 0:
        _fail("flat_spawn.radius", "must be >= 0 (a fraction of the field width)", spawn.radius)
    if not all(0.0 <= f <= 1.0 for f in spawn.center):
        _fail("flat_spawn.center", "must be fractions of the field in [0, 1]", spawn.center)
    reach = config.reachability
    _check_sign(reach, "reachability", positive=("resolution", "min_area"), non_negative=("redraws",))
    _check_range("reachability.goal_range", reach.goal_range, 0.0, strict=True)
    if not 0 <= reach.goal_sites <= 256:
        _fail("reachability.goal_sites", "must be between 0 and 256", reach.goal_sites)
    if not 1 <= reach.field_stride <= 8:
        _fail("reachability.field_stride", "must be between 1 and 8", reach.field_stride)
    _check_generators(config)
    if "corridor" in config.types and config.corridor.bend_amplitude > 0 and not reach.enabled:
        _fail(
            "corridor.bend_amplitude",
            "> 0 needs terrain.reachability.enabled: true (goals on a bent corridor are drawn on its floor)",
            config.corridor.bend_amplitude,
        )
    return config


def with_default_proportions(data: dict) -> dict:
    """An env config mapping whose ``terrain.types`` without ``proportions`` get equal shares."""
    section = data.get("terrain")
    if isinstance(section, Mapping) and isinstance(section.get("types"), (list, tuple)) and section["types"]:
        types = section["types"]
        data = {**data, "terrain": {"proportions": [1.0 / len(types)] * len(types), **section}}
    return data
