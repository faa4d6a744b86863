"""The env on terrain tasks, with one shared env (a bent corridor and a pole field): goals at the tiles'
goal sites with progress measured along the ground, and the random tiles re-drawn on the device."""

from __future__ import annotations

import copy
import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import hsa_mjx
from hsa_mjx.batch.auto_reset import AutoResetEnv
from hsa_mjx.task import observation, progress
from hsa_mjx.task.params import EnvParams
from hsa_mjx.terrain import TERRAIN_TYPES, reachability

ENVS = 4
CELLS = [(0, 0), (0, 0), (1, 0), (1, 0)]  # two envs in the corridor, two among the poles


@pytest.fixture(scope="module")
def batch():
    env = hsa_mjx.make_env(
        "flat",
        num_envs=ENVS,
        scene="terrain",
        terrain__types=["corridor", "poles"],
        terrain__tiles_per_type=2,
        terrain__corridor__corridor_width=0.72,
        terrain__corridor__center=0.510204,
        terrain__corridor__bend_amplitude=0.5,
        terrain__corridor__bend_wavelength=6.0,
        terrain__reachability__enabled=True,
        terrain__reachability__goal_sites=4,
        goal__mode="radial",
        goal__radial_range=[3.0, 4.5],
        reward__progress="geodesic",
        observation__heading=True,
        observation__path_direction=True,
    )
    return AutoResetEnv(env, regenerate_every=2)


@pytest.fixture(scope="module")
def start(batch):
    params = jax.tree.map(lambda *x: jnp.stack(x), *[EnvParams.make((3.0, 4.5), cell) for cell in CELLS])
    return jax.jit(batch.reset)(jax.random.split(jax.random.PRNGKey(0), ENVS), params)


@pytest.fixture(scope="module")
def step(batch):
    return jax.jit(batch.step)


def _tile_data(batch, atlas: np.ndarray, tile: int) -> np.ndarray:
    layout = batch.env.world.pool.layout
    r, c = layout.slots()[tile]
    t = layout.tile
    return atlas.reshape(layout.rows * t.nrow, -1)[r * t.nrow : (r + 1) * t.nrow, c * t.ncol : (c + 1) * t.ncol]


def test_goals_are_sites_and_progress_is_measured_along_the_bent_corridor(batch, start, step):
    task, sites = start.env.pipeline_state.task, batch.env.world.sites
    site, tile = np.asarray(task.site), np.asarray(task.tile)
    assert (site >= 0).all()
    np.testing.assert_allclose(np.asarray(task.goal_xy), sites.xy[tile, site])
    distance = np.asarray(start.env.metrics["distance_to_goal"])
    np.testing.assert_allclose(distance, sites.spawn_distance[tile, site], atol=0.25)  # the spawn is ~a cell off
    straight = np.hypot(*(np.asarray(task.goal_xy) - np.asarray(batch.env.spawn_xy)).T)
    assert (distance >= 3.0 - 0.25).all() and (distance[:2] > straight[:2] + 0.05).all()  # the bends add way
    stepped = step(start, jnp.zeros((ENVS, batch.env.action_size)))
    assert np.isfinite(np.asarray(stepped.env.reward)).all()
    assert np.abs(np.asarray(stepped.env.metrics["distance_to_goal"]) - distance).max() < 0.05


def test_the_observation_shows_the_path_direction_in_the_heading_frame(batch, start):
    """``observation.path_direction``: the field's downhill unit vector turned into the heading frame, beside
    the straight goal direction; round the bends and poles the two differ."""
    env, data = batch.env, start.env.pipeline_state.physics
    labels = list(observation.observation_labels(env.config.observation))
    obs = np.asarray(start.env.obs)
    path = obs[:, [labels.index("path_dir_ahead"), labels.index("path_dir_left")]]
    goal = obs[:, [labels.index("goal_dir_ahead"), labels.index("goal_dir_left")]]
    xy = jax.vmap(lambda d: observation.robot_xy(d, env.index))(data)
    world = jax.vmap(env.progress.measure)(start.env.pipeline_state.task, xy)[1]
    heading = jax.vmap(lambda d: observation.heading(d, env.index))(data)
    expected = jax.vmap(observation.to_heading_frame)(world, heading)
    np.testing.assert_allclose(path, np.asarray(expected), atol=1e-5)
    np.testing.assert_allclose(np.linalg.norm(path, axis=1), 1.0, atol=1e-4)
    assert np.degrees(np.arccos(np.clip((path * goal).sum(1), -1, 1))).max() > 5.0


def test_path_direction_needs_geodesic_progress():
    with pytest.raises(ValueError, match="observation.path_direction"):
        hsa_mjx.build_config("flat", observation__path_direction=True)


def test_a_goal_without_a_site_is_measured_along_the_straight_line(batch, start):
    """``set_goal`` (a goal set by hand) leaves no site: the distance falls back to the straight line."""
    task = jax.tree.map(lambda x: x[0], start.env.pipeline_state.task)
    task = task.replace(goal_xy=jnp.array([1.0, 0.5]), site=jnp.asarray(progress.NO_SITE, jnp.int32))
    xy = batch.env.spawn_xy
    distance, direction = jax.jit(batch.env.progress.measure)(task, xy)
    assert float(distance) == pytest.approx(float(jnp.linalg.norm(jnp.array([1.0, 0.5]) - xy)), rel=1e-5)
    np.testing.assert_allclose(direction, (jnp.array([1.0, 0.5]) - xy) / distance, atol=1e-5)


def _pole_tiles(batch) -> list[int]:
    """The pole tiles (of both halves: a cell's tiles at even and at odd positions, here one each)."""
    return [i for i, t in enumerate(batch.env.world.pool.tile_type) if t == TERRAIN_TYPES.index("poles")]


def test_tiles_change_when_regenerated_and_the_env_runs_on_the_new_ones(batch, start, step):
    tick = jax.jit(batch.tick)
    once = tick(start, jax.random.PRNGKey(1))
    assert int(once.terrain.generation) == 0  # one iteration: not yet due
    np.testing.assert_array_equal(np.asarray(once.terrain.atlas), np.asarray(start.terrain.atlas))
    twice = tick(once, jax.random.PRNGKey(2))
    assert int(twice.terrain.generation) == 1 and int(twice.terrain.age) == 0
    before, after = np.asarray(start.terrain.atlas), np.asarray(twice.terrain.atlas)
    written = [i for i in _pole_tiles(batch) if batch.regenerator.tile_half[i] == 1]  # the half no episode had drawn
    assert written and all(not np.allclose(_tile_data(batch, before, i), _tile_data(batch, after, i)) for i in written)
    kept = [i for i in range(len(batch.env.world.pool.tile_type)) if i not in written]
    assert all(np.array_equal(_tile_data(batch, before, i), _tile_data(batch, after, i)) for i in kept)
    # The new tiles were mapped: goal ground where the check asks for it, sites on it at their path distance.
    reach = batch.env.config.terrain.reachability
    fields = np.asarray(twice.terrain.reach)
    assert (reachability.goal_area(fields, reach.goal_range, reach.resolution) >= reach.min_area).all()
    spawn = np.asarray(twice.terrain.site_spawn)
    assert ((spawn >= reach.goal_range[0]) & (spawn <= reach.goal_range[1])).all()
    assert not np.allclose(spawn[written], np.asarray(start.terrain.site_spawn)[written])
    # The env reads the new tiles: the physics' heightfield, the ground, the goal sites.
    env = batch.bound(twice)
    assert env.robot.mjx_model.hfield_data is twice.terrain.atlas
    stepped = step(twice, jnp.zeros((ENVS, env.action_size)))
    assert np.isfinite(np.asarray(stepped.env.reward)).all() and stepped.terrain is not None


def _same_site_and_ground(state, grounds: dict[int, np.ndarray], batch) -> None:
    """Every env's goal is its goal site on its tile (the site whose field measures its progress), and the
    ground under every env is the tile it started on (``grounds``: env -> tile data at its start)."""
    task = state.env.pipeline_state.task
    tile, site = np.asarray(task.tile), np.asarray(task.site)
    np.testing.assert_allclose(np.asarray(task.goal_xy), np.asarray(state.terrain.site_xy)[tile, site])
    for env, data in grounds.items():
        np.testing.assert_array_equal(_tile_data(batch, np.asarray(state.terrain.atlas), int(tile[env])), data)


def test_no_tile_changes_under_a_running_episode(batch, start, step):
    """A re-draw writes the half of a cell's tiles no episode started on since the re-draw before; an episode
    still on the half being written (two re-draws old) is truncated and restarts on the new ground."""
    tick = jax.jit(batch.tick)
    state = step(start, jnp.zeros((ENVS, batch.env.action_size)))
    tiles = np.asarray(state.env.pipeline_state.task.tile)
    grounds = {e: _tile_data(batch, np.asarray(state.terrain.atlas), int(tiles[e])) for e in range(ENVS)}
    first = tick(tick(state, jax.random.PRNGKey(3)), jax.random.PRNGKey(4))  # re-draw 1
    assert int(first.terrain.generation) == 1 and float(first.totals["redraw_truncations"]) == 0
    np.testing.assert_array_equal(np.asarray(first.env.pipeline_state.task.step_count), 1)  # all still running
    _same_site_and_ground(first, grounds, batch)
    second = tick(tick(first, jax.random.PRNGKey(5)), jax.random.PRNGKey(6))  # re-draw 2: the poles' first half
    poles = [e for e, cell in enumerate(CELLS) if cell[0] == 1]
    assert float(second.totals["redraw_truncations"]) == len(poles)
    steps, new_tiles = (
        np.asarray(second.env.pipeline_state.task.step_count),
        np.asarray(second.env.pipeline_state.task.tile),
    )
    assert (steps[poles] == 0).all() and (steps[[e for e in range(ENVS) if e not in poles]] == 1).all()
    assert all(batch.regenerator.tile_half[new_tiles[e]] == 0 for e in poles)  # the tiles just written
    _same_site_and_ground(second, {e: grounds[e] for e in range(ENVS) if e not in poles}, batch)


def test_a_reset_episode_carries_nothing_of_the_one_before(batch, start, step):
    """An env reset in a batch starts exactly as a fresh reset from its key: no goal, site, tile, history,
    previous action or physics of its last episode (nor of another env) leaks into it."""
    state = start
    for i in range(3):
        state = step(state, jax.random.uniform(jax.random.PRNGKey(i), (ENVS, batch.env.action_size), minval=-1))
    done = jnp.asarray([True, False, True, False])
    params = jax.tree.map(lambda *x: jnp.stack(x), *[EnvParams.make((3.0, 4.5), cell) for cell in CELLS])
    reset = jax.jit(batch._reset_where)(state, done, params)
    keys = jax.vmap(lambda k: jax.random.split(k)[1])(state.env.pipeline_state.task.rng)
    fresh = jax.jit(jax.vmap(batch.bound(state).reset))(keys, params)
    for e in range(ENVS):
        got = jax.tree.map(lambda x, e=e: np.asarray(x[e]), (reset.env.obs, reset.env.pipeline_state.task))
        want = jax.tree.map(lambda x, e=e: np.asarray(x[e]), (fresh.obs, fresh.pipeline_state.task))
        before = jax.tree.map(lambda x, e=e: np.asarray(x[e]), (state.env.obs, state.env.pipeline_state.task))
        jax.tree.map(np.testing.assert_array_equal, got, want if done[e] else before)
    np.testing.assert_array_equal(
        np.asarray(reset.env.pipeline_state.physics.qpos)[[0, 2]], np.asarray(fresh.pipeline_state.physics.qpos)[[0, 2]]
    )


def test_regeneration_needs_per_env_terrain_with_a_random_type():
    from train import config as train_config

    with pytest.raises(ValueError, match="regenerate_terrain_every"):
        train_config.from_dict({"run": {"regenerate_terrain_every": 5}})  # the default env: a plane
    with pytest.raises(ValueError, match="regenerate_terrain_every"):
        train_config.from_dict({"run": {"regenerate_terrain_every": -1}})


def test_regeneration_refuses_c_mujoco_physics(batch):
    c_env = copy.copy(batch.env)
    c_env.robot = dataclasses.replace(c_env.robot, backend="c")  # what physics.backend c builds
    assert c_env.physics_backend == "c"
    with pytest.raises(ValueError, match="MJX physics"):
        AutoResetEnv(c_env, regenerate_every=1)
