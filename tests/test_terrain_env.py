"""The env on terrain: per-env terrain, spawn resting on it, terrain-relative termination, goals,
shared mode and rendering. The batched mixed-terrain env is compiled once per session (conftest)."""

import gymnasium
import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from mujoco import mjx

import hsa_mjx
from conftest import TERRAIN_BATCH
from hsa_mjx import config as cfg
from hsa_mjx import goals, observation
from hsa_mjx.model import BLOCKS, load_mj_model
from hsa_mjx.terrain import TERRAIN_TYPES, Grid, surface_height
from hsa_mjx.terrain.world import TerrainWorld

REST = 0.14  # block origins above flat ground once settled (0.138-0.140 measured, docs/model.md)


def _world(config: cfg.EnvConfig) -> tuple[TerrainWorld, mujoco.MjModel]:
    model = load_mj_model(config)
    blocks = np.array([model.body(name).id for name in BLOCKS])
    return TerrainWorld(config.scene, config.terrain, model, blocks), model


def _height_over_own_ground(env, state) -> np.ndarray:
    """Block-origin height above the surface under each block, per env, shape (batch, 2)."""
    xpos = state.pipeline_state.physics.xpos[:, env.index.block_body]
    ground = jax.vmap(env.world.ground)(state.pipeline_state.task.terrain, xpos[..., :2])
    return np.asarray(xpos[..., 2] - ground)


@pytest.fixture(scope="module")
def settled(terrain_env, terrain_batch):
    """A mixed batch right after reset and after 10 steps of holding the servos."""
    reset, step, _ = terrain_batch
    start = reset(jax.random.split(jax.random.PRNGKey(11), TERRAIN_BATCH))
    state = start
    for _ in range(10):
        state = step(state, jnp.zeros((TERRAIN_BATCH, 8)))
    return start, state


def test_mixed_batch_spawns_and_settles_on_each_own_terrain(terrain_env, settled):
    start, state = settled
    types = {TERRAIN_TYPES[i] for i in np.asarray(start.pipeline_state.task.terrain_id)}
    assert len(types) >= 5, types
    clearance = terrain_env.config.terrain.spawn_clearance
    np.testing.assert_allclose(_height_over_own_ground(terrain_env, start), REST + clearance, atol=2e-3)
    absolute = np.asarray(start.pipeline_state.physics.xpos[:, terrain_env.index.block_body, 2])
    assert absolute.max() - absolute.min() > 0.05  # the envs stand at different heights: their own ground
    after = _height_over_own_ground(terrain_env, state)
    assert np.all(np.abs(after - REST) < 0.006), after
    assert not np.any(np.asarray(state.done)) and np.all(np.isfinite(np.asarray(state.obs)))


def test_each_reset_draws_a_new_terrain_and_steps_keep_it(terrain_batch, settled):
    reset, _, counter = terrain_batch
    start, state = settled
    np.testing.assert_array_equal(state.pipeline_state.task.terrain, start.pipeline_state.task.terrain)
    again = reset(jax.random.split(jax.random.PRNGKey(12), TERRAIN_BATCH))
    old, new = np.asarray(start.pipeline_state.task.terrain), np.asarray(again.pipeline_state.task.terrain)
    assert old.shape == (TERRAIN_BATCH, 2500) and not np.array_equal(old, new)
    assert counter.traces == 1


def test_corridor_goals_lie_on_the_corridor_floor():
    config = cfg.with_overrides(cfg.get_preset("corridor"), goal__mode="radial", goal__radial_range=[1.5, 6.0])
    world, _ = _world(config)
    terrain, terrain_id = world.sampler.sample(jax.random.PRNGKey(0))
    keys = jax.random.split(jax.random.PRNGKey(1), 256)
    raw = jax.vmap(lambda k: goals.radial_goal(k, jnp.array([1.5, 6.0])))(keys)
    placed = np.asarray(jax.vmap(world.place_goal, in_axes=(0, None))(raw, terrain_id))
    centre_y = world.grid.fraction_to_y(config.terrain.corridor.center)  # the original's +0.102 m row
    np.testing.assert_allclose(placed[:, 1], centre_y, atol=1e-6)
    assert np.all(np.abs(placed[:, 0]) >= 1.5)
    assert np.abs(placed[:, 0]).max() <= world.grid.half_x - config.terrain.edge_margin + 1e-6
    np.testing.assert_array_equal(np.sign(placed[:, 0]), np.sign(np.asarray(raw)[:, 0]))
    np.testing.assert_array_equal(np.asarray(surface_height(terrain, world.grid, jnp.asarray(placed))), 0.0)
    assert float(world.ground(terrain, jnp.array([0.0, 0.8]))) == pytest.approx(0.25)  # the wall beside it


def test_corridor_preset_floor_is_the_originals_three_vertex_rows():
    config = cfg.get_preset("corridor")
    world, _ = _world(config)
    terrain, _ = world.sampler.sample(jax.random.PRNGKey(0))
    rows = world.grid.ys()
    near = rows[np.argsort(np.abs(rows - 0.1))[:5]]  # y = -0.306 ... 0.510
    heights = {round(float(y), 3): float(world.ground(terrain, jnp.array([1.0, y]))) for y in near}
    assert [heights[y] for y in (-0.102, 0.102, 0.306)] == [0.0, 0.0, 0.0]  # rows 24-26 of the original
    assert min(heights[-0.306], heights[0.51]) > 0.95 * config.terrain.corridor.wall_height
    assert float(world.ground(terrain, jnp.array([2.0, 0.12]))) == 0.0  # the robot's feet (y +-0.1) stand on floor
    assert float(world.ground(terrain, jnp.array([-2.0, -0.1]))) == 0.0


def test_spiral_preset_checkpoints_sit_on_its_track():
    config = cfg.get_preset("spiral")
    world, _ = _world(config)
    terrain, _ = world.sampler.sample(jax.random.PRNGKey(0))
    checkpoints = jnp.asarray(goals.spiral_checkpoints(config.goal))
    np.testing.assert_array_equal(np.asarray(world.ground(terrain, checkpoints)), 0.0)
    assert float(jnp.max(terrain)) * world.grid.z_scale == pytest.approx(config.terrain.spiral.wall_height)


def test_spiral_track_starts_stand_the_robot_on_its_track_facing_the_next_checkpoint():
    """goal.track_starts: episode k starts on checkpoint k - 1, resting on the track, heading for k."""
    env = hsa_mjx.make_env("spiral", goal__num_checkpoints=20, goal__track_starts=19, observation__heading=True)
    start = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(3), 8))
    task = start.pipeline_state.task
    index = np.asarray(task.checkpoint_index)
    assert len(set(index.tolist())) >= 5 and index.max() <= 19, index
    checkpoints = goals.spiral_checkpoints(env.config.goal)
    np.testing.assert_allclose(np.asarray(task.goal_xy), checkpoints[index], atol=1e-6)
    xy = np.asarray(start.pipeline_state.physics.xpos[:, env.index.block_body, :2].mean(axis=1))
    expected = np.where(index[:, None] > 0, checkpoints[np.maximum(index - 1, 0)], 0.0)  # k = 0: the origin
    np.testing.assert_allclose(xy, expected, atol=1e-5)
    # resting on the highest ground under the turned footprint: never in it, at most a ramp's rise above
    lift = _height_over_own_ground(env, start) - REST - env.config.terrain.spawn_clearance
    assert lift.min() > -1e-3 and lift.max() < 0.03, lift
    labels = observation.observation_labels(env.config.observation)
    ahead = np.asarray(start.obs[:, labels.index("goal_dir_ahead")])
    np.testing.assert_allclose(ahead[index > 0], 1.0, atol=1e-5)  # facing the goal checkpoint
    # reset_at_checkpoint: the same start at a chosen checkpoint (to probe a policy on one stretch of track)
    chosen = np.array([0, 4, 19])
    at = jax.jit(jax.vmap(env.reset_at_checkpoint))(jax.random.split(jax.random.PRNGKey(5), 3), jnp.asarray(chosen))
    np.testing.assert_array_equal(np.asarray(at.pipeline_state.task.checkpoint_index), chosen)
    np.testing.assert_allclose(np.asarray(at.pipeline_state.task.goal_xy), checkpoints[chosen], atol=1e-6)
    at_xy = np.asarray(at.pipeline_state.physics.xpos[:, env.index.block_body, :2].mean(axis=1))
    np.testing.assert_allclose(at_xy[1:], checkpoints[chosen[1:] - 1], atol=1e-5)
    with pytest.raises(ValueError, match=r"checkpoint index must be in 0\.\.19, got 20"):
        env.reset_at_checkpoint(jax.random.PRNGKey(0), 20)


@pytest.mark.parametrize("preset", ["corridor", "spiral"])
def test_track_presets_draw_the_same_terrain_from_every_key(preset):
    """The tracks are deterministic, so one shared copy (terrain.per_env: false) equals every per-env draw."""
    world, _ = _world(cfg.get_preset(preset))
    draws = jax.vmap(world.sampler.sample)(jax.random.split(jax.random.PRNGKey(5), 4))[0]
    shared, _ = _world(cfg.with_overrides(cfg.get_preset(preset), terrain__per_env=False))
    draws = np.asarray(draws)
    np.testing.assert_array_equal(draws, np.broadcast_to(draws[0], draws.shape))  # every key: the same field
    np.testing.assert_allclose(draws[0], shared.shared_data, atol=1e-5)  # = the shared one, up to float rounding (a micron)
    assert np.ptp(draws[0]) > 0.4  # a real track, walls and floor


def test_spawn_rests_the_lowest_geom_on_a_step_under_one_block():
    world, _ = _world(cfg.get_preset("craters"))
    x, _ = world.grid.mesh()
    data = jnp.asarray(np.where(x < -0.05, 0.2, 0.0).reshape(-1), jnp.float32)  # 0.1 m step under block A
    z = float(world.spawn_height(data))
    assert z == pytest.approx(0.1 + REST + world.config.spawn_clearance, abs=1e-5)


def test_termination_heights_and_bounds_follow_the_terrain():
    world, _ = _world(cfg.get_preset("craters"))
    data = jnp.full((world.grid.size,), 0.6, jnp.float32)  # ground at 0.3 m everywhere
    np.testing.assert_allclose(np.asarray(world.ground(data, jnp.zeros((2, 2)))), 0.3, atol=1e-6)
    margin = world.config.edge_margin
    assert bool(world.out_of_bounds(jnp.array([5.0 - margin + 0.05, 0.0])))
    assert not bool(world.out_of_bounds(jnp.array([5.0 - margin - 0.05, -4.0])))
    plane, _ = _world(cfg.get_preset("flat"))
    assert not bool(plane.out_of_bounds(jnp.array([50.0, 0.0]))) and float(plane.ground(None, jnp.zeros(2))) == 0.0


def test_shared_mode_bakes_one_terrain_into_both_models():
    config = cfg.with_overrides(cfg.get_preset("craters"), terrain__per_env=False, terrain__seed=3)
    world, model = _world(config)
    assert world.enabled and not world.per_env
    shared = world.shared_data
    assert shared.shape == (world.grid.size,) and shared.max() > 0.0
    np.testing.assert_array_equal(model.hfield_data, shared)
    baked = world.bake(mjx.put_model(model))
    np.testing.assert_array_equal(np.asarray(baked.hfield_data), shared)
    placeholder, type_id = world.draw(None)
    assert placeholder.shape == (1,) and TERRAIN_TYPES[int(type_id)] == "craters"
    assert float(world.ground(placeholder, jnp.array([3.0, 3.0]))) == pytest.approx(
        float(surface_height(jnp.asarray(shared), Grid.from_model(model), jnp.array([3.0, 3.0]))))


def test_gymnasium_renders_each_episodes_own_terrain():
    env = gymnasium.make("hsa_mjx/HSA-v0", config="mixed", render_mode="rgb_array", width=64, height=48,
                         camera="overview", terrain__types=["flat", "poles"])
    try:
        frames, terrains = [], []
        for seed in range(6):
            env.reset(seed=seed)
            frames.append(env.render())
            terrain = np.asarray(env.unwrapped._state.pipeline_state.task.terrain)
            np.testing.assert_array_equal(env.unwrapped.env.robot.mj_model.hfield_data, terrain)
            terrains.append(terrain.max() > 0)
        assert any(terrains) and not all(terrains)  # both flat and pole fields were drawn
        flat, poles = terrains.index(False), terrains.index(True)
        assert np.abs(frames[flat].astype(int) - frames[poles].astype(int)).mean() > 1.0
    finally:
        env.close()


def test_make_env_on_terrain_rejects_a_bad_type():
    with pytest.raises(ValueError, match="valid types"):
        hsa_mjx.make_env("mixed", terrain__types=["flat", "lava"])
