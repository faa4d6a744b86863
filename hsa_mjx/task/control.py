"""Incremental position control: action scaling, target clipping and substep interpolation."""

from __future__ import annotations

import jax
import jax.numpy as jnp


def sanitize_action(action: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Replace non-finite entries by 0 and clip to [-1, 1]; also return whether any was non-finite."""
    finite = jnp.isfinite(action)
    clean = jnp.clip(jnp.where(finite, action, 0.0), -1.0, 1.0)
    return clean, jnp.logical_not(jnp.all(finite))


def next_targets(current: jax.Array, action: jax.Array, max_increment: float, limit: float, xp=jnp) -> jax.Array:
    """Servo targets after adding ``max_increment * action``, clipped to the servo ctrlrange
    (``xp=numpy`` for the deployment loop)."""
    return xp.clip(current + max_increment * action, -limit, limit)


def substep_targets(start: jax.Array, end: jax.Array, frame_skip: int, smooth: bool, xp=jnp) -> jax.Array:
    """Targets for each of the ``frame_skip`` substeps, shape (frame_skip, 8).

    Smooth: linear ramp start + (i / F) (end - start) for i = 1..F, ending exactly at ``end``.
    Otherwise the new target is held for every substep.
    """
    if not smooth:
        return xp.broadcast_to(end, (frame_skip,) + end.shape)
    fraction = xp.arange(1, frame_skip + 1, dtype=start.dtype) / frame_skip
    return start + fraction[:, None] * (end - start)
