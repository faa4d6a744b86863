"""The identification rig: the robot lifted, both blocks held, each servo driving its HSA.

:func:`rig_model` is the env's robot (its servos, physics settings) with both blocks welded to the world
half a metre up, so that only the servos, the HSA springs and the discs move, as on a bench.
:func:`rig_rollout` plays a signal on it in C MuJoCo (float64), the servo law computed at every substep
as the env's C path does (``hsa_mjx.sim.servo.write_controls``); :func:`synthesize` reads its angles as a
tracker would, late and noisy; the fit (``hsa_mjx.sysid.fit``) rolls out each candidate the same way.
"""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np

from hsa_mjx.config import EnvConfig
from hsa_mjx.servo_config import resolve_servo
from hsa_mjx.sim import servo
from hsa_mjx.sim.model import BLOCKS, RobotIndex, build_index, compile_robot, robot_spec
from hsa_mjx.sysid.logs import ServoLog
from hsa_mjx.task.control import substep_targets

LIFT = 0.5  # m the blocks are held above their spawn pose
HOLD_TIME_CONSTANT = 0.004  # s, the welds' (MuJoCo's default 0.02 lets the HSAs pull the blocks by a cm)


def rig_model(config: EnvConfig) -> tuple[mujoco.MjModel, RobotIndex]:
    """The lifted robot of ``config`` (its servos and physics): blocks welded to the world, feet in the air.

    Raises:
        ValueError: the config's servos are the asset's springs (nothing to identify).
    """
    if resolve_servo(config.servo) is None:
        raise ValueError("the rig identifies DC-motor servos: the config's servo model is the spring (env.robot)")
    spec = robot_spec(dataclasses.replace(config, scene="flat"))
    for block in BLOCKS:  # held LIFT m up, where no foot reaches the floor
        spec.body(block).pos[2] += LIFT
        weld = spec.add_equality()
        weld.type, weld.objtype, weld.name1 = mujoco.mjtEq.mjEQ_WELD, mujoco.mjtObj.mjOBJ_BODY, block
        weld.data[:] = 0.0  # anchor at the body, relative pose from the reference pose (its quat left 0)
        weld.data[10] = 1.0  # the weld holds torques as well as forces
        weld.solref = [HOLD_TIME_CONSTANT, 1.0]  # stiff: the HSAs pull the blocks by tens of newtons
    model = compile_robot(spec, config)
    return model, build_index(model)


def substep_schedule(log: ServoLog, config: EnvConfig) -> np.ndarray:
    """The servo targets of each physics substep of ``log`` (ticks x frame_skip, 8), as the env ramps them."""
    control, previous, rows = config.control, np.zeros(log.targets.shape[1]), []
    for target in log.targets:
        rows.append(substep_targets(previous, target, control.frame_skip, control.smooth_positions, xp=np))
        previous = target
    return np.concatenate(rows)


def measured(angles: np.ndarray, latency_s: float, dt: float, ticks: int, frame_skip: int, xp=np):
    """Angles read at each tick ``latency_s`` late: ``angles`` (substeps + 1, 8) from t = 0, one substep
    apart, interpolated at ``i dt - latency`` (clamped at 0)."""
    substep = dt / frame_skip
    times = xp.maximum(xp.arange(ticks) * dt - latency_s, 0.0) / substep
    low = xp.clip(xp.floor(times).astype(int), 0, angles.shape[0] - 2)
    share = (times - low)[:, None]
    return angles[low] * (1.0 - share) + angles[low + 1] * share


def rig_rollout(config: EnvConfig, schedule: np.ndarray) -> np.ndarray:
    """The rig of ``config`` in C MuJoCo (float64) driven through the substep targets ``schedule``
    (substeps, 8): the hinge angles from t = 0 at every substep (substeps + 1, 8)."""
    model, index = rig_model(config)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    motors = resolve_servo(config.servo)
    angles = np.empty((len(schedule) + 1, len(index.joint_qpos)))
    angles[0] = data.qpos[index.joint_qpos]
    for i, target in enumerate(schedule):
        servo.write_controls(model, data, index, motors, target)
        mujoco.mj_step(model, data)
        angles[i + 1] = data.qpos[index.joint_qpos]
    return angles


def synthesize(
    config: EnvConfig, signal: ServoLog, noise: float, latency_s: float, seed: int = 0
) -> tuple[ServoLog, np.ndarray]:
    """The log the rig makes of ``signal`` with the servo of ``config``, read by a tracker ``latency_s``
    late with Gaussian noise of ``noise`` rad; also the exact angles at every substep."""
    exact = rig_rollout(config, substep_schedule(signal, config))
    read = measured(exact, latency_s, signal.dt, len(signal.targets), config.control.frame_skip)
    read = read + np.random.default_rng(seed).normal(0.0, noise, read.shape)
    return ServoLog(signal.dt, signal.targets, read), exact
