"""The DC-motor servo model: its law, gear play, encoder, config and robot profiles, and its torques on the
JAX, Warp and C physics (the same trajectories within the backends' bounds)."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_backend import BLOCK_TOL as WARP_BLOCK_TOL
from test_backend import QPOS_TOL as WARP_QPOS_TOL

import hsa_mjx
from hsa_mjx.deploy.perturbation import ModelPerturbation, perturbed_model
from hsa_mjx.robots import profile_names, profile_servo
from hsa_mjx.servo_config import ServoConfig, resolve_servo
from hsa_mjx.sim import servo
from hsa_mjx.sim.host_physics import HostPhysics
from hsa_mjx.sim.model import load_robot
from hsa_mjx.task import randomization

ENVS = 4
# the settings of tests/test_backend.py's Warp rollouts (their kernels compiled once for the suite)
PHYSICS = {"physics.integrator": "implicitfast", "physics.iterations": 8, "physics.ls_iterations": 8}
# envs that each draw one of two profiles' servos: a position and a continuous-rotation servo, both with
# rotor inertia, friction, damping, gear play and an encoder (the first profile's servo the env's own)
DRAWN = ["xl330_m288", "dfr05sr"]
# actuator_force is the torque at a substep's start; the law is checked against the speed after it
TORQUE_TOL = 0.03  # share of the stall torque
# float32 MJX against float64 C over 20 steps in which the joints turn about 2 rad under full drive: the
# loop's thresholds (encoder counts, gear play, friction's stick) part them by up to 5 mm of 2 rad (0.3 %);
# without them 2 mm, the bound of tests/test_host_physics.py
HOST_QPOS_TOL = 6e-3


def _actions() -> jax.Array:
    """Targets run ahead of the joints (full drive, the torque-speed line), then an alternating gait."""
    ahead = np.ones((8, ENVS, 8), np.float32)
    t = np.arange(12)[:, None, None] * 2 * np.pi / 12
    gait = np.broadcast_to(np.sin(t + np.arange(8) * np.pi / 4), (12, ENVS, 8)).astype(np.float32)
    return jnp.asarray(np.concatenate([ahead, gait]))


def _rollout(backend: str) -> dict:
    """Per step: the drives' ctrl and torque, the position actuators' torque, joint speeds, qpos."""
    overrides = {**PHYSICS, "physics.backend": backend, "randomization.robots": DRAWN}
    env = hsa_mjx.make_env("flat", num_envs=ENVS, robot=DRAWN[0], **overrides)
    step = jax.vmap(env.step)
    if backend == "c":
        step = jax.vmap(functools.partial(env.step_with, HostPhysics(env.robot.mj_model, env.index, env.motors)))
    state = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(1), ENVS))
    scales = state.pipeline_state.task.randomization.physics
    fields = jax.vmap(lambda s: randomization.model_fields(env._nominal, s, env.config.randomization))(scales)
    step, idx, rows = jax.jit(step), env.index, []
    for action in _actions():
        state = step(state, action)
        d = jax.device_get(state.pipeline_state.physics)
        rows.append(
            (d.ctrl[:, idx.drive_ids], d.actuator_force[:, idx.drive_ids], d.actuator_force[:, idx.servo_ids],
             d.qvel[:, idx.joint_qvel], d.qpos)
        )  # fmt: skip
    drive, force, springs, speed, qpos = (np.stack(x) for x in zip(*rows))
    drawn = np.asarray(scales.robot)
    return {"env": env, "drawn": drawn, "fields": jax.device_get(fields), "drive": drive, "force": force,
            "springs": springs, "speed": speed, "qpos": qpos, "done": np.asarray(state.done)}  # fmt: skip


@pytest.fixture(scope="module")
def rollouts():
    return {name: _rollout(name) for name in ("jax", "c", "warp")}


def test_the_law_limits_the_torque_and_follows_the_torque_speed_line():
    params = resolve_servo(profile_servo("st3215"))
    drive, speed = np.meshgrid(np.linspace(-1, 1, 41), np.linspace(-2, 2, 41) * params.no_load_speed)
    torque = np.asarray(servo.torque(params, drive, speed, xp=np))
    assert np.abs(torque).max() == pytest.approx(params.stall_torque) and np.abs(torque).max() <= params.stall_torque
    w = np.linspace(0, 1, 11) * params.no_load_speed  # full drive: stall torque at rest, none at no-load speed
    line = params.stall_torque * (1 - w / params.no_load_speed)
    np.testing.assert_allclose(servo.torque(params, np.ones_like(w), w, xp=np), line, atol=1e-12)
    # the proportional drive saturates at stall_torque / kp of error beyond the dead band
    free = ServoConfig(model="position", stall_torque=1.0, no_load_speed=5.0, kp=10.0)
    errors = np.array([0.0, 0.05, 0.1, 1.0, -1.0])
    np.testing.assert_allclose(servo.drive(resolve_servo(free), errors, 0.0, xp=np), [0.0, 0.5, 1.0, 1.0, -1.0])


def test_dead_bands_encoders_and_the_supply_voltage():
    position = resolve_servo(profile_servo("st3215"))
    inside, outside = 0.9 * position.deadband, position.deadband + 0.01
    assert servo.drive(position, inside, 0.0, xp=np) == 0.0 and servo.drive(position, -inside, 0.0, xp=np) == 0.0
    assert servo.drive(position, outside, 0.0, xp=np) == pytest.approx(position.kp * 0.01 / position.stall_torque)
    continuous = resolve_servo(profile_servo("dfr05sr"))
    step = continuous.encoder_resolution
    small = 0.01 * continuous.no_load_speed / continuous.speed_gain  # asks for 1 % of full speed: in its dead band
    assert servo.drive(continuous, 0.0, -small, xp=np) == 0.0
    # the loop reads whole encoder counts: an angle 0.4 count off reads as the count
    assert servo.drive(continuous, 0.0, 0.4 * step, xp=np) == 0.0 and servo.drive(continuous, 1.0, 0.0, xp=jnp) == 1.0
    np.testing.assert_allclose(servo.read_angle(continuous, np.array([0.6, -1.4]) * step, xp=np), [step, -step])
    # figures given at 5 V, supplied 6 V: stall torque and no-load speed x1.2, the loop gain with them
    at_six = resolve_servo(
        ServoConfig(model="position", stall_torque=0.5, no_load_speed=10.0, voltage=6.0, rated_voltage=5.0)
    )
    assert (at_six.stall_torque, at_six.no_load_speed) == pytest.approx((0.6, 12.0))


def test_gear_play_drives_nothing_until_the_motor_crosses_it():
    params = resolve_servo(profile_servo("xl330_m288"))
    half, dt, speed = params.backlash / 2, 1e-4, 0.3
    # the motor in the middle of the gap: it turns at its no-load speed, the joint gets no torque
    drive, motor = servo.through_play(params, 1.0, 0.0, 0.0, speed, dt, xp=np)
    assert motor == pytest.approx(params.no_load_speed * dt) and motor < half
    assert servo.torque(params, drive, speed, xp=np) == pytest.approx(0.0, abs=1e-12)
    # at the gap's edge the gears mesh: the drive goes through and the motor rides the joint
    drive, motor = servo.through_play(params, 1.0, half, 0.0, speed, dt, xp=np)
    assert drive == 1.0 and motor == pytest.approx(half)
    # the joint pushed back by its load drags the motor side along
    assert servo.through_play(params, 0.0, 0.0, 1.0, speed, dt, xp=np)[1] == pytest.approx(1.0 - half)


def test_bad_servo_configs_are_refused():
    bad = {
        "servo.model": {"servo.model": "stepper"},
        "servo.kp": {"servo.kp": -1.0, "servo.model": "position"},
        "need servo.model": {"servo.stall_torque": 1.0},
        "servo.stall_torque": {"servo.model": "position", "servo.no_load_speed": 5.0},
        "share of full command": {"robot": "dfr05sr", "servo.deadband": 1.5},
        "servo.rated_voltage": {"robot": "dfr05sr", "servo.rated_voltage": 0.0},
        "randomization.servo_gain": {"robot": "xl330_m288", "randomization.servo_gain": [0.5, 1.5]},
        "draw DC-motor servos": {"randomization.robots": ["xl330_m288"]},
        "has spring servos": {"robot": "xl330_m288", "randomization.robots": ["original"]},
        "needs servo.friction": {"robot": "xl330_m288", "servo.friction": 0.0, "randomization.robots": ["dfr05sr"]},
    }
    for message, overrides in bad.items():
        with pytest.raises(ValueError, match=message):
            hsa_mjx.config.with_overrides(hsa_mjx.get_preset("flat"), **overrides)
    robot = load_robot(hsa_mjx.config.with_overrides(hsa_mjx.get_preset("flat"), robot="xl330_m288"))
    with pytest.raises(ValueError, match="DC motors"):  # the deployment loop's perturbed robot: the same rule
        perturbed_model(robot.mj_model, robot.index, ModelPerturbation(servo_torque_limit=0.5))


def test_rotor_inertia_keeps_a_stiff_servos_first_full_command_within_the_acceleration_rule():
    """A 2.5 N m servo on the light HSA end: without rotor inertia its first full command accelerates the
    joint past the original's acceleration rule; the profile's rotor inertia (seen through the gears) holds it."""
    stiff = {"physics.backend": "c", "servo.model": "position", "servo.stall_torque": 2.5, "servo.no_load_speed": 5.76}
    ended = {}
    for armature in (0.0, profile_servo("st3215").armature):  # nothing else of a real servo: no friction
        env = hsa_mjx.make_env("flat", **stiff, **{"servo.armature": armature})
        step = functools.partial(env.step_with, HostPhysics(env.robot.mj_model, env.index, env.motors))
        state = jax.jit(step)(jax.jit(env.reset)(jax.random.PRNGKey(0)), jnp.ones(8))
        ended[armature] = bool(state.metrics["termination/qacc_limit"])
    assert list(ended.values()) == [True, False]


@pytest.mark.parametrize("backend", ["jax", "c", "warp"])
def test_each_env_drives_its_drawn_servo_within_its_stall_torque_on_its_curve(rollouts, backend):
    run = rollouts[backend]
    assert run["env"].physics_backend == backend and run["env"].motors.model == servo.MIXED
    assert set(run["drawn"].tolist()) == {0, 1} and not run["done"].any()  # both profiles, nothing ended
    stall = np.asarray([profile_servo(DRAWN[k]).stall_torque for k in run["drawn"]])
    assert np.all(np.abs(run["force"]).max(axis=(0, 2)) <= stall * (1 + 1e-5))
    assert np.all(run["springs"] == 0.0)  # the position actuators only hold the targets
    assert (np.abs(run["drive"]) == 1.0).mean() > 0.2 and np.abs(run["drive"]).max() <= 1.0
    for k, name in enumerate(run["drawn"]):  # each env's torque: its own profile's law at its speed
        params = resolve_servo(profile_servo(DRAWN[name]))
        law = np.asarray(servo.torque(params, run["drive"][:, k], run["speed"][:, k], xp=np))
        assert np.abs(run["force"][:, k] - law).max() <= TORQUE_TOL * params.stall_torque
        assert np.abs(run["speed"][:, k]).max() > 0.2 * params.no_load_speed  # the joints did move


def test_the_drawn_servo_fields_are_the_profiles_own(rollouts):
    run = rollouts["jax"]
    env, ids, hinges = run["env"], run["env"].index.drive_ids, run["env"].index.joint_qvel
    names = ("actuator_gainprm", "actuator_biasprm", "actuator_forcerange", "dof_damping", "dof_frictionloss")
    for k, drawn in enumerate(run["drawn"]):  # the fields of the env built with that profile's servo
        own = load_robot(hsa_mjx.config.with_overrides(env.config, robot=DRAWN[drawn], randomization__robots=[]))
        for name in names:
            where = hinges if name.startswith("dof") else ids
            expected = getattr(own.mj_model, name)[where]
            np.testing.assert_allclose(run["fields"][name][k][where], expected, rtol=1e-6, err_msg=name)
    # the privileged critic sees the drawn profile: one slot per profile, the drawn one set
    state = env.reset(jax.random.PRNGKey(3)).pipeline_state.task.randomization
    true = randomization.true_model(state, env.config.randomization)
    assert true.shape == (8 + len(DRAWN),) and float(true[8 + int(state.physics.robot)]) == 1.0


def test_the_same_servos_give_the_same_trajectories_on_every_backend(rollouts):
    jax_run, idx = rollouts["jax"], rollouts["jax"]["env"].index
    assert np.abs(rollouts["c"]["qpos"] - jax_run["qpos"]).max() <= HOST_QPOS_TOL
    warp_gap = np.abs(rollouts["warp"]["qpos"] - jax_run["qpos"])
    assert warp_gap[..., idx.joint_qpos].max() <= WARP_QPOS_TOL
    assert warp_gap[..., idx.block_qpos[:, None] + np.arange(3)].max() <= WARP_BLOCK_TOL


def test_servo_figures_are_scaled_per_env():
    config = hsa_mjx.config.with_overrides(
        hsa_mjx.get_preset("flat"), robot="xl330_m288", randomization__servo_figures=[0.8, 1.2]
    )
    robot = load_robot(config)
    own = resolve_servo(config.servo)
    nominal = randomization.NominalModel.from_model(robot.mj_model, robot.index, own)
    scales = randomization.PhysicsScales.nominal().replace(servo_figures=jnp.asarray([1.2, 0.8, 1.1, 0.9, 1.15]))
    fields = randomization.model_fields(nominal, scales, config.randomization)
    drives, hinges = robot.index.drive_ids, robot.index.joint_qvel
    stall = 1.2 * own.stall_torque
    np.testing.assert_allclose(fields["actuator_gainprm"][drives, servo.STALL], stall, rtol=1e-6)
    np.testing.assert_allclose(fields["actuator_biasprm"][drives, 2], -stall / (0.8 * own.no_load_speed), rtol=1e-6)
    np.testing.assert_allclose(fields["dof_damping"][hinges], 0.1 + 1.1 * own.damping, rtol=1e-6)
    np.testing.assert_allclose(fields["dof_frictionloss"][hinges], 0.9 * own.friction, rtol=1e-6)
    np.testing.assert_allclose(fields["dof_armature"][hinges], 1.15 * own.armature, rtol=1e-6)
    assert randomization.servo_model_labels(config.randomization)[-1] == "true_servo_armature"


def test_each_shipped_profile_builds_and_steps():
    for name in profile_names():
        env = hsa_mjx.make_env("flat", robot=name, physics__backend="c")
        step = functools.partial(env.step_with, HostPhysics(env.robot.mj_model, env.index, env.motors))
        state = jax.jit(step)(jax.jit(env.reset)(jax.random.PRNGKey(0)), jnp.full(8, 0.5))
        assert np.isfinite(np.asarray(state.obs)).all() and not bool(state.done), name
        assert (len(env.index.drive_ids) == 8) == (name != "original")  # DC-motor drives beside the springs
