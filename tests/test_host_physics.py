"""One env on a CPU with the physics substeps in C MuJoCo: the same trajectories as MJX within a bound."""

from __future__ import annotations

import functools

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import hsa_mjx
from hsa_mjx.sim.host_physics import HostPhysics
from hsa_mjx.terrain import height_scan

STEPS = 40
# C MuJoCo (float64) against MJX (float32), same settings, same actions from the same reset, 40 steps:
# measured max |dqpos| 6e-5 rad and per-step reward differences of 2e-4 on the plane; on a craters
# tile 0.02 rad and 0.08 (C MuJoCo's heightfield collision, the original's, generates other contacts
# than MJX's: the 40-step reward sums were 3.29 with MJX and 2.20 with C).
QPOS_TOL = {"flat": 2e-3, "craters": 0.06}
REWARD_TOL = {"flat": 1e-2, "craters": 0.15}
# the observation carries the height scan, so both physics paths' scans are checked on every step's state
SCAN = {"observation.heading": True, "observation.height_scan.enabled": True}
REST = 0.14  # block origins above level ground at rest: the scan's zero


def _scan(env: hsa_mjx.HSAEnv, state) -> np.ndarray:
    """The scan values of a state's observation."""
    return np.asarray(state.obs)[-height_scan.num_points(env.config.observation.height_scan) :]


def _ray_scan(env: hsa_mjx.HSAEnv, state) -> np.ndarray:
    """The scan computed independently: C MuJoCo ray casts onto the floor the state's physics stands on."""
    import mujoco

    physics, model = state.pipeline_state.physics, env.robot.mj_model
    data = mujoco.MjData(model)
    data.mocap_pos[:] = np.asarray(physics.mocap_pos)  # the env's tile under the origin (terrain scene)
    data.qpos[env.index.block_z] = 10.0  # the robot out of the rays' way
    mujoco.mj_kinematics(model, data)
    blocks = np.asarray(physics.xpos)[env.index.block_body]
    position, axis = blocks[:, :2].mean(axis=0), blocks[1, :2] - blocks[0, :2]
    points = np.asarray(
        height_scan.world_points(
            jnp.asarray(height_scan.local_points(env.config.observation.height_scan)),
            jnp.asarray(position),
            jnp.asarray(axis / np.linalg.norm(axis)),
        )
    )
    geom = np.zeros(1, np.int32)
    ground = np.array(
        [
            3.0 - mujoco.mj_ray(model, data, np.array([x, y, 3.0]), np.array([0.0, 0.0, -1.0]), None, 1, -1, geom)
            for x, y in points
        ]
    )
    return np.clip(ground - (blocks[:, 2].mean() - REST), -1.0, 1.0)


def _both(env: hsa_mjx.HSAEnv, key: int = 0) -> tuple[list, list]:
    """States of the MJX step and of the C MuJoCo step over the same random actions."""
    host = jax.jit(functools.partial(env.step_with, HostPhysics(env.robot.mj_model, env.index)))
    step = jax.jit(env.step)
    a = b = jax.jit(env.reset)(jax.random.PRNGKey(key))
    actions = np.random.default_rng(key).uniform(-1, 1, (STEPS, 8)).astype(np.float32)
    mjx_states, host_states = [], []
    for action in actions:
        a, b = step(a, action), host(b, action)
        mjx_states.append(a)
        host_states.append(b)
    return mjx_states, host_states


@pytest.mark.parametrize("preset", ["flat", "craters"])
def test_host_physics_follows_mjx_within_the_bound(preset):
    env = hsa_mjx.make_env(preset, physics__backend="jax", **SCAN)
    mjx_states, host_states = _both(env)
    worst = max(
        float(np.abs(np.asarray(a.pipeline_state.physics.qpos) - np.asarray(b.pipeline_state.physics.qpos)).max())
        for a, b in zip(mjx_states, host_states)
    )
    assert worst < QPOS_TOL[preset], worst
    rewards = np.array([[float(a.reward), float(b.reward)] for a, b in zip(mjx_states, host_states)])
    assert np.abs(rewards[:, 0] - rewards[:, 1]).max() < REWARD_TOL[preset]
    assert np.abs(rewards).max() > 0.01  # the comparison saw rewards, not zeros
    a, b = mjx_states[-1], host_states[-1]
    if preset == "flat":  # on terrain the joint velocities in the observation differ by more (see above)
        np.testing.assert_allclose(np.asarray(b.obs), np.asarray(a.obs), atol=0.05)
    assert float(b.pipeline_state.physics.time) == pytest.approx(STEPS * env.dt, rel=1e-5)
    for state in (a, b):  # each path's scan is the terrain under its own robot, as C MuJoCo collides with it
        np.testing.assert_allclose(_scan(env, state), _ray_scan(env, state), atol=1e-4)
    if preset == "craters":
        assert np.ptp(_scan(env, b)) > 0.01  # the scan saw relief
    np.testing.assert_allclose(_scan(env, a), _scan(env, b), atol=0.03)  # the two robots stand about alike


def test_state_crosses_to_c_mujoco_and_back_in_one_vector_unchanged():
    """The state vector's order is C MuJoCo's own (``mj_setState``): an idle call returns every state
    field it was given, bit for bit, and the C data holds them."""
    env = hsa_mjx.make_env("flat", physics__backend="jax")
    host = HostPhysics(env.robot.mj_model, env.index)
    data = jax.jit(env.reset)(jax.random.PRNGKey(1)).pipeline_state.physics
    rng = np.random.default_rng(0)
    data = data.replace(
        **{
            n: getattr(data, n) + rng.normal(size=getattr(data, n).shape).astype(np.float32)
            for n in ("qpos", "qvel", "qacc_warmstart", "ctrl", "time")
        }
    )
    targets = jnp.zeros((env.config.control.frame_skip, 8))
    out = host.run(True, host.layout(targets, {}), np.asarray(host.inputs(data, targets, {})))
    back, _ = host.outputs(data, jnp.asarray(out))
    for name in ("qpos", "qvel", "qacc_warmstart", "ctrl", "time"):
        np.testing.assert_array_equal(np.asarray(getattr(back, name)), np.asarray(getattr(data, name)), err_msg=name)
        np.testing.assert_allclose(getattr(host.data, name), np.asarray(getattr(data, name)), rtol=1e-7)
    np.testing.assert_array_equal(host.data.mocap_pos, np.asarray(data.mocap_pos))


def test_model_fields_reach_the_c_model_whatever_order_their_dict_has():
    """The fields' layout and vector follow their names, so a layout taken from a dict that went through
    a pytree (keys sorted, as the Gymnasium env's halves get it) still writes each into its own field."""
    env = hsa_mjx.make_env("flat", physics__backend="jax")
    host = HostPhysics(env.robot.mj_model, env.index)
    data = jax.jit(env.reset)(jax.random.PRNGKey(1)).pipeline_state.physics
    model = env.robot.mj_model
    fields = {"body_mass": model.body_mass * 1.3, "body_inertia": model.body_inertia * 0.7}  # unsorted
    targets = jnp.zeros((env.config.control.frame_skip, 8))
    layout = host.layout(targets, jax.eval_shape(lambda f: f, fields))
    host.run(True, layout, np.asarray(host.inputs(data, targets, fields)))
    np.testing.assert_allclose(host.model.body_mass, model.body_mass * 1.3, rtol=1e-6)
    np.testing.assert_allclose(host.model.body_inertia, model.body_inertia * 0.7, rtol=1e-6)


def test_a_diverging_c_state_terminates_as_non_finite():
    env = hsa_mjx.make_env("flat", physics__backend="jax")
    host = jax.jit(functools.partial(env.step_with, HostPhysics(env.robot.mj_model, env.index)))
    state = jax.jit(env.reset)(jax.random.PRNGKey(0))
    physics = state.pipeline_state.physics
    bad = state.replace(
        pipeline_state=state.pipeline_state.replace(physics=physics.replace(qvel=physics.qvel.at[0].set(jnp.nan)))
    )
    out = host(bad, jnp.zeros(8))
    assert float(out.metrics["termination/non_finite"]) == 1.0 and float(out.done) == 1.0
    assert np.all(np.isfinite(np.asarray(out.obs))) and np.isfinite(float(out.reward))


def test_gymnasium_env_uses_c_physics_on_a_cpu_unless_asked_not_to():
    fast = gymnasium.make("hsa_mjx/HSA-v0")
    plain = gymnasium.make("hsa_mjx/HSA-v0", physics__backend="jax")
    assert fast.unwrapped.env.physics_backend == "c" and plain.unwrapped.env.physics_backend == "jax"
    obs_fast, _ = fast.reset(seed=3)
    obs_plain, _ = plain.reset(seed=3)
    np.testing.assert_array_equal(obs_fast, obs_plain)
    action = np.full(8, 0.5, np.float32)
    for _ in range(5):
        obs_fast, *_ = fast.step(action)
        obs_plain, *_ = plain.step(action)
    np.testing.assert_allclose(obs_fast, obs_plain, atol=1e-2)


def test_c_backend_steps_a_batch_in_c_mujoco_like_step_with():
    """``physics.backend: c`` is the env's own step: each env of a vmapped batch runs HostPhysics."""
    env_c = hsa_mjx.make_env("flat", physics__backend="c")
    env_jax = hsa_mjx.make_env("flat", physics__backend="jax")
    assert env_c.physics_backend == "c" and env_jax.physics_backend == "jax"
    keys, actions = jax.random.split(jax.random.PRNGKey(5), 2), jnp.full((2, 8), 0.5)
    own = jax.jit(jax.vmap(env_c.step))(jax.jit(jax.vmap(env_c.reset))(keys), actions)
    host = HostPhysics(env_jax.robot.mj_model, env_jax.index)
    via = jax.jit(jax.vmap(functools.partial(env_jax.step_with, host)))(jax.jit(jax.vmap(env_jax.reset))(keys), actions)
    np.testing.assert_array_equal(np.asarray(own.obs), np.asarray(via.obs))
    np.testing.assert_array_equal(np.asarray(own.reward), np.asarray(via.reward))


def test_ended_episodes_run_no_c_substeps_and_play_the_same():
    """In a rollout on C MuJoCo, an episode that has ended runs no substeps (its state is frozen): the
    traces are the ones of a rollout that steps every episode to the end."""
    from train.episodes import rollout

    env = hsa_mjx.make_env("flat", physics__backend="c", max_episode_steps=3)
    host, played = env.host_physics, []
    run = host.run
    host.run = lambda idle, *args: played.append(not idle) or run(idle, *args)
    every = HostPhysics(env.robot.mj_model, env.index)
    keys, goals = jax.random.split(jax.random.PRNGKey(2), 2), jnp.array([1.5, 1.8])
    policy = lambda obs, key: (jnp.full(8, 0.5), {})  # noqa: E731
    skipped = rollout.rollout(env, policy, keys, goals, 5)
    stepped = rollout.rollout(env, policy, keys, goals, 5, simulate=lambda d, t, f: every(d, t, f))
    assert sum(played) == 2 * 3 and len(played) == 2 * 5  # two episodes of three steps, in five
    for name in ("xy", "qpos", "done", "alive", "distance"):
        np.testing.assert_array_equal(np.asarray(skipped[name]), np.asarray(stepped[name]), err_msg=name)
