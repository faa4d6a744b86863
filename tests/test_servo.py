"""The DC-motor servo model: its law, its config and presets, and its torques on the JAX, Warp and C
physics (the same trajectories within the bounds of tests/test_host_physics.py and tests/test_backend.py)."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_backend import BLOCK_TOL as WARP_BLOCK_TOL
from test_backend import QPOS_TOL as WARP_QPOS_TOL
from test_host_physics import QPOS_TOL as HOST_QPOS_TOL

import hsa_mjx
import hsa_mjx.sim.model
from hsa_mjx.deploy.perturbation import ModelPerturbation, perturbed_model
from hsa_mjx.servo_config import PRESETS, ServoConfig, resolve_servo
from hsa_mjx.sim import servo
from hsa_mjx.sim.host_physics import HostPhysics
from hsa_mjx.task import randomization

ENVS = 2
# the settings of tests/test_backend.py's Warp rollouts (their kernels compiled once for the suite)
PHYSICS = {"physics.integrator": "implicitfast", "physics.iterations": 8, "physics.ls_iterations": 8}
# actuator_force is the torque at a substep's start; the law is checked against the speed after it
TORQUE_TOL = 0.03  # share of the stall torque


def _actions() -> jax.Array:
    """Targets run ahead of the joints (full drive, the torque-speed line), then an alternating gait."""
    ahead = np.ones((8, ENVS, 8), np.float32)
    t = np.arange(12)[:, None, None] * 2 * np.pi / 12
    gait = np.broadcast_to(np.sin(t + np.arange(8) * np.pi / 4), (12, ENVS, 8)).astype(np.float32)
    return jnp.asarray(np.concatenate([ahead, gait]))


def _rollout(backend: str, preset: str) -> dict:
    """Per step: the drives' ctrl and torque, the position actuators' torque, joint speeds, qpos."""
    env = hsa_mjx.make_env("flat", num_envs=ENVS, **{**PHYSICS, "physics.backend": backend, "servo.preset": preset})
    step = jax.vmap(env.step)
    if backend == "c":
        step = jax.vmap(functools.partial(env.step_with, HostPhysics(env.robot.mj_model, env.index, env.motors)))
    state = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(0), ENVS))
    step, idx, rows = jax.jit(step), env.index, []
    for action in _actions():
        state = step(state, action)
        d = jax.device_get(state.pipeline_state.physics)
        rows.append(
            (d.ctrl[:, idx.drive_ids], d.actuator_force[:, idx.drive_ids], d.actuator_force[:, idx.servo_ids],
             d.qvel[:, idx.joint_qvel], d.qpos)
        )  # fmt: skip
    drive, force, springs, speed, qpos = (np.stack(x) for x in zip(*rows))
    return {"env": env, "drive": drive, "force": force, "springs": springs, "speed": speed, "qpos": qpos}


@pytest.fixture(scope="module")
def rollouts():
    return {name: _rollout(name, "xl330_m288") for name in ("jax", "c", "warp")}


def test_the_law_limits_the_torque_and_follows_the_torque_speed_line():
    params = resolve_servo(ServoConfig(preset="mx28"))
    drive, speed = np.meshgrid(np.linspace(-1, 1, 41), np.linspace(-2, 2, 41) * params.no_load_speed)
    torque = np.asarray(servo.torque(params, drive, speed, xp=np))
    assert np.abs(torque).max() == pytest.approx(params.stall_torque) and np.abs(torque).max() <= params.stall_torque
    w = np.linspace(0, 1, 11) * params.no_load_speed  # full drive: stall torque at rest, none at no-load speed
    line = params.stall_torque * (1 - w / params.no_load_speed)
    np.testing.assert_allclose(servo.torque(params, np.ones_like(w), w, xp=np), line, atol=1e-12)
    # the proportional drive saturates at stall_torque / kp of error
    errors = np.array([0.0, 0.05, params.stall_torque / params.kp, 1.0, -1.0])
    np.testing.assert_allclose(servo.drive(params, errors, 0.0, xp=np), [0.0, 0.5, 1.0, 1.0, -1.0])


def test_dead_bands_hold_small_errors_and_commands():
    position = resolve_servo(ServoConfig(preset="mg90s"))
    assert position.deadband == pytest.approx(np.radians(5 / 5.6))
    inside, outside = 0.9 * position.deadband, position.deadband + 0.01
    assert servo.drive(position, inside, 0.0, xp=np) == 0.0 and servo.drive(position, -inside, 0.0, xp=np) == 0.0
    assert servo.drive(position, outside, 0.0, xp=np) == pytest.approx(position.kp * 0.01 / position.stall_torque)
    continuous = resolve_servo(ServoConfig(preset="dfr05sr", deadband=0.1))
    small = 0.05 * continuous.no_load_speed / continuous.speed_gain  # asks for 5 % of full speed
    assert servo.drive(continuous, small, 0.0, xp=np) == 0.0 and servo.drive(continuous, 2 * small, 0.0, xp=np) == 0.1
    assert servo.drive(continuous, 1.0, 0.0, xp=jnp) == 1.0  # the JAX path is the same function


def test_presets_resolve_and_bad_servo_configs_are_refused():
    assert resolve_servo(ServoConfig()) is None  # the asset's springs
    for name, preset in PRESETS.items():
        params = resolve_servo(ServoConfig(preset=name))
        assert (params.model, params.stall_torque) == (preset.model, preset.stall_torque) and preset.source
    custom = resolve_servo(ServoConfig(preset="mx28", stall_torque=1.0, kp=20.0))
    assert (custom.stall_torque, custom.kp, custom.no_load_speed) == (1.0, 20.0, PRESETS["mx28"].no_load_speed)
    bad = {
        "servo.model": {"servo.model": "stepper"},
        "servo.preset": {"servo.preset": "sg90000"},
        "servo.kp": {"servo.kp": -1.0, "servo.model": "position"},
        "need servo.model": {"servo.stall_torque": 1.0},
        "servo.stall_torque": {"servo.model": "position", "servo.no_load_speed": 5.0},
        "share of full command": {"servo.preset": "dfr05sr", "servo.deadband": 1.5},
        "randomization.servo_gain": {"servo.preset": "mx28", "randomization.servo_gain": [0.5, 1.5]},
    }
    for message, overrides in bad.items():
        with pytest.raises(ValueError, match=message):
            hsa_mjx.make_env("flat", **overrides)
    robot = hsa_mjx.sim.model.load_robot(
        hsa_mjx.config.with_overrides(hsa_mjx.get_preset("flat"), servo__preset="mx28")
    )
    with pytest.raises(ValueError, match="DC motors"):  # the deployment loop's perturbed robot: the same rule
        perturbed_model(robot.mj_model, robot.index, ModelPerturbation(servo_torque_limit=0.5))


@pytest.mark.parametrize("backend", ["jax", "c", "warp"])
def test_servo_torque_stays_within_the_stall_torque_on_its_curve(rollouts, backend):
    run = rollouts[backend]
    params = run["env"].motors
    assert run["env"].physics_backend == backend
    assert np.abs(run["force"]).max() <= params.stall_torque * (1 + 1e-5)
    assert np.all(run["springs"] == 0.0)  # the position actuators only hold the targets
    assert (np.abs(run["drive"]) == 1.0).mean() > 0.2  # full drive: the torque-speed line itself
    assert np.abs(run["drive"]).max() <= 1.0
    law = np.asarray(servo.torque(params, run["drive"], run["speed"], xp=np))
    assert np.abs(run["force"] - law).max() <= TORQUE_TOL * params.stall_torque
    assert np.abs(run["speed"]).max() > 0.3 * params.no_load_speed  # the joints did move


def test_the_same_servos_give_the_same_trajectories_on_every_backend(rollouts):
    jax_run = rollouts["jax"]
    idx = jax_run["env"].index
    assert np.abs(rollouts["c"]["qpos"] - jax_run["qpos"]).max() <= HOST_QPOS_TOL["flat"]
    warp_gap = np.abs(rollouts["warp"]["qpos"] - jax_run["qpos"])
    assert warp_gap[..., idx.joint_qpos].max() <= WARP_QPOS_TOL
    assert warp_gap[..., idx.block_qpos[:, None] + np.arange(3)].max() <= WARP_BLOCK_TOL


DRAWN = ["mg90s", "xl330_m288", "mx28"]  # position servos of 0.18, 0.52 and 2.5 N m


def _drawn_rollout(backend: str) -> dict:
    """Envs that each draw their servo class: the drawn class, the drive fields, per-step torques, qpos."""
    overrides = {
        **PHYSICS,
        "physics.backend": backend,
        "servo.preset": "xl330_m288",
        "randomization.servo_presets": DRAWN,
    }
    env = hsa_mjx.make_env("flat", num_envs=8, **overrides)
    step = jax.vmap(env.step)
    if backend == "c":
        step = jax.vmap(functools.partial(env.step_with, HostPhysics(env.robot.mj_model, env.index, env.motors)))
    state = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(3), 8))
    scales = state.pipeline_state.task.randomization.physics
    fields = jax.vmap(lambda s: randomization.model_fields(env._nominal, s, env.config.randomization))(scales)
    step, forces, qpos = jax.jit(step), [], []
    for action in _actions()[:, :1].repeat(8, axis=1):
        state = step(state, action)
        forces.append(np.asarray(state.pipeline_state.physics.actuator_force[:, env.index.drive_ids]))
        qpos.append(np.asarray(state.pipeline_state.physics.qpos))
    drawn = np.asarray(scales.servo_preset)
    return {
        "env": env,
        "drawn": drawn,
        "fields": jax.device_get(fields),
        "force": np.stack(forces),
        "qpos": np.stack(qpos),
    }


@pytest.fixture(scope="module")
def drawn_rollouts():
    return {name: _drawn_rollout(name) for name in ("jax", "c")}


def test_each_env_drives_its_drawn_servo_class_as_that_preset_configured(drawn_rollouts):
    run = drawn_rollouts["jax"]
    env, drawn, ids = run["env"], run["drawn"], run["env"].index.drive_ids
    assert set(drawn.tolist()) == {0, 1, 2}  # 8 envs over the three classes
    for name in ("actuator_gainprm", "actuator_biasprm", "actuator_forcerange"):
        for k, preset in enumerate(drawn):  # the fields of the env that has this preset as its servo
            configured = hsa_mjx.sim.model.load_robot(
                hsa_mjx.config.with_overrides(env.config, servo__preset=DRAWN[preset], randomization__servo_presets=[])
            ).mj_model
            np.testing.assert_allclose(run["fields"][name][k][ids], getattr(configured, name)[ids], rtol=1e-6)
    stall = np.asarray([PRESETS[DRAWN[p]].stall_torque for p in drawn])
    for backend, rollout in drawn_rollouts.items():  # each env's torque within its own class's stall torque
        peak = np.abs(rollout["force"]).max(axis=(0, 2))
        assert np.all(peak <= stall * (1 + 1e-5)), (backend, peak, stall)
        weakest = drawn == 0  # mg90s: saturated at its own stall torque, which the stronger classes pass
        assert np.all(peak[weakest] >= 0.95 * stall[weakest]) and np.all(peak[~weakest] > 2 * stall[weakest][0])
    # C got each env's fields: the classes without a dead band within the host physics' bound (the MG90S's
    # dead band, a threshold on the error, parts float32 and float64 by up to 5 mm in 20 steps, drawn
    # or configured alike)
    smooth = np.asarray([PRESETS[DRAWN[p]].deadband == 0.0 for p in drawn])
    assert np.abs(drawn_rollouts["c"]["qpos"] - run["qpos"])[:, smooth].max() <= HOST_QPOS_TOL["flat"]
    # the privileged critic sees the class: one slot per preset, the drawn one set
    drawn_state = env.reset(jax.random.PRNGKey(3)).pipeline_state.task.randomization
    true = randomization.true_model(drawn_state, env.config.randomization)
    assert true.shape == (8 + len(DRAWN),) and float(true[8 + int(drawn_state.physics.servo_preset)]) == 1.0
    assert float(true[8:].sum()) == 1.0


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        ({}, "draws DC-motor servos"),
        ({"servo.model": "position", "servo.stall_torque": 1.0, "servo.no_load_speed": 5.0}, "set servo.preset"),
        ({"servo.preset": "mx28", "randomization.servo_presets": ["sg90000"]}, "not a preset"),
        ({"servo.preset": "mx28", "randomization.servo_presets": ["dfr05sr"]}, "is a continuous servo"),
        ({"servo.preset": "mx28", "servo.stall_torque": 1.0}, "set by each drawn preset"),
    ],
)
def test_drawn_servo_classes_need_dc_servos_of_their_model(overrides, message):
    overrides = {"randomization.servo_presets": ["mg90s"], **overrides}
    with pytest.raises(ValueError, match=message):
        hsa_mjx.make_env("flat", **overrides)
