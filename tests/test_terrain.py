"""Terrain generators, layout, lookup, sampler and the terrain config (pure JAX; no MJX compile)."""

import dataclasses
import math

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

import hsa_mjx.config
from hsa_mjx.sim.model import load_mj_model
from hsa_mjx.task import goals
from hsa_mjx.terrain import (
    TERRAIN_TYPES,
    CorridorParams,
    FlatSpawnConfig,
    Grid,
    InclineParams,
    PolesParams,
    StairsParams,
    TerrainConfig,
    TerrainSampler,
    generate,
    surface_height,
    to_hfield_data,
)
from hsa_mjx.terrain.generators import pole_centres
from hsa_mjx.terrain.sampler import apply_flat_spawn, spawn_plane

GRID = Grid()  # the asset's 50 x 50 vertices over 10 x 10 m, z scale 0.5 m
D = TerrainConfig()
# World height bounds (m) of each generator with the default parameters (before lifting).
BOUNDS = {
    "wavy": (-D.wavy.amplitude, D.wavy.amplitude),
    "perlin": (-0.5, 0.5),
    "stairs": (-0.2, 0.2),
    "flat": (0.0, 0.0),
    "incline": (-0.1, 0.1),
    "craters": (-D.craters.num * D.craters.depth[1], 0.0),
    "poles": (0.0, D.poles.height[1]),
    "flat_with_incline": (0.0, 0.14),
    "flat_with_ramp": (0.0, D.flat_with_ramp.height),
    "corridor": (0.0, D.corridor.wall_height),
    "spiral": (0.0, D.spiral.wall_height),
}
RANDOM = {"perlin", "craters", "poles"}


def _single(terrain_type: str, **changes) -> TerrainConfig:
    return dataclasses.replace(TerrainConfig(), types=(terrain_type,), proportions=(1.0,), **changes)


def _no_zone(terrain_type: str, **changes) -> TerrainConfig:
    return _single(terrain_type, flat_spawn=FlatSpawnConfig(enabled=False), **changes)


def _data(config: TerrainConfig, seed: int = 0) -> jax.Array:
    return TerrainSampler(config, GRID).sample(jax.random.PRNGKey(seed))[0]


@pytest.mark.parametrize("terrain_type", TERRAIN_TYPES)
def test_generator_jits_vmaps_is_deterministic_finite_and_in_range(terrain_type):
    fn = jax.jit(jax.vmap(lambda k: generate(terrain_type, k, None, GRID)))
    keys = jax.random.split(jax.random.PRNGKey(0), 3)
    heights = np.asarray(fn(keys))
    assert heights.shape == (3, GRID.nrow, GRID.ncol) and heights.dtype == np.float32
    assert np.all(np.isfinite(heights))
    np.testing.assert_array_equal(heights, np.asarray(fn(keys)))  # same keys, same terrains
    lo, hi = BOUNDS[terrain_type]
    assert heights.min() >= lo - 1e-6 and heights.max() <= hi + 1e-6
    assert (not np.array_equal(heights[0], heights[1])) == (terrain_type in RANDOM)
    data = np.asarray(jax.vmap(lambda h: to_hfield_data(h, GRID))(heights))
    assert data.shape == (3, GRID.size) and data.min() == 0.0 and data.max() <= 1.0


def test_unknown_type_and_bad_grid_raise():
    with pytest.raises(ValueError, match=r"unknown terrain type 'lava'.*valid types.*'wavy'.*'spiral'"):
        generate("lava", jax.random.PRNGKey(0))
    with pytest.raises(ValueError, match="'nrow' must be an integer >= 2"):
        Grid(nrow=1)
    with pytest.raises(ValueError, match="'z_scale' must be > 0"):
        Grid(z_scale=0.0)


def test_hfield_data_lifts_negative_heights_and_clips_tall_ones():
    heights = jnp.zeros((GRID.nrow, GRID.ncol)).at[0, 0].set(-0.2).at[1, 1].set(2.0)
    data = np.asarray(to_hfield_data(heights, GRID)).reshape(GRID.nrow, GRID.ncol)
    assert data[0, 0] == 0.0 and data[1, 1] == 1.0 and data[2, 2] == pytest.approx(0.2 / GRID.z_scale)


def test_layout_and_lookup_match_mujoco_ray_casts():
    """Row = world y, column = world x, and the lookup equals MuJoCo's triangulated surface."""
    model = load_mj_model(
        hsa_mjx.config.with_overrides(hsa_mjx.config.get_preset("craters"), terrain__per_env=False)
    )  # one tile
    grid = Grid.from_model(model)
    assert grid == GRID
    rise = generate("incline", None, InclineParams(angle=2.0, direction="x"), grid)
    bumps = generate("perlin", jax.random.PRNGKey(1), None, grid)
    data = np.asarray(to_hfield_data(rise + 0.3 * bumps, grid))
    model.hfield_data[:] = data
    mj_data = mujoco.MjData(model)
    mujoco.mj_forward(model, mj_data)
    points = np.random.default_rng(0).uniform(-4.9, 4.9, (200, 2))
    points = points[np.abs(points).max(axis=1) > 0.8]  # keep clear of the robot at the origin
    geom = np.zeros(1, np.int32)
    rays = np.array(
        [
            3.0 - mujoco.mj_ray(model, mj_data, np.array([x, y, 3.0]), np.array([0.0, 0.0, -1.0]), None, 1, -1, geom)
            for x, y in points
        ]
    )
    np.testing.assert_allclose(
        np.asarray(surface_height(jnp.asarray(data), grid, jnp.asarray(points))), rays, atol=2e-5
    )
    plain = np.asarray(to_hfield_data(rise, grid))
    east, west, north = (
        float(surface_height(jnp.asarray(plain), grid, jnp.array(p))) for p in ([3.0, 0.0], [-3.0, 0.0], [0.0, 3.0])
    )
    assert east - west == pytest.approx(6.0 * math.tan(math.radians(2.0)), abs=1e-4)  # rises along world x
    assert north == pytest.approx(float(surface_height(jnp.asarray(plain), grid, jnp.zeros(2))), abs=1e-6)


@pytest.mark.parametrize(
    "terrain_type", ["wavy", "perlin", "stairs", "incline", "craters", "poles", "flat_with_incline", "flat_with_ramp"]
)
def test_spawn_zone_is_level_or_follows_an_incline(terrain_type):
    config = _single(terrain_type)
    heights, _ = TerrainSampler(config, GRID).heights(jax.random.PRNGKey(4))
    x, y = GRID.mesh()
    zone = np.hypot(x, y) <= config.flat_spawn.radius * 2 * GRID.half_x
    plane = spawn_plane(terrain_type, config.params(terrain_type), GRID, config.flat_spawn)
    level, slope_x, slope_y = np.asarray(plane)
    follows = terrain_type in ("incline", "flat_with_incline", "flat_with_ramp")  # planes under the whole zone
    expected = level + slope_x * x + slope_y * y if follows else np.full_like(x, level)
    np.testing.assert_allclose(np.asarray(heights)[zone], expected[zone], atol=1e-5)
    assert zone.sum() >= 49  # at least the original's 49 levelled cells


def test_spawn_zone_leaves_an_incline_through_it_without_a_step():
    config = _single("flat_with_incline")
    plane = spawn_plane("flat_with_incline", config.flat_with_incline, GRID, config.flat_spawn)
    rise = math.tan(math.radians(1.92))
    np.testing.assert_allclose(np.asarray(plane), [2.0 * rise, rise, 0.0], rtol=1e-3, atol=1e-6)  # not a pit at 0
    raw = generate("flat_with_incline", None, config.flat_with_incline, GRID)
    out = np.asarray(apply_flat_spawn(raw, GRID, config.flat_spawn, plane))
    np.testing.assert_allclose(out, np.asarray(raw), atol=1e-5)  # a level landing would leave a step at its rim
    level = jnp.asarray([plane[0], 0.0, 0.0])  # a level landing: its uphill rim over 3x as steep as the slope
    landing = np.asarray(apply_flat_spawn(raw, GRID, config.flat_spawn, level))
    assert np.max(np.diff(landing, axis=1)) > 3.0 * rise * GRID.spacing_x


def test_stairs_are_monotone_steps_of_the_requested_height():
    params = StairsParams(step_height=0.04, step_length=0.8)  # 13 steps: 0.48 m, within the 0.5 m z scale
    data = _data(_no_zone("stairs", stairs=params))
    heights = np.asarray(data).reshape(GRID.nrow, GRID.ncol)
    assert np.all(np.diff(heights, axis=1) >= 0) and np.all(np.diff(heights, axis=0) == 0)
    centres = jnp.stack([jnp.arange(-5, 6) * 0.8, jnp.zeros(11)], axis=1)  # the middle of each step
    levels = np.asarray(surface_height(data, GRID, centres))
    np.testing.assert_allclose(np.diff(levels), 0.04, atol=1e-5)


@pytest.mark.parametrize(
    "direction, axis", [("x", (1.0, 0.0)), ("y", (0.0, 1.0)), ("diagonal", (0.7071068, 0.7071068))]
)
@pytest.mark.parametrize("angle", [1.04, 2.5])
def test_incline_has_the_requested_angle(direction, axis, angle):
    data = _data(_no_zone("incline", incline=InclineParams(angle=angle, direction=direction)))
    a, b = -3.0 * jnp.asarray(axis), 3.0 * jnp.asarray(axis)
    rise = float(surface_height(data, GRID, b) - surface_height(data, GRID, a))
    assert math.degrees(math.atan2(rise, 6.0)) == pytest.approx(angle, abs=0.01)
    across = jnp.asarray([-axis[1], axis[0]]) * 2.0
    level = surface_height(data, GRID, across) - surface_height(data, GRID, -across)
    assert float(level) == pytest.approx(0.0, abs=1e-5)


def _width_at_half_height(profile: np.ndarray, positions: np.ndarray, wall: float) -> float:
    floor = positions[profile < wall / 2]
    return float(floor.max() - floor.min())


@pytest.mark.parametrize("axis", ["x", "y"])
@pytest.mark.parametrize("width", [0.6, 0.85, 1.3])
def test_corridor_has_the_requested_width(axis, width):
    params = CorridorParams(corridor_width=width, axis=axis)
    data = _data(_no_zone("corridor", corridor=params))
    across = np.linspace(-1.5, 1.5, 3001)
    for along in (-4.0, 0.0, 2.7):
        line = (np.full_like(across, along), across)
        points = np.stack(line if axis == "x" else line[::-1], 1)
        profile = np.asarray(surface_height(data, GRID, jnp.asarray(points)))
        assert _width_at_half_height(profile, across, params.wall_height) == pytest.approx(width, abs=0.05)
        assert profile[len(across) // 2] == 0.0 and profile[0] == pytest.approx(params.wall_height)


def test_spiral_preset_has_the_originals_floor():
    """The original zeroed every vertex within 0.4 m of the line; our half-height edge at 0.4 m leaves
    fewer floor vertices on the scene's 0.2 m grid, which the preset's 0.95 m track makes up for."""
    from hsa_mjx.terrain.generators import spiral, spiral_extension, spiral_track_distance

    x, y = (jnp.asarray(v, jnp.float32) for v in GRID.mesh())
    preset = hsa_mjx.config.get_preset("spiral").terrain.spiral
    original = dataclasses.replace(preset, track_width=0.8)
    distance = spiral_track_distance(original, x, y, spiral_extension(original))
    original_floor = int(jnp.sum((distance <= 0.4) | (jnp.hypot(x, y) <= original.start_radius)))

    def floor(params) -> int:
        return int(jnp.sum(spiral(jax.random.PRNGKey(0), params, GRID, x, y) < 0.01))

    assert floor(original) < 0.85 * original_floor  # the generator's 0.8 m default: a floor one vertex narrower
    assert floor(preset) == pytest.approx(original_floor, rel=0.05)


@pytest.mark.parametrize("num_checkpoints", [8, 20])
def test_spiral_track_passes_through_its_checkpoints(num_checkpoints):
    goal = hsa_mjx.config.GoalConfig(mode="spiral", num_checkpoints=num_checkpoints)
    data = _data(_no_zone("spiral"))
    wall = D.spiral.wall_height
    checkpoints = jnp.asarray(goals.spiral_checkpoints(goal))
    np.testing.assert_array_equal(np.asarray(surface_height(data, GRID, checkpoints)), 0.0)  # none on a wall
    s = np.linspace(0.0, 1.0, 600)  # the whole centre line, start to end, is floor
    angle, radius = np.pi - 4 * np.pi * s, 0.5 + 3.5 * s
    line = np.stack([radius * np.cos(angle), radius * np.sin(angle)], 1)
    np.testing.assert_array_equal(np.asarray(surface_height(data, GRID, jnp.asarray(line))), 0.0)
    between = line[(s > 0.1) & (s < 0.75)] * (1.0 + 0.875 / radius[(s > 0.1) & (s < 0.75)])[:, None]
    np.testing.assert_allclose(np.asarray(surface_height(data, GRID, jnp.asarray(between))), wall)  # walls between laps
    assert float(surface_height(data, GRID, jnp.zeros(2))) == 0.0  # the start disc under the spawn


def test_poles_keep_their_spacing_and_number():
    params = PolesParams()
    for seed in range(4):
        x, y, present = (np.asarray(a) for a in pole_centres(jax.random.PRNGKey(seed), params, GRID))
        assert present.sum() == params.num
        pts = np.stack([x[present], y[present]], 1)
        gaps = np.linalg.norm(pts[:, None] - pts[None], axis=-1) + np.eye(len(pts)) * 99
        assert gaps.min() >= params.min_spacing and np.abs(pts).max() <= GRID.half_x - params.radius[1]
    spikes = np.asarray(generate("poles", jax.random.PRNGKey(0), params, GRID))
    assert (spikes > 0).sum() == params.num  # single-vertex spikes, as the original's r = 1 cell poles


def test_mixed_sampler_draws_types_in_proportion_and_fresh_terrain_per_key():
    config = dataclasses.replace(TerrainConfig(), types=("flat", "stairs", "craters"), proportions=(0.5, 0.3, 0.2))
    sampler = TerrainSampler(config, GRID)
    data, ids = jax.jit(jax.vmap(sampler.sample))(jax.random.split(jax.random.PRNGKey(0), 1500))
    data, ids = np.asarray(data), np.asarray(ids)
    for name, share in zip(config.types, config.proportions):
        assert (ids == TERRAIN_TYPES.index(name)).mean() == pytest.approx(share, abs=0.04)
    flat = ids == TERRAIN_TYPES.index("flat")
    assert np.all(data[flat] == 0.0) and np.all(data[~flat].max(axis=1) > 0.05)
    craters = data[ids == TERRAIN_TYPES.index("craters")]
    assert len(np.unique(craters.round(5), axis=0)) == len(craters)  # every reset a new crater field
    stairs = data[ids == TERRAIN_TYPES.index("stairs")].reshape(-1, GRID.nrow, GRID.ncol)
    assert np.all(stairs == stairs[0])  # a deterministic type is the same every time


# ----- config ---------------------------------------------------------------------------------
def test_presets_are_the_shipped_yaml_files():
    """The flat YAML states the config defaults; every preset is its file (no copy elsewhere)."""
    from hsa_mjx import resources

    assert hsa_mjx.config.get_preset("flat") == hsa_mjx.config.EnvConfig()
    for name, file in hsa_mjx.config.PRESET_FILES.items():
        assert (
            hsa_mjx.config.get_preset(name) == hsa_mjx.config.load_config(resources.data_dir("configs") / file)
            and hsa_mjx.config.get_preset(name).name == name
        ), name
    assert (
        hsa_mjx.config.get_preset("spiral").goal.mode == "spiral"
        and hsa_mjx.config.get_preset("corridor").control.servo_target_limit == 6.28
    )


def test_terrain_type_and_types_stay_in_step():
    c = hsa_mjx.config.from_dict({"scene": "terrain", "terrain_type": "craters"})
    assert c.terrain.types == ("craters",) and c.terrain.proportions == (1.0,)
    c = hsa_mjx.config.from_dict({"scene": "terrain", "terrain": {"types": ["wavy", "poles"]}})
    assert c.terrain_type == "mixed" and c.terrain.proportions == (0.5, 0.5)
    assert hsa_mjx.config.with_overrides(c, terrain_type="stairs").terrain.types == ("stairs",)
    assert hsa_mjx.config.from_dict(
        hsa_mjx.config.to_dict(hsa_mjx.config.get_preset("mixed"))
    ) == hsa_mjx.config.get_preset("mixed")


@pytest.mark.parametrize(
    "data, message",
    [
        ({"terrain": {"types": ["wavy", "lava"]}}, r"unknown terrain type 'lava'; valid types: \['wavy'"),
        ({"terrain_type": "lava"}, r"terrain_type.*not valid.*'craters'"),
        ({"terrain": {"types": ["wavy", "stairs"], "proportions": [0.5, 0.6]}}, "proportions.*sum to 1"),
        ({"terrain": {"types": ["wavy", "stairs"], "proportions": [1.0]}}, "proportions.*one entry per type"),
        ({"terrain": {"types": ["wavy", "wavy"]}}, "must not repeat"),
        ({"terrain_type": "craters", "terrain": {"craters": {"radius": [-1.0, 2.0]}}}, r"craters.radius.*> 0"),
        ({"terrain_type": "poles", "terrain": {"poles": {"radius": [0.3, 0.2]}}}, r"poles.radius.*min <= max"),
        ({"terrain_type": "craters", "terrain": {"flat_spawn": {"radius": -0.1}}}, "flat_spawn.radius.*>= 0"),
        ({"terrain_type": "incline", "terrain": {"incline": {"angle": 95.0}}}, "incline.angle.*between -90 and 90"),
        (
            {"terrain_type": "incline", "terrain": {"incline": {"direction": "z"}}},
            r"incline.direction.*\['x', 'y', 'diagonal'\]",
        ),
        ({"terrain_type": "corridor", "terrain": {"corridor": {"corridor_width": 0.0}}}, "corridor_width.*> 0"),
        ({"terrain_type": "stairs", "terrain": {"types": ["wavy"]}}, "terrain_type.*does not match"),
        ({"terrain_type": "spiral"}, "goal.mode: spiral"),
        (
            {
                "terrain_type": "spiral",
                "goal": {"mode": "spiral", "spiral_turns": 3.0},
                "terrain": {"spiral": {"turns": 2.0}},
            },
            r"'goal.spiral_turns' = 3.0 differs from 'terrain.spiral.turns' = 2.0",
        ),
    ],
)
def test_bad_terrain_config_raises_when_loading(data, message):
    with pytest.raises(ValueError, match=message):
        hsa_mjx.config.from_dict(dict(data, scene="terrain"))


def test_terrain_on_a_plane_is_refused():
    with pytest.raises(ValueError, match="need a heightfield: set 'scene: terrain'"):
        hsa_mjx.config.from_dict({"terrain_type": "craters"})


def test_keys_of_older_configs_map_onto_the_current_ones():
    """Older files (policies, checkpoints) hold ``terrain_type`` and the goal's spiral keys: both load."""
    old = {
        "scene": "terrain",
        "terrain_type": "spiral",
        "goal": {"mode": "spiral", "spiral_start_radius": 0.7, "spiral_end_radius": 4.0, "spiral_turns": 3.0},
    }
    config = hsa_mjx.config.from_dict(old)
    assert config.terrain.types == ("spiral",) and config.terrain_type == "spiral"
    assert (config.terrain.spiral.start_radius, config.terrain.spiral.turns) == (0.7, 3.0)
    saved = hsa_mjx.config.to_dict(config)
    assert "terrain_type" not in saved and not [k for k in saved["goal"] if k.startswith("spiral_")]
    assert hsa_mjx.config.from_dict(saved) == config
