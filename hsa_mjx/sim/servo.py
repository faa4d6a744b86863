"""Servos as hardware behaves: a stall torque, a torque-speed line, a saturating drive, a dead band, rotor
inertia, friction, gear play and the resolution of the angle the servo's loop reads.

The asset's servos are soft position springs (``kp`` 1 N m/rad, ``kv`` 0.1, no torque or speed limit),
the default (``env.servo.model: spring``). The other two models are DC-motor servos:

- ``position``: a servo's internal proportional loop drives the motor: drive
  ``d = clip(kp * e / stall_torque, -1, 1)`` from the target error ``e`` (less ``deadband`` rad);
- ``continuous``: a continuous-rotation servo is commanded a speed: the controller asks for
  ``speed_gain * e`` (rad/s), as a share ``d`` of the no-load speed, clipped to [-1, 1]; commands
  under ``deadband`` (a share of full command) do not move it.

Either way the error is taken from the angle as the loop reads it: rounded to ``encoder_resolution``
(the servo's own potentiometer or encoder, or for a continuous-rotation servo the encoder on the HSA end
that the robot's controller reads). The motor gives ``clip(stall_torque * (d - w / no_load_speed),
-stall_torque, stall_torque)`` at joint speed ``w`` (:func:`torque`). The servo's viscous ``damping``,
Coulomb ``friction`` and rotor inertia (``armature``, seen through the gears) are the hinge's own MuJoCo
fields (``dof_damping`` on top of the asset's, ``dof_frictionloss``, ``dof_armature``), so every
backend's solver treats them. With ``backlash`` the gear train has play: the motor side turns freely
at its no-load speed times the drive until it meets the output (:func:`through_play`), and gives no
torque while it crosses the gap; its angle rides in the ``act`` state of eight inert actuators
(``<joint>_play``), carried with the rest of the physics state on every backend.

The eight servos keep their position actuators, made inert, whose ``ctrl`` holds the targets as
before; beside each, a ``general`` actuator (``<joint>_drive``) takes the drive as its ``ctrl``, with
the stall torque as gain, the back-EMF as a velocity bias and the stall torque as force range. MuJoCo
computes the torque on every backend, the velocity term implicitly under ``implicitfast``; only the
drive, a function of the target and the joint angle, is computed at each substep, by :func:`drive`
(JAX for MJX, numpy for C MuJoCo). The drive's own figures ride in the drive actuators' unused gain
slots (``SLOTS``), so that every figure of a servo is a model field (:func:`figures` reads them back):
an env that draws its servo per episode (``randomization.robots``, ``randomization.servo_figures``)
writes them like any other randomised field, on every backend.

The config and its resolution: ``hsa_mjx.servo_config``.
"""

from __future__ import annotations

import jax.numpy as jnp
import mujoco
import numpy as np

from hsa_mjx.servo_config import MIXED, ServoParams

DRIVE_SUFFIX = "_drive"
PLAY_SUFFIX = "_play"
# the drive actuators' gainprm slots: the stall torque is the (fixed) gain; MuJoCo reads no other slot
# of a fixed gain, so the drive's figures are kept in the next ones (MODEL: 1 continuous, 0 position)
SLOTS = ("stall_torque", "kp", "speed_gain", "deadband", "backlash", "encoder_resolution", "model")
STALL, KP, SPEED_GAIN, DEADBAND, BACKLASH, RESOLUTION, MODEL = range(len(SLOTS))
FIGURE_SLOTS = len(SLOTS)


def read_angle(params: ServoParams, angle, xp=jnp):
    """The angle as the servo's loop reads it: rounded to its encoder's resolution (0: exact)."""
    step = params.encoder_resolution
    if isinstance(step, float) and step == 0.0:
        return angle
    safe = xp.where(step > 0, step, 1.0)
    return xp.where(step > 0, safe * xp.round(angle / safe), angle)


def drive(params: ServoParams, target, angle, xp=jnp):
    """The motor drive in [-1, 1] for each servo from its target and joint angle (rad); ``xp=numpy``
    for C MuJoCo. A traced ``params.model`` (1: continuous) chooses the law per servo."""
    error = target - read_angle(params, angle, xp)
    if isinstance(params.model, str):
        law = _continuous_drive if params.model == "continuous" else _position_drive
        return law(params, error, xp)
    return xp.where(params.model > 0.5, _continuous_drive(params, error, xp), _position_drive(params, error, xp))


def _position_drive(params: ServoParams, error, xp):
    error = xp.sign(error) * xp.maximum(xp.abs(error) - params.deadband, 0.0)
    return xp.clip(params.kp * error / params.stall_torque, -1.0, 1.0)


def _continuous_drive(params: ServoParams, error, xp):
    command = xp.clip(params.speed_gain * error / params.no_load_speed, -1.0, 1.0)
    return xp.where(xp.abs(command) < params.deadband, 0.0, command)


def through_play(params: ServoParams, drive_value, motor, angle, speed, dt: float, xp=jnp):
    """Gear play: the drive that reaches the joint and the motor side's new angle (rad, at the output).

    The motor side moves ``no_load_speed * drive * dt`` and is kept within ``backlash / 2`` of the
    output; where it is held at either edge the gears mesh and the drive goes through; inside the gap
    the joint gets no torque (the drive that cancels the back-EMF term at its speed)."""
    half = 0.5 * params.backlash
    free = motor + params.no_load_speed * drive_value * dt
    meshed = xp.abs(free - angle) >= half
    coasting = xp.clip(speed / params.no_load_speed, -1.0, 1.0)
    return xp.where(meshed, drive_value, coasting), xp.clip(free, angle - half, angle + half)


def figures(gainprm, biasprm, model) -> ServoParams:
    """The DC-motor servos' drive figures as the model holds them (``gainprm`` and ``biasprm`` of the
    drive actuators, MJX or C MuJoCo arrays): one value per servo, for :func:`drive`. ``model``: the
    static model name, or None to read it per servo from the model (an env drawing its robot)."""
    stall = gainprm[..., STALL]
    return ServoParams(
        model=gainprm[..., MODEL] if model is None else model,
        stall_torque=stall,
        no_load_speed=stall / -biasprm[..., 2],
        kp=gainprm[..., KP],
        speed_gain=gainprm[..., SPEED_GAIN],
        deadband=gainprm[..., DEADBAND],
        backlash=gainprm[..., BACKLASH],
        encoder_resolution=gainprm[..., RESOLUTION],
    )


def gain_slots(params: ServoParams) -> list[float]:
    """The first ``FIGURE_SLOTS`` gainprm values of a drive actuator of these figures."""
    model = 1.0 if params.model == "continuous" else 0.0
    return [getattr(params, name) for name in SLOTS[:-1]] + [model]


def torque(params: ServoParams, drive_value, speed, xp=jnp):
    """The motor torque (N m) at a drive and joint speed: what the drive actuators give in MuJoCo."""
    raw = params.stall_torque * drive_value - params.back_emf * speed
    return xp.clip(raw, -params.stall_torque, params.stall_torque)


def add_drives(spec: mujoco.MjSpec, params: ServoParams, servos: tuple[str, ...], joints: tuple[str, ...]) -> None:
    """Make the position actuators ``servos`` inert (their ``ctrl`` keeps the targets), add beside each a
    drive actuator on its joint (``<joint>_drive``: gain the stall torque, velocity bias the back-EMF,
    force range the stall torque, ``ctrl`` the drive in [-1, 1]), write the servo's damping, friction and
    rotor inertia into its joint and, with gear play, add its motor-side state (``<joint>_play``)."""
    for name in servos:
        actuator = spec.actuator(name)
        actuator.gainprm[0], actuator.biasprm[1], actuator.biasprm[2] = 0.0, 0.0, 0.0
    for name in joints:
        joint = spec.joint(name)
        joint.damping[0] += params.damping  # the linear coefficient (MuJoCo 4 keeps a damping polynomial)
        joint.frictionloss, joint.armature = params.friction, params.armature
        actuator = spec.add_actuator()
        actuator.name, actuator.target = name + DRIVE_SUFFIX, name
        actuator.trntype = mujoco.mjtTrn.mjTRN_JOINT
        actuator.gaintype, actuator.biastype = mujoco.mjtGain.mjGAIN_FIXED, mujoco.mjtBias.mjBIAS_AFFINE
        actuator.gainprm[:FIGURE_SLOTS] = gain_slots(params)
        actuator.biasprm[2] = -params.back_emf
        actuator.ctrllimited, actuator.ctrlrange = mujoco.mjtLimited.mjLIMITED_TRUE, [-1.0, 1.0]
        actuator.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
        actuator.forcerange = [-params.stall_torque, params.stall_torque]
    if params.backlash > 0:
        for name in joints:  # an integrator whose ctrl stays 0: its act holds the motor side's angle
            state = spec.add_actuator()
            state.name, state.target, state.trntype = name + PLAY_SUFFIX, name, mujoco.mjtTrn.mjTRN_JOINT
            state.dyntype, state.gaintype = mujoco.mjtDyn.mjDYN_INTEGRATOR, mujoco.mjtGain.mjGAIN_FIXED
            state.gainprm[0], state.ctrllimited = 0.0, mujoco.mjtLimited.mjLIMITED_FALSE


def write_controls(
    model: mujoco.MjModel, data: mujoco.MjData, index, motors: ServoParams | None, target: np.ndarray
) -> None:
    """C MuJoCo, before a substep: the targets into the servos' ``ctrl`` and, for DC-motor servos, the
    drives from the targets and joint angles (through the gear play where there is one), with the
    figures ``model`` holds (``index``: the env's ``RobotIndex``; ``motors``: the servo model, None for
    the asset's springs)."""
    data.ctrl[index.servo_ids] = target
    if motors is None:
        return
    ids = index.drive_ids
    params = figures(model.actuator_gainprm[ids], model.actuator_biasprm[ids], static_model(motors))
    angle = data.qpos[index.joint_qpos]
    value = drive(params, target, angle, xp=np)
    if len(index.play_act):
        speed = data.qvel[index.joint_qvel]
        value, data.act[index.play_act] = through_play(
            params, value, data.act[index.play_act], angle, speed, model.opt.timestep, xp=np
        )
    data.ctrl[ids] = value


def static_model(motors: ServoParams) -> str | None:
    """The model name when every env has it, None when each env reads its own from the model (``MIXED``)."""
    return None if motors.model == MIXED else motors.model
