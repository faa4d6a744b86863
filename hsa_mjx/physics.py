"""Physics stepping: the substep loop over interpolated servo targets, and foot contact forces."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from mujoco import mjx

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


def foot_contact_efc(data: mjx.Data, index_slots: np.ndarray, cone_rows: int) -> np.ndarray:
    """Static constraint-row addresses of each foot contact, shape (feet, contacts, rows)."""
    address = np.asarray(data._impl.contact.efc_address)[index_slots]
    return address[..., None] + np.arange(cone_rows)


def foot_forces(data: mjx.Data, efc_rows: np.ndarray, friction: jax.Array, pyramidal: bool) -> jax.Array:
    """Magnitude of the total contact force on each foot (N), shape (feet,).

    ``efc_rows`` (feet, contacts, rows) are static addresses; ``friction`` (feet, contacts, 2) the
    two sliding coefficients, needed to decode pyramidal rows into normal and tangent forces.
    """
    rows = data._impl.efc_force[efc_rows]
    if pyramidal:  # rows (p0+, p0-, p1+, p1-): normal = sum, tangent_i = (p_i+ - p_i-) * mu_i
        normal = jnp.sum(rows, axis=-1)
        tangent = (rows[..., 0::2] - rows[..., 1::2]) * friction
        force = jnp.concatenate([normal[..., None], tangent], axis=-1)
    else:
        force = rows
    return jnp.linalg.norm(jnp.sum(force, axis=-2), axis=-1)
