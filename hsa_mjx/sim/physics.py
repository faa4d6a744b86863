"""Physics stepping: the substep loop over interpolated servo targets (with each substep's motor drive
where the servos are DC motors, ``hsa_mjx.sim.servo``), and foot contact forces."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from hsa_mjx.servo_config import ServoParams
from hsa_mjx.sim import servo
from hsa_mjx.sim.backend import mjx
from hsa_mjx.sim.model import RobotIndex

# ``mjx.step`` jitted on its own, the model an argument: a nested call that XLA inlines (the compiled
# program is the same), while JAX keeps its trace per model layout, so every later env step, reset or
# training epoch of this process over a model of that layout reuses it instead of tracing MJX again
# (1.3-2.0 s per vmapped flat step on a CPU, about 0.1 s with it). Batching under ``vmap`` is still
# done once per batch size.
_STEP = jax.jit(mjx.step)


@struct.dataclass
class SubstepStats:
    """Worst values seen over the substeps of one env step (the original looked at the last only)."""

    max_abs_qvel: jax.Array
    max_abs_qacc: jax.Array
    non_finite: jax.Array  # bool: any NaN/Inf in qpos, qvel or qacc at any substep
    final_abs_qacc: jax.Array  # max |qacc| over the dofs at the last substep (the original's check)


def substep_stats(data: mjx.Data) -> SubstepStats:
    """Stats of one substep's state."""
    finite = jnp.all(jnp.isfinite(data.qpos)) & jnp.all(jnp.isfinite(data.qvel)) & jnp.all(jnp.isfinite(data.qacc))
    qacc = jnp.max(jnp.abs(jnp.nan_to_num(data.qacc)))
    return SubstepStats(
        max_abs_qvel=jnp.max(jnp.abs(jnp.nan_to_num(data.qvel))),
        max_abs_qacc=qacc,
        non_finite=jnp.logical_not(finite),
        final_abs_qacc=qacc,
    )


def merge_stats(a: SubstepStats, b: SubstepStats) -> SubstepStats:
    """Worst of two substep stats (``b`` the later one: its final |qacc| is kept)."""
    return SubstepStats(
        jnp.maximum(a.max_abs_qvel, b.max_abs_qvel),
        jnp.maximum(a.max_abs_qacc, b.max_abs_qacc),
        a.non_finite | b.non_finite,
        b.final_abs_qacc,
    )


def simulate(
    model: mjx.Model, data: mjx.Data, targets: jax.Array, index: RobotIndex, motors: ServoParams | None = None
) -> tuple[mjx.Data, SubstepStats]:
    """Run one physics step per row of ``targets`` (frame_skip, 8) with ``lax.scan``; ``motors``: the
    DC-motor servos' model (None: the asset's springs), their figures read from ``model``.

    Returns the final data and the worst velocity/acceleration/finiteness seen on the way.
    """

    drives = index.drive_ids
    if motors is not None:  # this env's figures, as its model holds them (drawn per episode or not)
        gains, biases = model.actuator_gainprm[drives], model.actuator_biasprm[drives]
        motors = servo.figures(gains, biases, servo.static_model(motors))

    def substep(carry, servo_target):
        data, stats = carry
        ctrl = data.ctrl.at[index.servo_ids].set(servo_target)
        if motors is not None:
            ctrl, data = _drive_servos(model, data, ctrl, servo_target, index, motors)
        data = _STEP(model, data.replace(ctrl=ctrl))
        return (data, merge_stats(stats, substep_stats(data))), None

    # zeros that depend on ``data`` (exactly 0, whatever its clock holds): under ``vmap`` they are batched
    # like the rest of the carry, so the scan's batching rule batches the substep once, not twice (a
    # constant carry turns batched in the body and the rule starts again)
    zero = jnp.where(jnp.isfinite(data.time), 0.0, 0.0).astype(jnp.float32)
    start = SubstepStats(zero, zero, zero.astype(bool), zero)
    (data, stats), _ = jax.lax.scan(substep, (data, start), targets)
    return data, stats


def _drive_servos(
    model: mjx.Model, data: mjx.Data, ctrl: jax.Array, target: jax.Array, index: RobotIndex, motors: ServoParams
) -> tuple[jax.Array, mjx.Data]:
    """The drive actuators' ``ctrl`` for one substep, and the data with the gear play's motor angles."""
    angle = data.qpos[index.joint_qpos]
    value = servo.drive(motors, target, angle)
    if len(index.play_act):  # static: the model has gear play
        speed = data.qvel[index.joint_qvel]
        value, motor = servo.through_play(motors, value, data.act[index.play_act], angle, speed, model.opt.timestep)
        data = data.replace(act=data.act.at[index.play_act].set(motor))
    return ctrl.at[index.drive_ids].set(value), data


def foot_forces(data: mjx.Data, sensors: np.ndarray) -> jax.Array:
    """Magnitude of the total contact force on each foot (N), shape (feet,).

    ``sensors`` (feet, contacts, 3) are the sensordata addresses of each foot's contact sensor: the
    force of each of its active contacts in that contact's frame (normal, two tangents; zeros for
    unused slots). Summed over the contacts, then the norm, from public data on either backend.
    """
    return jnp.linalg.norm(jnp.sum(data.sensordata[sensors], axis=-2), axis=-1)
