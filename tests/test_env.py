"""The jitted env: determinism, a finite batch, retracing, NaN handling, Brax compatibility."""

import itertools

import brax.envs.wrappers.training as brax_wrappers
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import BATCH

import hsa_mjx


def _actions(key, n):
    return jax.random.uniform(key, (n, 8), minval=-1.0, maxval=1.0)


def test_reset_matches_the_original_start(env, jit_single):
    reset, _, _ = jit_single
    state = reset(jax.random.PRNGKey(0))
    assert state.obs.shape == (24,) == (env.observation_size,) and state.obs.dtype == jnp.float32
    np.testing.assert_allclose(state.obs[:21], 0.0, atol=1e-6)  # robot at rest at the origin
    goal = np.asarray(state.pipeline_state.task.goal_xy)
    assert 1.5 <= abs(goal[0]) <= 4.5 and abs(goal[1]) <= 4.0
    assert float(state.obs[21]) == pytest.approx(np.linalg.norm(goal), rel=1e-5)
    # The reset state carries kinematics only: block bodies sit at their free joints' positions,
    # foot contact forces are zero until a step computes them (once the spawned robot has landed on its feet).
    physics, index = state.pipeline_state.physics, env.index
    np.testing.assert_allclose(
        physics.xpos[index.block_body], physics.qpos[index.block_qpos[:, None] + np.arange(3)], atol=1e-6
    )
    assert not np.any(physics.sensordata[index.foot_sensors])
    for _ in range(10):  # the robot spawns a little above the floor and lands within 0.2 s
        state = jit_single[1](state, jnp.zeros(8))
    assert np.abs(state.pipeline_state.physics.sensordata[index.foot_sensors]).sum() > 0.0


def test_same_key_same_trajectory(jit_single):
    reset, step, _ = jit_single
    runs = []
    for _ in range(2):
        state = reset(jax.random.PRNGKey(7))
        for a in _actions(jax.random.PRNGKey(3), 5):
            state = step(state, a)
        runs.append(np.asarray(state.obs))
    np.testing.assert_array_equal(runs[0], runs[1])
    other = reset(jax.random.PRNGKey(8))
    assert not np.allclose(other.pipeline_state.task.goal_xy, reset(jax.random.PRNGKey(7)).pipeline_state.task.goal_xy)


def test_batch_stays_finite_for_200_random_steps_without_retracing(jit_batch):
    reset, step, counter = jit_batch
    state = reset(jax.random.split(jax.random.PRNGKey(0), BATCH))
    keys = jax.random.split(jax.random.PRNGKey(1), 200)
    for key in keys:
        state = step(state, _actions(key, BATCH))
    assert counter.traces == 1  # one trace for 200 calls
    assert np.all(np.isfinite(state.obs)) and np.all(np.isfinite(state.reward))
    z = np.asarray(state.pipeline_state.physics.xpos)[:, 1, 2]
    assert np.all((z > 0.05) & (z < 0.4))  # still on the ground
    assert float(state.metrics["termination/non_finite"].sum()) == 0.0
    moved = np.abs(np.asarray(state.obs[:, :8])).max()
    assert moved > 0.1  # the servos really turned the hinges


def test_reward_is_the_sum_of_logged_components(jit_single):
    reset, step, counter = jit_single
    state = step(reset(jax.random.PRNGKey(2)), jnp.full(8, 0.5, jnp.float32))
    assert counter.traces == 1  # single and batch steps share one compile (a weak-typed action would not)
    parts = sum(float(v) for k, v in state.metrics.items() if k.startswith("reward/"))
    assert float(state.reward) == pytest.approx(parts, rel=1e-5, abs=1e-6)


@pytest.fixture(scope="module")
def options_env():
    """An env with every optional observation entry and the heading shaping term on: (env, reset, step)."""
    env = hsa_mjx.make_env(
        "flat",
        observation__heading=True,
        observation__servo_targets=True,
        observation__clock_period_s=1.0,
        observation__hinge_angles="sincos",
        reward__heading_alignment=100.0,
    )
    return env, jax.jit(env.reset), jax.jit(env.step)


def test_heading_alignment_is_wired_to_the_robot_axis(options_env):
    """With the shaping weight on, the logged term is w * (|cos| after - |cos| before) of axis vs goal."""
    from hsa_mjx.task import observation

    env, reset, step = options_env
    state = reset(jax.random.PRNGKey(4))
    one_sided = jnp.array([1.0, 1.0, 0.0, 0.0, 1.0, 1.0, 0.0, 0.0])
    logged, expected = [], []
    for _ in range(30):
        new = step(state, one_sided)
        data, goal = new.pipeline_state.physics, new.pipeline_state.task.goal_xy
        _, direction = observation.goal_vector(observation.robot_xy(data, env.index), goal)
        cos = [
            abs(float(jnp.dot(observation.heading(d, env.index), direction)))
            for d in (state.pipeline_state.physics, data)
        ]
        expected.append(100.0 * (cos[1] - cos[0]))
        logged.append(float(new.metrics["reward/heading_alignment"]))
        state = new
    np.testing.assert_allclose(logged, expected, rtol=1e-3, atol=1e-5)
    assert np.max(np.abs(logged)) > 1e-4  # the robot did rotate


def test_nan_state_terminates_and_never_reaches_the_learner(jit_single):
    reset, step, _ = jit_single
    state = reset(jax.random.PRNGKey(0))
    physics = state.pipeline_state.physics
    poisoned = physics.replace(qvel=physics.qvel.at[7].set(jnp.nan))
    state = state.replace(pipeline_state=state.pipeline_state.replace(physics=poisoned))
    out = step(state, jnp.zeros(8))
    assert float(out.done) == 1.0 and float(out.metrics["termination/non_finite"]) == 1.0
    assert np.all(np.isfinite(out.obs)) and np.isfinite(float(out.reward))
    assert float(out.info["truncation"]) == 0.0
    # simulator health and task failure are reported apart
    assert float(out.metrics["termination/simulator_health"]) == 1.0
    assert float(out.metrics["termination/task_failure"]) == 0.0


def test_nonfinite_action_is_sanitised_and_counted(jit_single):
    reset, step, _ = jit_single
    out = step(reset(jax.random.PRNGKey(0)), jnp.array([jnp.nan, 1, 1, 1, 1, 1, 1, jnp.inf]))
    assert float(out.metrics["nonfinite_action"]) == 1.0 and np.all(np.isfinite(out.obs))


def test_goal_reached_and_truncation_are_separate(env, jit_single):
    reset, step, _ = jit_single
    set_goal = jax.jit(env.set_goal)
    near = set_goal(reset(jax.random.PRNGKey(0)), jnp.array([0.0, 0.05]))  # inside the success radius
    out = step(near, jnp.zeros(8))
    assert float(out.metrics["termination/goal_reached"]) == 1.0 and float(out.done) == 1.0
    assert float(out.info["truncation"]) == 0.0 and float(out.metrics["reward/goal_bonus"]) == 40.0
    far = set_goal(reset(jax.random.PRNGKey(0)), jnp.array([3.0, 0.0]))
    last = env.config.termination.max_episode_steps - 1  # the episode's last step comes next
    task = far.pipeline_state.task.replace(step_count=jnp.int32(last))
    far = step(far.replace(pipeline_state=far.pipeline_state.replace(task=task)), jnp.zeros(8))
    assert float(far.info["truncation"]) == 1.0 and float(far.done) == 1.0
    assert float(far.metrics["termination/goal_reached"]) == 0.0
    assert float(step(reset(jax.random.PRNGKey(0)), jnp.zeros(8)).done) == 0.0  # not on an earlier step


def test_brax_training_wrappers_run_unchanged(env):
    wrapped = brax_wrappers.wrap(env, episode_length=3, action_repeat=1)
    reset, step = jax.jit(wrapped.reset), jax.jit(wrapped.step)
    state = reset(jax.random.split(jax.random.PRNGKey(0), 2))
    for _ in range(3):
        state = step(state, jnp.zeros((2, 8)))
    assert state.obs.shape == (2, 24) and np.all(state.done == 1) and np.all(state.info["truncation"] == 1)
    state = step(state, jnp.zeros((2, 8)))  # Brax resets the step counter on the next step
    assert np.all(state.info["steps"] == 1) and np.all(state.done == 0)
    assert "reward/forward" in state.info["episode_metrics"]


def _lapack_calls(lowered) -> int:
    """How many LAPACK custom calls a lowered program makes."""
    return lowered.as_text().count("lapack_")


def test_large_batches_lower_without_lapack_on_cpu(env):
    """jit(vmap(step)) over 64 envs has no LAPACK call left, small batches keep LAPACK's fast kernels.

    Before hsa_mjx.sim.cpu_linalg a step over 64 envs hung forever on a 2-core machine (jaxlib's batched
    LAPACK Cholesky deadlocks its thread pool once a batch exceeds 44 matrices; 1024 envs hung as well).
    The lowering is checked (XLA's own ops have no such pool), and a 64-matrix batch is run against numpy.
    """
    from hsa_mjx.sim import cpu_linalg

    assert cpu_linalg.use_xla_linalg_on_cpu()  # installed when the env was built (hsa_mjx.sim.model.load_robot)
    n = 64
    state = jax.eval_shape(jax.vmap(env.reset), jax.random.split(jax.random.PRNGKey(7), n))
    assert _lapack_calls(jax.jit(jax.vmap(env.step)).lower(state, jnp.zeros((n, env.action_size)))) == 0
    spd = np.eye(24, dtype=np.float32) * 3 + np.random.default_rng(0).normal(size=(n, 24, 24)).astype(np.float32) / 8
    spd = spd @ np.swapaxes(spd, 1, 2)
    for batch, lapack in ((n, False), (4, True)):
        lowered = jax.jit(jnp.linalg.cholesky).lower(spd[:batch])
        assert (_lapack_calls(lowered) > 0) == lapack, batch
    np.testing.assert_allclose(jax.jit(jnp.linalg.cholesky)(spd), np.linalg.cholesky(spd), atol=1e-4)


@pytest.mark.parametrize("batch", [4, 64])  # LAPACK's kernels, then XLA's ops
def test_cpu_triangular_solves_and_failed_factorisations_match_numpy(batch):
    """Every triangular-solve variant MJX can reach, and NaN for a matrix that is not positive definite."""
    from hsa_mjx.sim import cpu_linalg

    assert cpu_linalg.use_xla_linalg_on_cpu()
    rng = np.random.default_rng(1)
    lower = np.tril(rng.normal(size=(batch, 24, 24))).astype(np.float32) + 5 * np.eye(24, dtype=np.float32)
    b = rng.normal(size=(batch, 24, 3)).astype(np.float32)
    for is_lower, transpose, left in itertools.product((True, False), repeat=3):
        a = lower if is_lower else np.swapaxes(lower, 1, 2)
        rhs = b if left else np.swapaxes(b, 1, 2)
        options = {"left_side": left, "lower": is_lower, "transpose_a": transpose}
        solve = jax.jit(lambda a, r, options=options: jax.lax.linalg.triangular_solve(a, r, **options))
        assert (_lapack_calls(solve.lower(a, rhs)) > 0) == (batch <= cpu_linalg.LAPACK_MAX_BATCH)
        op = np.swapaxes(a, 1, 2) if transpose else a
        expected = (
            np.linalg.solve(op, rhs)
            if left
            else np.swapaxes(np.linalg.solve(np.swapaxes(op, 1, 2), np.swapaxes(rhs, 1, 2)), 1, 2)
        )
        np.testing.assert_allclose(solve(a, rhs), expected, rtol=1e-4, atol=1e-5)
    factor = np.asarray(jax.jit(jnp.linalg.cholesky)(-np.eye(24, dtype=np.float32)[None].repeat(batch, 0)))
    assert np.isnan(factor[:, 0, 0]).all()  # as JAX's own CPU lowering


def _yaw(physics, env):
    """Direction from block A's body origin to block B's, computed from the state's block positions."""
    a, b = np.asarray(physics.xpos)[env.index.block_body, :2]
    return np.arctan2(b[1] - a[1], b[0] - a[0])


def _rotated_about_z(state, env, angle):
    """The reset state with the whole robot turned by ``angle`` about the world z axis (both free blocks)."""
    physics = state.pipeline_state.physics
    qpos = np.asarray(physics.qpos).copy()
    c, s = np.cos(angle), np.sin(angle)
    turn = np.array([np.cos(angle / 2), 0.0, 0.0, np.sin(angle / 2)])
    for adr in env.index.block_qpos:
        x, y = qpos[adr : adr + 2]
        qpos[adr : adr + 2] = c * x - s * y, s * x + c * y
        w, v = turn[0], turn[1:]
        q0, qv = qpos[adr + 3], qpos[adr + 4 : adr + 7]
        qpos[adr + 3 : adr + 7] = np.concatenate([[w * q0 - v @ qv], w * qv + q0 * v + np.cross(v, qv)])
    return state.replace(pipeline_state=state.pipeline_state.replace(physics=physics.replace(qpos=jnp.asarray(qpos))))


def test_optional_observation_entries(jit_single, options_env):
    """sin/cos hinge angles, heading (unit heading, goal direction rotated by -yaw), servo targets and gait clock.

    One env with all four options (one compile): slots 0-15 sin/cos, 16-31 the original's other 16,
    32-35 heading, 36-43 targets, 44-45 clock; sanitised like the rest.
    """
    env, reset, step = options_env
    start = reset(jax.random.PRNGKey(0))
    assert env.observation_size == 46 == start.obs.shape[0]
    np.testing.assert_allclose(start.obs[16:32], jit_single[0](jax.random.PRNGKey(0)).obs[8:], atol=1e-6)
    np.testing.assert_allclose(start.obs[36:], np.r_[np.zeros(8), 0.0, 1.0], atol=1e-6)  # targets 0, phase 0
    action = jnp.linspace(-1.0, 1.0, 8)
    moved = step(step(start, action), action)  # two steps: 0.04 s of a 1 s clock, targets 2 x 0.1785 x a
    angles = np.asarray(moved.pipeline_state.physics.qpos[env.index.joint_qpos])
    assert np.abs(angles).max() > 0.02  # the hinges moved (slots 8-15 hold cosines, not the velocities)
    np.testing.assert_allclose(moved.obs[:16], np.r_[np.sin(angles), np.cos(angles)], atol=1e-5)
    np.testing.assert_allclose(moved.obs[36:44], 2 * env.config.control.max_increment * np.asarray(action), atol=1e-6)
    np.testing.assert_allclose(moved.obs[36:44], moved.pipeline_state.physics.ctrl[env.index.servo_ids], atol=0)
    np.testing.assert_allclose(moved.obs[44:46], [np.sin(2 * np.pi * 0.04), np.cos(2 * np.pi * 0.04)], atol=1e-5)
    turned = step(_rotated_about_z(start, env, 2.0), jnp.zeros(8))
    for state in (start, turned):
        obs, yaw = np.asarray(state.obs), _yaw(state.pipeline_state.physics, env)
        heading, body_goal, world_goal = obs[32:34], obs[34:36], obs[30:32]
        np.testing.assert_allclose(heading, [np.cos(yaw), np.sin(yaw)], atol=1e-5)
        np.testing.assert_allclose([np.linalg.norm(heading), np.linalg.norm(body_goal)], 1.0, atol=1e-5)
        rotation = np.array([[np.cos(yaw), np.sin(yaw)], [-np.sin(yaw), np.cos(yaw)]])  # by -yaw
        np.testing.assert_allclose(body_goal, rotation @ world_goal, atol=1e-5)
    assert yaw == pytest.approx(2.0, abs=0.05)  # the turned robot faces where it was turned
    physics = turned.pipeline_state.physics
    poisoned = turned.replace(
        pipeline_state=turned.pipeline_state.replace(physics=physics.replace(qvel=physics.qvel.at[7].set(jnp.nan)))
    )
    out = step(poisoned, jnp.zeros(8))
    assert float(out.metrics["termination/non_finite"]) == 1.0 and np.all(np.isfinite(out.obs))


def test_reset_at_checkpoint_needs_spiral_goals(env):
    with pytest.raises(ValueError, match="reset_at_checkpoint needs goal.mode 'spiral', got 'random'"):
        env.reset_at_checkpoint(jax.random.PRNGKey(0), 1)
