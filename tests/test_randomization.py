"""Sim-to-real options: per-env physical draws, their effect on the physics, latency, pushes, noise."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import hsa_mjx
from hsa_mjx.randomization_config import RandomizationConfig
from hsa_mjx.task import randomization
from hsa_mjx.task.observation import observation_labels

RANGES = dict(
    friction=(0.5, 1.5),
    block_mass=(0.8, 1.2),
    hsa_stiffness=(0.7, 1.3),
    hsa_damping=(0.9, 1.1),
    servo_gain=(0.8, 1.2),
    servo_force_limit=(0.3, 0.6),
)
# physics on MJX's JAX implementation: friction and block masses randomised (one compile for both tests)
PHYSICS = {
    "randomization__friction": [0.5, 1.5],
    "randomization__block_mass": [1.0, 1.5],
    "termination__max_episode_steps": 1000,
}


def _scales(env, state, **values):
    """``state`` with every env's physical scales replaced by ``values`` (lists over the batch)."""
    task = state.pipeline_state.task
    physics = task.randomization.physics.replace(**{k: jnp.asarray(v, jnp.float32) for k, v in values.items()})
    task = task.replace(randomization=task.randomization.replace(physics=physics))
    return state.replace(pipeline_state=state.pipeline_state.replace(task=task))


def test_draws_lie_in_their_ranges_differ_per_env_and_repeat_from_the_key():
    config = RandomizationConfig(**RANGES)
    keys = jax.random.split(jax.random.PRNGKey(3), 256)
    draws = jax.vmap(lambda k: randomization.draw(k, config))(keys)
    for name, (lo, hi) in RANGES.items():
        values = np.asarray(getattr(draws, name))
        assert values.min() >= lo and values.max() <= hi, name
        assert len(np.unique(values)) == values.size, name  # every env (and block) its own draw
        assert values.max() - values.min() > 0.8 * (hi - lo), name  # spread over the range
    again = jax.vmap(lambda k: randomization.draw(k, config))(keys)
    assert jax.tree.all(jax.tree.map(lambda a, b: bool(jnp.array_equal(a, b)), draws, again))
    fixed = randomization.draw(keys[0], RandomizationConfig(friction=(0.5, 0.5)))
    assert float(fixed.friction) == 0.5 and float(fixed.servo_force_limit) == np.inf


def test_robots_are_drawn_alike_or_by_their_weights():
    keys = jax.random.split(jax.random.PRNGKey(5), 64)
    robots = ("a", "b", "c")
    alike = jax.vmap(lambda k: randomization.draw(k, RandomizationConfig(robots=robots)).robot)(keys)
    weighted = RandomizationConfig(robots=robots, robot_weights=(0.0, 1.0, 0.0))
    only_b = jax.vmap(lambda k: randomization.draw(k, weighted).robot)(keys)
    assert set(np.asarray(alike).tolist()) == {0, 1, 2} and set(np.asarray(only_b).tolist()) == {1}


def test_the_same_key_draws_the_same_episode_on_every_backend():
    keys = jax.random.split(jax.random.PRNGKey(0), 3)
    overrides = {f"randomization__{k}": list(v) for k, v in RANGES.items()}
    realism = {}
    for backend in ("jax", "warp", "c"):
        env = hsa_mjx.make_env("flat", physics__backend=backend, randomization__latency_steps=[0, 2], **overrides)
        draw = jax.jit(
            jax.vmap(lambda key, env=env: env.reset(key).pipeline_state.task.randomization)
        )  # physics pruned
        realism[backend] = jax.device_get(draw(keys))
    for backend in ("warp", "c"):
        same = jax.tree.map(np.array_equal, realism["jax"], realism[backend])
        assert all(jax.tree.leaves(same)), backend
    assert len(set(np.asarray(realism["jax"].physics.friction).tolist())) == 3


def test_model_fields_scale_the_assets_values_and_leave_the_rest():
    env = hsa_mjx.make_env("flat", physics__backend="c", **{f"randomization__{k}": list(v) for k, v in RANGES.items()})
    nominal, mj = env._nominal, env.robot.mj_model
    scales = randomization.PhysicsScales.nominal().replace(
        friction=jnp.float32(0.5),
        servo_gain=jnp.float32(2.0),
        block_mass=jnp.asarray([1.5, 1.0], jnp.float32),
        servo_force_limit=jnp.float32(0.4),
    )
    fields = randomization.model_fields(nominal, scales, env.config.randomization)
    servos_own = {"dof_damping", "dof_frictionloss", "dof_armature"}  # a DC-motor servo's (tests/test_servo.py)
    assert set(fields) == set(randomization.FIELDS) - servos_own
    np.testing.assert_allclose(fields["pair_friction"][:, :2], 0.5 * mj.pair_friction[:, :2], rtol=1e-6)
    np.testing.assert_allclose(fields["pair_friction"][:, 2:], mj.pair_friction[:, 2:], rtol=1e-6)
    block_a, block_b = env.index.block_body
    assert fields["body_mass"][block_a] == pytest.approx(1.5 * mj.body_mass[block_a])
    assert fields["body_mass"][block_b] == pytest.approx(mj.body_mass[block_b])
    servos = env.index.servo_ids
    np.testing.assert_allclose(fields["actuator_gainprm"][servos, 0], 2.0 * mj.actuator_gainprm[servos, 0])
    np.testing.assert_allclose(fields["actuator_biasprm"][servos, 1], 2.0 * mj.actuator_biasprm[servos, 1])
    np.testing.assert_allclose(fields["actuator_forcerange"][servos], [[-0.4, 0.4]] * len(servos), rtol=1e-6)
    assert mj.actuator_forcelimited[servos].all()  # compiled force-limited for the drawn limits
    only = randomization.model_fields(nominal, scales, RandomizationConfig(hsa_damping=(0.5, 2.0)))
    assert set(only) == {"tendon_damping"}  # the unrandomised fields stay the model's own


@pytest.mark.parametrize("scene", ["flat", "mixed"])
def test_each_foot_draws_its_own_friction_and_anisotropy(scene):
    feet = {"foot_friction": (0.5, 1.5), "foot_anisotropy": (0.3, 3.0)}
    config = RandomizationConfig(**feet)
    draws = jax.vmap(lambda k: randomization.draw(k, config))(jax.random.split(jax.random.PRNGKey(5), 64))
    for name, (lo, hi) in feet.items():
        values = np.asarray(getattr(draws, name))
        assert values.shape == (64, 4) and values.min() >= lo and values.max() <= hi
        assert len(np.unique(values)) == values.size  # every foot of every env its own draw
    before = randomization.draw(jax.random.PRNGKey(5), RandomizationConfig(friction=(0.5, 1.5)))
    after = randomization.draw(jax.random.PRNGKey(5), RandomizationConfig(friction=(0.5, 1.5), **feet))
    assert before.friction == after.friction  # the feet's draws leave the other draws as they were
    env = hsa_mjx.make_env(scene, physics__backend="c", **{f"randomization__{k}": list(v) for k, v in feet.items()})
    mj, pairs = env.robot.mj_model, env.index.foot_pairs
    scales = randomization.PhysicsScales.nominal().replace(
        foot_friction=jnp.asarray([0.5, 1.0, 1.0, 2.0], jnp.float32),
        foot_anisotropy=jnp.asarray([1.0, 3.0, 1.0, 1.0], jnp.float32),
    )
    fields = randomization.model_fields(env._nominal, scales, env.config.randomization)
    assert set(fields) == {"pair_friction"}
    lower = np.argmin(mj.pair_friction[pairs, :2], axis=1)  # across the robot on a plane, world Y on terrain
    expected = mj.pair_friction[pairs, :2] * np.asarray([0.5, 1.0, 1.0, 2.0])[:, None]
    expected[1, lower[1]] *= 3.0
    np.testing.assert_allclose(fields["pair_friction"][pairs, :2], expected, rtol=1e-6)
    np.testing.assert_allclose(fields["pair_friction"][pairs, 2:], mj.pair_friction[pairs, 2:], rtol=1e-6)
    with pytest.raises(ValueError, match="randomization.foot_anisotropy"):
        hsa_mjx.make_env("flat", randomization__foot_anisotropy=[0.0, 2.0])


@pytest.fixture(scope="module")
def physics_env():
    """Two envs on MJX's JAX implementation, jitted batch reset and step."""
    env = hsa_mjx.make_env("flat", physics__backend="jax", **PHYSICS)
    return env, jax.jit(jax.vmap(env.reset)), jax.jit(jax.vmap(env.step))


def _run(step, state, steps: int, action: jax.Array | None = None):
    """``steps`` steps with one action for both envs (zeros: the servos hold); every step's state."""
    action = jnp.zeros((2, 8)) if action is None else action
    states = []
    for _ in range(steps):
        state = step(state, action)
        states.append(state)
    return states


def test_heavier_blocks_fall_the_same_but_press_harder(physics_env):
    env, reset, step = physics_env
    state = reset(jax.random.split(jax.random.PRNGKey(1), 2))
    state = _scales(env, state, block_mass=[[1.0, 1.0], [1.5, 1.5]], friction=[1.0, 1.0])
    states = _run(step, state, 40)
    blocks = env.index.block_body
    fall = [np.asarray(s.pipeline_state.physics.xpos[:, blocks, 2]) for s in states[:3]]  # before touching down
    for heights in fall:
        np.testing.assert_allclose(heights[0], heights[1], atol=2e-4)
    # at rest (40 steps = 0.8 s later): the floor carries the weight, about 1.5x for the heavier blocks
    normal = [
        float(np.abs(np.asarray(states[-1].pipeline_state.physics.sensordata[e])[env.index.foot_sensors[..., 0]]).sum())
        for e in range(2)
    ]
    assert normal[1] > 1.2 * normal[0] > 0


def _slide(env, reset, step, **alike) -> np.ndarray:
    """How far each of two envs (floor friction x0.5 and x1.5, ``alike`` scales the same) slides after
    both are shoved alike."""
    state = reset(jax.random.split(jax.random.PRNGKey(1), 2))
    state = _run(step, _scales(env, state, friction=[0.5, 1.5], **alike), 30)[-1]
    data = state.pipeline_state.physics
    shove = jax.vmap(lambda qvel: randomization.pushed(qvel, jnp.asarray([0.4, 0.0, 0.0]), env.index.block_qvel))(
        data.qvel
    )
    state = state.replace(pipeline_state=state.pipeline_state.replace(physics=data.replace(qvel=shove)))
    start = np.asarray(state.pipeline_state.physics.xpos[:, env.index.block_body, 0]).mean(axis=1)
    end = np.asarray(_run(step, state, 15)[-1].pipeline_state.physics.xpos[:, env.index.block_body, 0]).mean(axis=1)
    return end - start


def test_a_slicker_floor_slides_further(physics_env):
    slide = _slide(*physics_env, block_mass=[[1.0, 1.0]] * 2)
    assert slide[0] > 1.3 * slide[1] > 0, slide


def test_warp_batches_the_randomised_fields_per_world():
    env = hsa_mjx.make_env(  # the flat task's physics: Warp's kernels compiled for tests/test_backend.py
        "flat",
        physics__backend="warp",
        num_envs=2,
        randomization__friction=[0.5, 1.5],
        physics__integrator="implicitfast",
        physics__iterations=4,
        physics__ls_iterations=8,
    )
    slide = _slide(env, jax.jit(jax.vmap(env.reset)), jax.jit(jax.vmap(env.step)))
    assert slide[0] > 1.3 * slide[1] > 0, slide  # each world its own friction (0.073 and 0.034 m on a CPU)


def test_latency_delays_the_action_by_the_set_steps():
    steps = {}
    for latency in (0, 2):
        env = hsa_mjx.make_env("flat", physics__backend="c", randomization__latency_steps=[latency, latency])
        state = env.reset(jax.random.PRNGKey(0))
        step, moved = jax.jit(env.step), []
        for _ in range(4):
            state = step(state, jnp.ones(8))
            moved.append(float(jnp.abs(state.pipeline_state.physics.ctrl[env.index.servo_ids]).max()) > 0)
        steps[latency] = moved.index(True)
    assert steps == {0: 0, 2: 2}


def test_pushes_come_at_their_interval_and_add_horizontal_speed():
    config = RandomizationConfig(push_interval_s=(0.1, 0.1), push_speed=0.3)
    realism = randomization.reset_state(jax.random.PRNGKey(0), config, 8, dt=0.02)
    assert int(realism.next_push) == 5
    qvel = jnp.zeros(20)
    block_qvel = np.array([0, 6])
    early, _ = randomization.apply_push(jax.random.PRNGKey(1), realism, qvel, jnp.int32(4), config, 0.02, block_qvel)
    assert not np.any(np.asarray(early))
    late, after = randomization.apply_push(jax.random.PRNGKey(1), realism, qvel, jnp.int32(5), config, 0.02, block_qvel)
    late = np.asarray(late)
    np.testing.assert_array_equal(late[0:3], late[6:9])  # both blocks alike
    assert 0 < np.hypot(*late[:2]) <= 0.3 and late[2] == 0 and not np.any(late[3:6])
    assert int(after.next_push) == 10


def test_observation_noise_touches_only_its_groups():
    env = hsa_mjx.make_env(
        "flat",
        physics__backend="c",
        observation__noise__position=0.05,
        observation__noise__hinge_velocities=0.2,
        observation__servo_targets=True,
    )
    labels = observation_labels(env.config.observation)
    scales = randomization.noise_scales(labels, env.config.observation.noise)
    noisy = {labels[i] for i in np.flatnonzero(scales)}
    assert noisy == {"robot_x", "robot_y"} | {f"hinge_velocity_{i}" for i in range(8)}
    clean_env = hsa_mjx.make_env("flat", physics__backend="c", observation__servo_targets=True)
    key = jax.random.PRNGKey(0)
    difference = np.asarray(env.reset(key).obs - clean_env.reset(key).obs)
    assert np.all(np.abs(difference) <= scales + 1e-6) and np.abs(difference[scales > 0]).min() > 0
    assert not np.any(difference[scales == 0])


@pytest.mark.parametrize(
    "key, value, message",
    [
        ("randomization__friction", [0.0, 1.0], "randomization.friction' must be a range"),
        ("randomization__block_mass", [1.2, 0.8], "randomization.block_mass' must be a range"),
        ("randomization__latency_steps", [-1, 2], "randomization.latency_steps' must be a range"),
        ("randomization__push_speed", 0.2, "push_interval_s' must be > 0 s when push_speed > 0"),
        ("observation__noise__goal", -0.1, "observation.noise.goal' must be >= 0"),
        ("randomization__mass", [1, 1], "valid keys: \\['block_mass'"),
        ("randomization__robot_weights", [1.0], "robot_weights' must give one weight >= 0 per profile"),
    ],
)
def test_bad_randomization_values_are_refused(key, value, message):
    with pytest.raises(ValueError, match=message):
        hsa_mjx.build_config("flat", **{key: value})


def test_a_curriculum_level_moves_the_draws_toward_the_nominal_model():
    config = RandomizationConfig(**RANGES, latency_steps=(2, 2), push_interval_s=(1.0, 1.0), push_speed=0.3)
    key = jax.random.PRNGKey(4)
    full, same = (randomization.reset_state(key, config, 8, 0.02, s) for s in (1.0, jnp.float32(1.0)))
    assert jax.tree.all(jax.tree.map(lambda a, b: bool(jnp.array_equal(a, b)), full, same))
    plain = randomization.reset_state(key, config, 8, 0.02)
    assert jax.tree.all(jax.tree.map(lambda a, b: bool(jnp.array_equal(a, b)), full, plain))  # 1: the ranges as set
    none = randomization.reset_state(key, config, 8, 0.02, 0.0)
    assert float(none.physics.friction) == 1.0 and np.all(np.asarray(none.physics.block_mass) == 1.0)
    assert float(none.physics.servo_force_limit) == np.inf and int(none.latency) == 0 and float(none.push_scale) == 0
    half = randomization.reset_state(key, config, 8, 0.02, 0.5)
    np.testing.assert_allclose(float(half.physics.friction) - 1, 0.5 * (float(full.physics.friction) - 1), rtol=1e-5)
    np.testing.assert_allclose(float(half.physics.servo_force_limit), 2 * float(full.physics.servo_force_limit))
    assert int(half.latency) == 1


def test_the_randomization_curriculum_widens_only_while_episodes_succeed():
    from hsa_mjx.curricula import randomization_curriculum as rc
    from hsa_mjx.curricula.state import CurriculumRules, EpisodeEnds

    config = rc.RandomizationCurriculumConfig(enabled=True, start=0.2, step_up=0.3, step_down=0.5)
    level = jnp.asarray([0.2, 0.2, 0.9, 0.6, 0.6], jnp.float32)
    done = jnp.asarray([True, True, True, True, False])
    success = jnp.asarray([True, False, True, False, True])
    np.testing.assert_allclose(rc.update(level, done, success, config), [0.5, 0.2, 1.0, 0.2, 0.6], atol=1e-6)
    env = hsa_mjx.build_config("flat", randomization__friction=[0.5, 1.5])
    rules = CurriculumRules(env, randomization=config)
    state = rules.init(jax.random.split(jax.random.PRNGKey(0), 3))
    np.testing.assert_allclose(rules.params(state).randomization_scale, [0.2] * 3)
    ends = EpisodeEnds(done=jnp.ones(3), success=jnp.asarray([1.0, 1.0, 0.0]), progress=jnp.zeros(3))
    state = rules.after_step(state, ends, jax.random.split(jax.random.PRNGKey(1), 3))
    np.testing.assert_allclose(rules.params(state).randomization_scale, [0.5, 0.5, 0.2], atol=1e-6)
    assert rc.summarize(jax.device_get(rules.drain(state)[1])) == pytest.approx(
        {"randomization_curriculum/mean_level": 0.4, "randomization_curriculum/full_share": 0.0}
    )
    off = CurriculumRules(env)  # without the curriculum every env draws from the full ranges
    np.testing.assert_array_equal(
        off.params(off.init(jax.random.split(jax.random.PRNGKey(0), 2))).randomization_scale, 1
    )
    with pytest.raises(ValueError, match="needs ranges to widen"):
        rc.validate(config, randomizes=False)
    with pytest.raises(ValueError, match="step_up must be in"):
        rc.validate(rc.RandomizationCurriculumConfig(step_up=0.0), randomizes=True)


def test_the_privileged_critic_sees_the_episodes_true_model():
    from hsa_mjx.task import privileged
    from hsa_mjx.task.env import HSAEnv

    config = hsa_mjx.build_config(
        "flat",
        physics__backend="c",
        randomization__servo_force_limit=[0.5, 2.0],
        **{f"randomization__{k}": list(v) for k, v in RANGES.items() if k != "servo_force_limit"},
        randomization__latency_steps=[0, 2],
    )
    env = HSAEnv(config, privileged=True)
    state = env.reset(jax.random.PRNGKey(5))
    names = privileged.labels(config.observation, config.randomization)
    assert env.privileged_size == len(names) and names[-8:] == randomization.TRUE_MODEL_LABELS
    seen = dict(zip(names, np.asarray(state.info["privileged_obs"])))
    drawn = state.pipeline_state.task.randomization
    assert seen["true_friction"] == pytest.approx(float(drawn.physics.friction))
    assert seen["true_inverse_torque_limit"] == pytest.approx(1 / float(drawn.physics.servo_force_limit))
    assert seen["true_latency_steps"] == int(drawn.latency)
    assert privileged.size(config.observation) == len(names) - 8  # nothing drawn: no model values
    feet = hsa_mjx.build_config("flat", physics__backend="c", randomization__foot_friction=[0.5, 1.5])
    env = HSAEnv(feet, privileged=True)
    names = privileged.labels(feet.observation, feet.randomization)
    seen = dict(zip(names, np.asarray(env.reset(jax.random.PRNGKey(6)).info["privileged_obs"])))
    assert env.privileged_size == len(names) and names[-8:] == randomization.FOOT_MODEL_LABELS
    assert 0.5 <= seen["true_foot_friction_3"] <= 1.5 and seen["true_foot_anisotropy_0"] == 1.0


def test_randomization_levels_round_trip_through_a_checkpoint(tmp_path):
    """What the trainer saves is what a resume restores; a checkpoint without them starts afresh."""
    from hsa_mjx.curricula.state import CurriculumRules, host_levels
    from train import config as train_config
    from train.run import checkpoint
    from train.run.saved import payload, restore_levels

    config = train_config.load("configs/train_flat_dr.yaml")
    rules = CurriculumRules(config.env, randomization=config.randomization_curriculum)
    state = rules.init(jax.random.split(jax.random.PRNGKey(0), 8))
    state = state.replace(randomization=jnp.linspace(0.25, 1.0, 8, dtype=jnp.float32))
    host = host_levels([state])
    assert host["randomization"].shape == (8,) and set(host) >= {"terrain_type", "level"}
    path = checkpoint.save(
        tmp_path,
        5,
        payload({"w": np.zeros(2)}, {"c": np.zeros(1)}, np.zeros(2, np.uint32), None, host["randomization"]),
        train_config.to_dict(config),
        extra={"randomization_envs": 8},
    )
    meta = {**checkpoint.read_meta(path), "path": path}
    restored = restore_levels(config, meta, 8)
    assert restored.terrain is None
    np.testing.assert_array_equal(np.asarray(restored.randomization), np.asarray(state.randomization))
    resumed = rules.init(jax.random.split(jax.random.PRNGKey(1), 8), restored=restored)
    np.testing.assert_array_equal(np.asarray(rules.params(resumed).randomization_scale), host["randomization"])
    more = restore_levels(config, meta, 32).randomization
    assert more.shape == (32,) and set(np.asarray(more).tolist()) <= set(host["randomization"].tolist())
    assert restore_levels(config, {**meta, "randomization_envs": None}, 8) is None  # an older checkpoint
