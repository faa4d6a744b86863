"""The env on terrain: per-env terrain tiles, spawn resting on them, terrain-relative termination, goals,
shared mode and rendering. The batched mixed-terrain env is compiled once per session (conftest)."""

import gymnasium
import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from conftest import TERRAIN_BATCH

import hsa_mjx
import hsa_mjx.config
from hsa_mjx.sim.model import BLOCKS, load_scene
from hsa_mjx.task import goals, observation
from hsa_mjx.terrain import TERRAIN_TYPES, surface_height
from hsa_mjx.terrain.atlas import TerrainPool
from hsa_mjx.terrain.world import TerrainWorld

REST = 0.14  # block origins above flat ground once settled (0.138-0.140 measured, docs/model.md)


def _world(config: hsa_mjx.config.EnvConfig, tiles: np.ndarray | None = None) -> tuple[TerrainWorld, mujoco.MjModel]:
    """The terrain world of ``config`` (its own pool, or one hand-made tile per slot given as ``tiles``)."""
    model, pool = load_scene(config)
    if tiles is not None:
        pool = TerrainPool(config.terrain, pool.layout, tiles, pool.tile_type)
    blocks = np.array([model.body(name).id for name in BLOCKS])
    return TerrainWorld(config.terrain, pool, model, blocks), model


def _height_over_own_ground(env, state) -> np.ndarray:
    """Block-origin height above the surface under each block, per env, shape (batch, 2)."""
    xpos = state.pipeline_state.physics.xpos[:, env.index.block_body]
    ground = jax.vmap(env.world.ground)(state.pipeline_state.task.tile, xpos[..., :2])
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
    height = _height_over_own_ground(terrain_env, start)  # on an incline the block over higher ground sets it
    np.testing.assert_allclose(height.min(axis=1), REST + clearance, atol=2e-3)
    assert np.all(height.max(axis=1) - height.min(axis=1) < 0.02)  # level robot: 0.46 m over a gentle slope
    absolute = np.asarray(start.pipeline_state.physics.xpos[:, terrain_env.index.block_body, 2])
    assert absolute.max() - absolute.min() > 0.05  # the envs stand at different heights: their own ground
    after = _height_over_own_ground(terrain_env, state)
    assert np.all(np.abs(after - REST) < 0.006), after
    assert not np.any(np.asarray(state.done)) and np.all(np.isfinite(np.asarray(state.obs)))


def test_each_reset_draws_a_tile_and_steps_keep_it(terrain_env, terrain_batch, settled):
    reset, _, counter = terrain_batch
    start, state = settled
    tile = np.asarray(start.pipeline_state.task.tile)
    np.testing.assert_array_equal(state.pipeline_state.task.tile, tile)
    again = np.asarray(reset(jax.random.split(jax.random.PRNGKey(12), TERRAIN_BATCH)).pipeline_state.task.tile)
    assert not np.array_equal(tile, again)
    pool = terrain_env.world.pool
    assert len(pool.tiles) == len(pool.layout.slots()) > len(set(pool.layout.types))  # random types: several tiles
    np.testing.assert_array_equal(np.asarray(start.pipeline_state.task.terrain_id), pool.tile_type[tile])
    floor = np.asarray(state.pipeline_state.physics.mocap_pos[:, terrain_env.index.terrain_mocap, :2])
    np.testing.assert_allclose(floor, -pool.centres[tile])  # each env's tile is moved under its robot
    assert counter.traces == 1


def test_tile_lookup_matches_mujoco_ray_casts_on_a_moved_atlas():
    """``world.ground(tile, xy)`` equals the surface MuJoCo collides with once the floor is moved for that tile."""
    world, model = _world(
        hsa_mjx.config.with_overrides(hsa_mjx.config.get_preset("craters"), terrain__tiles_per_type=4)
    )
    data = mujoco.MjData(model)
    points = np.random.default_rng(0).uniform(-4.5, 4.5, (60, 2))
    points = points[np.abs(points).max(axis=1) > 0.8]  # keep clear of the robot at the origin
    geom, floor = np.zeros(1, np.int32), model.body("terrain_frame").mocapid[0]
    for tile in (0, 3):
        data.mocap_pos[floor] = np.asarray(world.floor_position(tile))
        mujoco.mj_forward(model, data)
        rays = [
            3.0 - mujoco.mj_ray(model, data, np.array([x, y, 3.0]), np.array([0.0, 0.0, -1.0]), None, 1, -1, geom)
            for x, y in points
        ]
        np.testing.assert_allclose(np.asarray(world.ground(tile, jnp.asarray(points))), rays, atol=2e-5)
        own = surface_height(jnp.asarray(world.pool.tiles)[tile], world.grid, jnp.asarray(points))
        np.testing.assert_allclose(np.asarray(own), rays, atol=2e-5)  # the tile's own data, as generated
    assert np.ptp(world.pool.tiles, axis=0).max() > 0.05  # the tiles differ


def test_corridor_goals_lie_on_the_corridor_floor():
    config = hsa_mjx.config.with_overrides(
        hsa_mjx.config.get_preset("corridor"), goal__mode="radial", goal__radial_range=[1.5, 6.0]
    )
    world, _ = _world(config)
    tile, terrain_id = world.draw(jax.random.PRNGKey(0))
    keys = jax.random.split(jax.random.PRNGKey(1), 256)
    raw = jax.vmap(lambda k: goals.radial_goal(k, jnp.array([1.5, 6.0])))(keys)
    placed = np.asarray(jax.vmap(world.place_goal, in_axes=(0, None))(raw, terrain_id))
    centre_y = world.grid.fraction_to_y(config.terrain.corridor.center)  # the original's +0.102 m row
    np.testing.assert_allclose(placed[:, 1], centre_y, atol=1e-6)
    assert np.all(np.abs(placed[:, 0]) >= 1.5)
    assert np.abs(placed[:, 0]).max() <= world.grid.half_x - config.terrain.edge_margin + 1e-6
    np.testing.assert_array_equal(np.sign(placed[:, 0]), np.sign(np.asarray(raw)[:, 0]))
    np.testing.assert_array_equal(np.asarray(world.ground(tile, jnp.asarray(placed))), 0.0)
    assert float(world.ground(tile, jnp.array([0.0, 0.8]))) == pytest.approx(0.25)  # the wall beside it


def test_corridor_preset_floor_is_the_originals_three_vertex_rows():
    config = hsa_mjx.config.get_preset("corridor")
    world, _ = _world(config)
    rows = world.grid.ys()
    near = rows[np.argsort(np.abs(rows - 0.1))[:5]]  # y = -0.306 ... 0.510
    heights = {round(float(y), 3): float(world.ground(0, jnp.array([1.0, y]))) for y in near}
    assert [heights[y] for y in (-0.102, 0.102, 0.306)] == [0.0, 0.0, 0.0]  # rows 24-26 of the original
    assert min(heights[-0.306], heights[0.51]) > 0.95 * config.terrain.corridor.wall_height
    assert float(world.ground(0, jnp.array([2.0, 0.12]))) == 0.0  # the robot's feet (y +-0.1) stand on floor
    assert float(world.ground(0, jnp.array([-2.0, -0.1]))) == 0.0


def test_spiral_preset_checkpoints_sit_on_its_track():
    config = hsa_mjx.config.get_preset("spiral")
    world, _ = _world(config)
    checkpoints = jnp.asarray(goals.spiral_checkpoints(config.goal))
    np.testing.assert_array_equal(np.asarray(world.ground(0, checkpoints)), 0.0)
    assert float(np.max(world.pool.tiles[0])) * world.grid.z_scale == pytest.approx(config.terrain.spiral.wall_height)


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
def test_track_presets_have_one_tile_every_env_draws(preset):
    """The tracks are deterministic: the pool holds one tile, every draw takes it, and it equals the shared one."""
    world, _ = _world(hsa_mjx.config.get_preset(preset))
    tiles, _ = jax.vmap(world.draw)(jax.random.split(jax.random.PRNGKey(5), 4))
    np.testing.assert_array_equal(np.asarray(tiles), 0)
    shared, _ = _world(hsa_mjx.config.with_overrides(hsa_mjx.config.get_preset(preset), terrain__per_env=False))
    assert world.pool.tiles.shape == shared.pool.tiles.shape == (1, world.grid.size)
    np.testing.assert_allclose(world.pool.tiles[0], shared.pool.tiles[0], atol=1e-5)  # up to float rounding (a micron)
    assert np.ptp(world.pool.tiles[0]) * world.grid.z_scale > 0.2  # a real track: walls 0.2 m and more above the floor


def test_spawn_rests_the_lowest_geom_on_a_step_under_one_block():
    config = hsa_mjx.config.with_overrides(hsa_mjx.config.get_preset("craters"), terrain__per_env=False)
    grid = _world(config)[0].grid
    x, _ = grid.mesh()
    world, _ = _world(config, np.where(x < -0.05, 0.1 / grid.z_scale, 0.0).reshape(1, -1))  # 0.1 m step under block A
    z = float(world.spawn_height(0))
    assert z == pytest.approx(0.1 + REST + world.config.spawn_clearance, abs=1e-5)


def test_termination_heights_and_bounds_follow_the_terrain():
    config = hsa_mjx.config.with_overrides(hsa_mjx.config.get_preset("craters"), terrain__per_env=False)
    z_scale = _world(config)[0].grid.z_scale
    world, _ = _world(config, np.full((1, 2500), 0.3 / z_scale, np.float32))  # ground at 0.3 m everywhere
    np.testing.assert_allclose(np.asarray(world.ground(0, jnp.zeros((2, 2)))), 0.3, atol=1e-6)
    margin = world.config.edge_margin
    assert bool(world.out_of_bounds(jnp.array([5.0 - margin + 0.05, 0.0])))
    assert not bool(world.out_of_bounds(jnp.array([5.0 - margin - 0.05, -4.0])))
    plane, _ = _world(hsa_mjx.config.get_preset("flat"))
    assert not bool(plane.out_of_bounds(jnp.array([50.0, 0.0]))) and float(plane.ground(0, jnp.zeros(2))) == 0.0


def test_shared_mode_puts_one_terrain_into_the_model():
    config = hsa_mjx.config.with_overrides(
        hsa_mjx.config.get_preset("craters"), terrain__per_env=False, terrain__seed=3
    )
    world, model = _world(config)
    assert world.enabled and not world.per_env
    shared = world.pool.tiles[0]
    assert world.pool.tiles.shape == (1, world.grid.size) and shared.max() > 0.0
    np.testing.assert_array_equal(model.hfield_data, shared)  # one tile: the atlas is the asset's field
    tile, type_id = world.draw(None)
    assert int(tile) == 0 and TERRAIN_TYPES[int(type_id)] == "craters"
    np.testing.assert_array_equal(np.asarray(world.floor_position(tile)), 0.0)
    assert float(world.ground(tile, jnp.array([3.0, 3.0]))) == pytest.approx(
        float(surface_height(jnp.asarray(shared), world.grid, jnp.array([3.0, 3.0])))
    )
    other, _ = _world(hsa_mjx.config.with_overrides(config, terrain__seed=4))
    assert not np.array_equal(other.pool.tiles[0], shared)  # the seed picks the terrain


def test_gymnasium_renders_each_episodes_own_terrain():
    env = gymnasium.make(
        "hsa_mjx/HSA-v0",
        config="mixed",
        render_mode="rgb_array",
        width=64,
        height=48,
        camera="overview",
        terrain__types=["flat", "poles"],
    )
    try:
        frames, poles = [], []
        for seed in range(6):
            env.reset(seed=seed)
            frames.append(env.render())
            state = env.unwrapped.state
            poles.append(TERRAIN_TYPES[int(state.pipeline_state.task.terrain_id)] == "poles")
            drawn = env.unwrapped._renderer._data.mocap_pos[env.unwrapped.env.index.terrain_mocap]
            np.testing.assert_allclose(
                drawn, np.asarray(state.pipeline_state.physics.mocap_pos)[env.unwrapped.env.index.terrain_mocap]
            )  # the drawn floor is the episode's tile
        assert any(poles) and not all(poles)  # both flat and pole tiles were drawn
        flat, pole = poles.index(False), poles.index(True)
        assert np.abs(frames[flat].astype(int) - frames[pole].astype(int)).mean() > 1.0
    finally:
        env.close()


def test_make_env_on_terrain_rejects_a_bad_type():
    with pytest.raises(ValueError, match="valid types"):
        hsa_mjx.make_env("mixed", terrain__types=["flat", "lava"])
