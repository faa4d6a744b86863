"""Physics stepping: the substep loop over interpolated servo targets, and foot contact forces."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from hsa_mjx.backend import mjx
from hsa_mjx.model import RobotIndex
from hsa_mjx.termination import SubstepStats, merge_stats, substep_stats


def simulate(model: mjx.Model, data: mjx.Data, targets: jax.Array,
             index: RobotIndex) -> tuple[mjx.Data, SubstepStats]:
    """Run one physics step per row of ``targets`` (frame_skip, 8) with ``lax.scan``.

    Returns the final data and the worst velocity/acceleration/finiteness seen on the way.
    """
    def substep(carry, servo_target):
        data, stats = carry
        data = mjx.step(model, data.replace(ctrl=data.ctrl.at[index.servo_ids].set(servo_target)))
        return (data, merge_stats(stats, substep_stats(data))), None

    start = SubstepStats(jnp.zeros(()), jnp.zeros(()), jnp.zeros((), bool), jnp.zeros(()))
    (data, stats), _ = jax.lax.scan(substep, (data, start), targets)
    return data, stats


def foot_forces(data: mjx.Data, sensors: np.ndarray) -> jax.Array:
    """Magnitude of the total contact force on each foot (N), shape (feet,).

    ``sensors`` (feet, contacts, 3) are the sensordata addresses of each foot's contact sensor: the
    force of each of its active contacts in that contact's frame (normal, two tangents; zeros for
    unused slots). Summed over the contacts, then the norm, from public data on either backend.
    """
    return jnp.linalg.norm(jnp.sum(data.sensordata[sensors], axis=-2), axis=-1)
