"""Servos as hardware behaves: a stall torque, a torque-speed line, a saturating drive and a deadband.

The asset's servos are soft position springs (``kp`` 1 N m/rad, ``kv`` 0.1, no torque or speed limit),
the default (``env.servo.model: spring``). The other two models are DC-motor servos:

- ``position``: a servo's internal proportional loop drives the motor: drive
  ``d = clip(kp * e / stall_torque, -1, 1)`` from the target error ``e`` (less ``deadband`` rad);
- ``continuous``: a continuous-rotation servo is commanded a speed: the controller asks for
  ``speed_gain * e`` (rad/s), as a share ``d`` of the no-load speed, clipped to [-1, 1]; commands
  under ``deadband`` (a share of full command) do not move it.

Either way the motor gives ``clip(stall_torque * (d - w / no_load_speed), -stall_torque, stall_torque)``
at joint speed ``w``: the stall torque at rest under full drive, nothing at the no-load speed, and
never more than the stall torque (:func:`torque`). The eight servos keep their position actuators,
made inert, whose ``ctrl`` holds the targets as before; beside each, a ``general`` actuator
(``<joint>_drive``) takes the drive as its ``ctrl``, with the stall torque as gain, the back-EMF as a
velocity bias and the stall torque as force range. MuJoCo computes the torque on every backend, the
velocity term implicitly under ``implicitfast``; only the drive, a function of the target and the
joint angle, is computed at each substep, by :func:`drive` (JAX for MJX, numpy for C MuJoCo). The
drive's own figures (``kp``, ``speed_gain``, ``deadband``) ride in the drive actuators' unused gain
slots, so that every figure of a servo is a model field (:func:`figures` reads them back): an env
that draws its servo class per episode (``randomization.servo_presets``) writes them like any other
randomised field, on every backend.

The config, its presets (data-sheet figures of common servo classes) and their resolution:
``hsa_mjx.servo_config``.
"""

from __future__ import annotations

import jax.numpy as jnp
import mujoco
import numpy as np

from hsa_mjx.servo_config import ServoParams

DRIVE_SUFFIX = "_drive"
# the drive actuators' gainprm slots: the stall torque is the (fixed) gain; MuJoCo reads no other slot
# of a fixed gain, so the drive's figures are kept in the next three
STALL, KP, SPEED_GAIN, DEADBAND = range(4)
FIGURE_SLOTS = 4


def drive(params: ServoParams, target, angle, xp=jnp):
    """The motor drive in [-1, 1] for each servo from its target and joint angle (rad); ``xp=numpy``
    for C MuJoCo."""
    error = target - angle
    if params.model == "position":
        error = xp.sign(error) * xp.maximum(xp.abs(error) - params.deadband, 0.0)
        return xp.clip(params.kp * error / params.stall_torque, -1.0, 1.0)
    command = xp.clip(params.speed_gain * error / params.no_load_speed, -1.0, 1.0)
    return xp.where(xp.abs(command) < params.deadband, 0.0, command)


def figures(gainprm, biasprm, model: str) -> ServoParams:
    """The DC-motor servos' figures as the model holds them (``gainprm`` and ``biasprm`` of the drive
    actuators, MJX or C MuJoCo arrays): one value per servo, for :func:`drive`."""
    stall = gainprm[..., STALL]
    return ServoParams(
        model=model,
        stall_torque=stall,
        no_load_speed=stall / -biasprm[..., 2],
        kp=gainprm[..., KP],
        speed_gain=gainprm[..., SPEED_GAIN],
        deadband=gainprm[..., DEADBAND],
    )


def gain_slots(params: ServoParams) -> list[float]:
    """The first ``FIGURE_SLOTS`` gainprm values of a drive actuator of these figures."""
    return [params.stall_torque, params.kp, params.speed_gain, params.deadband]


def torque(params: ServoParams, drive_value, speed, xp=jnp):
    """The motor torque (N m) at a drive and joint speed: what the drive actuators give in MuJoCo."""
    raw = params.stall_torque * drive_value - params.back_emf * speed
    return xp.clip(raw, -params.stall_torque, params.stall_torque)


def add_drives(spec: mujoco.MjSpec, params: ServoParams, servos: tuple[str, ...], joints: tuple[str, ...]) -> None:
    """Make the position actuators ``servos`` inert (their ``ctrl`` keeps the targets) and add beside
    each a drive actuator on its joint (``<joint>_drive``): gain the stall torque, velocity bias the
    back-EMF, force range the stall torque, ``ctrl`` the drive in [-1, 1]."""
    for name in servos:
        actuator = spec.actuator(name)
        actuator.gainprm[0], actuator.biasprm[1], actuator.biasprm[2] = 0.0, 0.0, 0.0
    for joint in joints:
        actuator = spec.add_actuator()
        actuator.name, actuator.target = joint + DRIVE_SUFFIX, joint
        actuator.trntype = mujoco.mjtTrn.mjTRN_JOINT
        actuator.gaintype, actuator.biastype = mujoco.mjtGain.mjGAIN_FIXED, mujoco.mjtBias.mjBIAS_AFFINE
        actuator.gainprm[:FIGURE_SLOTS] = gain_slots(params)
        actuator.biasprm[2] = -params.back_emf
        actuator.ctrllimited, actuator.ctrlrange = mujoco.mjtLimited.mjLIMITED_TRUE, [-1.0, 1.0]
        actuator.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
        actuator.forcerange = [-params.stall_torque, params.stall_torque]


def write_controls(
    model: mujoco.MjModel, data: mujoco.MjData, index, motors: ServoParams | None, target: np.ndarray
) -> None:
    """C MuJoCo, before a substep: the targets into the servos' ``ctrl`` and, for DC-motor servos, the
    drives from the targets and joint angles, with the figures ``model`` holds (``index``: the env's
    ``RobotIndex``; ``motors``: the servo model, None for the asset's springs)."""
    data.ctrl[index.servo_ids] = target
    if motors is not None:
        ids = index.drive_ids
        params = figures(model.actuator_gainprm[ids], model.actuator_biasprm[ids], motors.model)
        data.ctrl[ids] = drive(params, target, data.qpos[index.joint_qpos], xp=np)
