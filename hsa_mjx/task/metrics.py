"""What every env step reports besides its reward: the named reward components, the termination reasons
(one by one and grouped into simulator health and task failure), non-finite actions, the distance to the
goal (``reward.progress``'s measure) and the checkpoint index."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from hsa_mjx.task import reward, termination


def step_metrics(
    components: dict, reasons: dict, bad_action: jax.Array, distance: jax.Array, checkpoint_index: jax.Array
) -> dict[str, jax.Array]:
    """``EnvState.metrics`` of one step (float32 scalars; a non-finite distance reads 0)."""
    metrics = {f"reward/{k}": v.astype(jnp.float32) for k, v in components.items()}
    metrics.update({f"termination/{k}": v.astype(jnp.float32) for k, v in reasons.items()})
    metrics.update({f"termination/{k}": v.astype(jnp.float32) for k, v in termination.grouped(reasons).items()})
    metrics["nonfinite_action"] = bad_action.astype(jnp.float32)
    metrics["distance_to_goal"] = jnp.where(jnp.isfinite(distance), distance, 0.0).astype(jnp.float32)
    metrics["checkpoint_index"] = checkpoint_index.astype(jnp.float32)
    return metrics


def reset_metrics(distance: jax.Array, checkpoint_index: jax.Array) -> dict[str, jax.Array]:
    """``EnvState.metrics`` at reset: the same keys as a step's, every reward term and reason zero."""
    components = {name: jnp.zeros(()) for name in reward.TERM_NAMES}
    reasons = {name: jnp.zeros((), bool) for name in termination.REASONS}
    return step_metrics(components, reasons, jnp.zeros((), bool), distance, checkpoint_index)
