"""Terrain difficulty in every generator, the atlas's levels, and the per-env terrain curriculum (no physics)."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import hsa_mjx.config
from hsa_mjx.curricula import terrain_curriculum
from hsa_mjx.terrain import TERRAIN_TYPES, Grid, PolesParams, TerrainConfig, generate
from hsa_mjx.terrain.atlas import AtlasLayout, TerrainPool
from hsa_mjx.terrain.generators import DIFFICULTY_PARAMETER, GENERATORS
from train import config as train_config
from train.run import checkpoint

GRID = Grid()
HARD_TYPES = tuple(t for t in TERRAIN_TYPES if t != "flat")
DIFFICULTIES = (0.25, 0.5, 1.0)


def _relief(heights: np.ndarray) -> dict[str, float]:
    """Measured roughness: RMS height about the mean, largest slope between neighbours, largest step."""
    dx, dy = np.diff(heights, axis=1) / GRID.spacing_x, np.diff(heights, axis=0) / GRID.spacing_y
    step = max(np.abs(np.diff(heights, axis=1)).max(), np.abs(np.diff(heights, axis=0)).max())
    return {"rms": float(np.std(heights)), "slope": float(max(np.abs(dx).max(), np.abs(dy).max())), "step": float(step)}


@pytest.mark.parametrize("terrain_type", TERRAIN_TYPES)
def test_difficulty_zero_is_level_ground(terrain_type):
    heights = np.asarray(generate(terrain_type, jax.random.PRNGKey(3), None, GRID, 0.0))
    assert np.all(heights == 0.0), terrain_type


@pytest.mark.parametrize("terrain_type", HARD_TYPES)
def test_roughness_grows_with_difficulty(terrain_type):
    key = jax.random.PRNGKey(7)
    # the poles' heights grow until the original's 0.5 m top (max_height), reached at about 0.4-0.67: uncapped here
    params = PolesParams(max_height=10.0) if terrain_type == "poles" else None
    measured = [_relief(np.asarray(generate(terrain_type, key, params, GRID, d))) for d in DIFFICULTIES]
    if terrain_type == "poles":
        assert np.asarray(generate("poles", key, None, GRID, 1.0)).max() == PolesParams().max_height == 0.5
    for name in ("rms", "slope", "step"):
        values = [m[name] for m in measured]
        assert values[0] > 0 and all(a < b for a, b in zip(values, values[1:])), (terrain_type, name, values)
    assert terrain_type in DIFFICULTY_PARAMETER


def test_difficulty_scales_the_named_parameter():
    """Stairs at difficulty 0.5 rise by half the step height; an incline at 0.5 has half the angle."""
    key = jax.random.PRNGKey(0)
    params = TerrainConfig().stairs
    centres = np.arange(3, dtype=np.float32) * params.step_length  # the middle of steps 0, 1, 2
    stairs = np.asarray(GENERATORS["stairs"](key, params, GRID, centres, np.zeros(3, np.float32), 0.5))
    np.testing.assert_allclose(stairs, 0.5 * params.step_height * np.arange(3), atol=1e-6)
    incline = np.asarray(generate("incline", key, None, GRID, 0.5))
    slope = (incline[0, -1] - incline[0, 0]) / (2 * GRID.half_x)
    assert np.isclose(slope, np.tan(np.radians(0.5 * TerrainConfig().incline.angle)), rtol=1e-4)
    traced = jax.jit(lambda d: generate("incline", key, None, GRID, d))(0.5)  # a traced difficulty
    np.testing.assert_allclose(np.asarray(traced), incline, atol=1e-6)


def test_atlas_holds_every_level_of_every_type():
    config = TerrainConfig(types=("craters", "stairs"), proportions=(0.5, 0.5), levels=3, tiles_per_type=2)
    layout = AtlasLayout.from_config(config, Grid(11, 11, 1.0, 1.0, 0.5, 0.1))
    pool = TerrainPool(config, layout)
    assert config.level_difficulties == (0.0, 0.5, 1.0)
    # craters: 3 levels x 2 tiles, stairs: 3 levels x 1 tile
    assert list(pool.tile_level) == [0, 0, 1, 1, 2, 2, 0, 1, 2]
    spread = [np.ptp(pool.tiles[i]) for i in range(len(pool.tiles))]
    assert spread[0] == spread[1] == spread[6] == 0.0  # level 0: level ground
    assert spread[2] > 0 and spread[4] > 0 and 0 < spread[7] < spread[8]  # random tiles differ per level
    for row, level in [(0, 2), (1, 1), (0, 0)]:
        tiles, types = jax.vmap(lambda k, cell=(row, level): pool.draw(k, jnp.asarray(cell)))(
            jax.random.split(jax.random.PRNGKey(row), 16)
        )
        assert set(np.asarray(pool.tile_level)[np.asarray(tiles)]) == {level}
        assert set(np.asarray(types)) == {TERRAIN_TYPES.index(config.types[row])}
    free, _ = jax.vmap(pool.draw)(jax.random.split(jax.random.PRNGKey(9), 200))
    assert set(np.asarray(pool.tile_level)[np.asarray(free)]) == {0, 1, 2}  # no curriculum: every level


@pytest.mark.parametrize(
    "override, key",
    [
        ({"difficulty": 1.5}, "terrain.difficulty"),
        ({"difficulty": -0.1}, "terrain.difficulty"),
        ({"levels": 0}, "terrain.levels"),
        ({"levels": 2, "per_env": False}, "terrain.levels"),
        ({"types": ["flat", "lava"], "proportions": [0.5, 0.5]}, "lava"),
        ({"types": ["flat", "wavy"], "proportions": [0.5, 0.4]}, "terrain.proportions"),
    ],
)
def test_bad_terrain_levels_are_refused_at_load(override, key):
    with pytest.raises(ValueError, match=key):
        hsa_mjx.config.from_dict({"terrain": override}, base=hsa_mjx.config.get_preset("mixed"))


@pytest.mark.parametrize(
    "section, key",
    [
        ({"promote_progress": 0.2, "demote_progress": 0.5}, "demote_progress"),
        ({"initial_spread": 2.0}, "initial_spread"),
        ({"speed": 1}, "speed"),
    ],
)
def test_bad_terrain_curriculum_is_refused_at_load(section, key):
    data = train_config.read_yaml("configs/train_rough.yaml")
    data["terrain_curriculum"] = {**data["terrain_curriculum"], **section}
    with pytest.raises(ValueError, match=key):
        train_config.from_dict(data)


def test_terrain_curriculum_needs_per_env_terrain():
    with pytest.raises(ValueError, match="per-env terrain"):
        train_config.from_dict({"env": {"preset": "flat_radial"}, "terrain_curriculum": {"enabled": True}})


def test_types_split_by_proportion_and_levels_spread_at_start():
    terrain = TerrainConfig(types=("flat", "wavy", "stairs"), proportions=(0.5, 0.25, 0.25), levels=11)
    rows = terrain_curriculum.type_indices(400, terrain.proportions)
    assert np.bincount(rows).tolist() == [200, 100, 100]
    config = terrain_curriculum.TerrainCurriculumConfig(enabled=True, initial_spread=0.5)
    state = terrain_curriculum.init(jax.random.split(jax.random.PRNGKey(0), 400), config, terrain)
    levels = np.asarray(state.level)
    assert set(levels.tolist()) == set(range(6))  # levels 0..5 (half of 0..10), every one used
    assert np.asarray(state.terrain_type).tolist() == rows.tolist()
    none = terrain_curriculum.init(
        jax.random.split(jax.random.PRNGKey(0), 8), dataclasses.replace(config, initial_spread=0.0), terrain
    )
    assert np.all(np.asarray(none.level) == 0)


def test_promotion_and_demotion_follow_the_episode_outcome():
    config = terrain_curriculum.TerrainCurriculumConfig(enabled=True, promote_progress=0.8, demote_progress=0.3)
    state = terrain_curriculum.TerrainLevels(
        terrain_type=jnp.zeros(6, jnp.int32), level=jnp.asarray([2, 2, 2, 2, 0, 4], jnp.int32)
    )
    done = jnp.asarray([True, True, True, False, True, True])
    success = jnp.asarray([True, False, False, False, False, True])
    progress = jnp.asarray([1.0, 0.9, 0.1, 0.0, 0.0, 1.0])
    new = terrain_curriculum.update(state, done, success, progress, config, levels=5)
    # goal reached: up; 90 % covered: up; 10 %: down; still running: kept; floor and ceiling hold
    assert np.asarray(new.level).tolist() == [3, 3, 1, 2, 0, 4]
    middling = terrain_curriculum.update(state, done, jnp.zeros(6, bool), jnp.full(6, 0.5), config, levels=5)
    assert np.asarray(middling.level).tolist() == [2, 2, 2, 2, 0, 4]  # 50 %: neither


def test_top_redraw_sends_envs_promoted_from_the_top_to_random_levels():
    config = terrain_curriculum.TerrainCurriculumConfig(enabled=True, top_redraw=True)
    batch, levels = 512, 10
    state = terrain_curriculum.TerrainLevels(
        terrain_type=jnp.zeros(batch, jnp.int32), level=jnp.full(batch, levels - 1, jnp.int32)
    )
    keys = jax.random.split(jax.random.PRNGKey(0), batch)
    done, success = jnp.arange(batch) % 2 == 0, jnp.ones(batch, bool)
    new = np.asarray(terrain_curriculum.update(state, done, success, jnp.ones(batch), config, levels, keys).level)
    assert np.all(new[1::2] == levels - 1)  # still running: kept at the top
    redrawn = new[0::2]
    assert redrawn.min() == 0 and redrawn.max() == levels - 1 and len(set(redrawn.tolist())) == levels
    again = terrain_curriculum.update(state, done, success, jnp.ones(batch), config, levels, keys).level
    np.testing.assert_array_equal(np.asarray(again), new)  # reproducible from the keys
    below = state.replace(level=jnp.full(batch, 3, jnp.int32))  # promoted below the top: one level up, as before
    assert np.all(
        np.asarray(terrain_curriculum.update(below, done, success, jnp.ones(batch), config, levels, keys).level)[0::2]
        == 4
    )
    kept = terrain_curriculum.update(
        state, done, success, jnp.ones(batch), dataclasses.replace(config, top_redraw=False), levels
    )
    assert np.all(np.asarray(kept.level) == levels - 1)  # without the rule the top level holds
    with pytest.raises(ValueError, match="key"):
        terrain_curriculum.update(state, done, success, jnp.ones(batch), config, levels)


def test_success_is_logged_per_type_and_level_of_the_episode_that_ended():
    types, levels = ("flat", "poles"), 3
    state = terrain_curriculum.TerrainLevels(
        terrain_type=jnp.asarray([0, 0, 1, 1, 1]), level=jnp.asarray([2, 2, 0, 1, 1])
    )
    done = jnp.asarray([True, True, True, True, False])
    success = jnp.asarray([True, False, True, False, True])  # the last env's episode has not ended
    sums = terrain_curriculum.cell_outcomes(state, done, success, len(types) * levels, levels)
    named = {k: float(v) for k, v in terrain_curriculum.name_outcomes(sums, types, levels).items()}
    summary = terrain_curriculum.summarize(named, levels)
    assert summary["terrain/success/flat/L2"] == 0.5 and summary["terrain/success/poles/L0"] == 1.0
    assert summary["terrain/success/poles/L1"] == 0.0
    assert "terrain/success/flat/L0" not in summary  # no episode ended there: not logged as 0


def test_level_logs_per_type_and_top_share():
    state = terrain_curriculum.TerrainLevels(terrain_type=jnp.asarray([0, 0, 1, 1]), level=jnp.asarray([0, 4, 4, 4]))
    sums = {k: float(v) for k, v in terrain_curriculum.totals(state, ("flat", "poles"), levels=5).items()}
    summary = terrain_curriculum.summarize(sums, levels=5)
    assert summary["terrain/mean_level/flat"] == 2.0 and summary["terrain/mean_level/poles"] == 4.0
    assert summary["terrain/top_share/flat"] == 0.5 and summary["terrain/top_share"] == 0.75


def test_levels_round_trip_through_a_checkpoint(tmp_path):
    """What the trainer saves is what a resume restores (the same batch), or the same mix (another batch)."""
    from train.run.saved import payload, restore_terrain

    config = train_config.load("configs/train_rough.yaml")
    levels = terrain_curriculum.init(
        jax.random.split(jax.random.PRNGKey(2), 64), config.terrain_curriculum, config.env.terrain
    )
    host = terrain_curriculum.to_host([jax.device_get(levels)])
    path = checkpoint.save(
        tmp_path,
        5,
        payload({"w": np.zeros(2)}, {"c": np.zeros(1)}, np.zeros(2, np.uint32), host),
        train_config.to_dict(config),
        extra={"terrain_envs": 64},
    )
    meta = {**checkpoint.read_meta(path), "path": path}
    same = restore_terrain(config, meta, 64)
    np.testing.assert_array_equal(np.asarray(same.level), np.asarray(levels.level))
    np.testing.assert_array_equal(np.asarray(same.terrain_type), np.asarray(levels.terrain_type))
    # on disk the terrain type keeps checkpoint format 1's name: a checkpoint of any version reads the same
    assert set(
        checkpoint.load(path, {"terrain_levels": {k: np.zeros(64, np.int32) for k in ("row", "level")}})[
            "terrain_levels"
        ]
    ) == {"row", "level"}
    more = restore_terrain(config, meta, 256)
    assert more.level.shape == (256,) and set(np.asarray(more.level).tolist()) <= set(np.asarray(levels.level).tolist())
    off = train_config.load("configs/train_rough.yaml", ["terrain_curriculum.enabled=false"])
    assert restore_terrain(off, meta, 64) is None


def test_terrain_evaluation_arguments():
    from train.episodes import terrain_eval

    rough = train_config.load("configs/train_rough.yaml").env
    assert terrain_eval.resolve_types("all", rough) == tuple(rough.terrain.types)
    assert terrain_eval.resolve_types(("stairs", "poles"), rough) == ("stairs", "poles")
    assert terrain_eval.check_levels((0, 0.5, 1)) == (0.0, 0.5, 1.0)
    for bad, match in ((("lava",), "lava"), (("spiral",), "goal.mode spiral"), ((), "unknown"), ("stairs", "unknown")):
        with pytest.raises(ValueError, match=match):
            terrain_eval.resolve_types(bad, rough)
    with pytest.raises(ValueError, match="--levels"):
        terrain_eval.check_levels((0.0, 1.5))
    assert terrain_eval.level_groups((1.0, 0.0, 0.5)) == [(0.0, 0.5, 1.0)]  # one atlas, one rollout
    assert terrain_eval.level_groups((0.2, 0.9)) == [(0.2,), (0.9,)]
    config = terrain_eval.cell_config(rough, ("stairs", "poles"), (0.0, 0.5, 1.0))
    assert config.terrain.level_difficulties == (0.0, 0.5, 1.0) and config.terrain.tiles_per_type == 1
    assert terrain_eval.cell_config(rough, ("poles",), (1.0,), tiles=8).terrain.tiles_per_type == 8


def test_a_terrain_evaluation_sizes_its_policy_on_one_tile():
    """The env an evaluation per terrain cell loads its policy with is one tile of one type and level: the
    policy's sizes, without the run's pool and distance fields (each cell's env is built for it)."""
    from hsa_mjx.task import observation
    from hsa_mjx.task.env import HSAEnv
    from train.episodes import policy_sources

    rough = train_config.load("configs/train_rough.yaml").env
    small = policy_sources.sizing_env_config(rough)
    assert (small.terrain.types, small.terrain.levels, small.terrain.tiles_per_type) == (("flat",), 1, 1)
    assert small.terrain.reachability.goal_sites == 1 < rough.terrain.reachability.goal_sites
    env = HSAEnv(small)
    assert env.observation_size == observation.observation_size(rough.observation) and env.action_size == 8
    assert len(env.world.pool.tiles) == 1
    flat = train_config.load("configs/train_flat.yaml").env
    assert policy_sources.sizing_env_config(flat) == flat  # a plane scene has nothing to skip


def test_terrain_table_rows_and_means():
    from train.episodes import terrain_eval

    rows = [
        {"type": t, "difficulty": d, "success_rate": s, "mean_progress_m": p}
        for t, d, s, p in (
            ("flat", 0.0, 1.0, 2.0),
            ("flat", 1.0, 1.0, 2.0),
            ("poles", 0.0, 1.0, 2.0),
            ("poles", 1.0, 0.5, 1.0),
        )
    ]
    lines = terrain_eval.table(rows).splitlines()
    assert lines[2].split() == ["flat", "100%", "2.00", "100%", "2.00"]
    assert lines[-1].split() == ["mean", "100%", "2.00", "75%", "1.50"]


def test_the_speed_of_reached_goals_counts_only_the_episodes_that_reached_them():
    from train.episodes import terrain_eval

    steps = 6
    alive = np.zeros((3, steps))
    alive[0, :5] = alive[1, :] = alive[2, :2] = 1  # reached at step 5; out of steps; reached at step 2
    success = np.zeros((3, steps))
    success[0, 4] = success[2, 1] = 1
    traces = {
        "alive": alive,
        "success": success,
        "distance": np.ones((3, steps)),
        "start_distance": np.array([2.0, 3.0, 0.5]),
        "reasons": np.zeros((3, steps, 1)),
    }
    outcome = terrain_eval.episode_outcomes(traces)
    assert outcome["steps"].tolist() == [5, 6, 2] and outcome["success"].tolist() == [True, False, True]
    speed = terrain_eval._success_speed(outcome, np.array([True, True, True]), dt=0.1)
    assert speed == pytest.approx((2.0 / 0.5 + 0.5 / 0.2) / 2)  # the failure's 6 steps do not count
    assert terrain_eval._success_speed(outcome, np.array([False, True, False]), dt=0.1) is None
