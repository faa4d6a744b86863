"""The randomisation curriculum: each env's share of the ``randomization`` ranges, widened while it succeeds.

OpenAI's automatic domain randomisation widens the ranges while performance holds. Here every env
keeps its own level in [0, 1] (``EnvParams.randomization_scale``): each range is drawn at that share
of its width around the nominal model (``hsa_mjx.task.randomization.toward_nominal``; the torque
limit's inverse and the latency scale the same way, and pushes reach that share of their speed).
An episode that reaches its goal widens the env's next draws by ``step_up``; one that fails or runs
out of time narrows them by ``step_down``, down to ``start``. Per env, as the terrain curriculum, it
needs no outcome gathered over devices, and the batch holds every level at once: envs that keep
failing on the wide models stay where they succeed.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp


@dataclasses.dataclass(frozen=True)
class RandomizationCurriculumConfig:
    """``randomization_curriculum``: the levels' start and steps (off by default: the full ranges at once)."""

    enabled: bool = False
    start: float = 0.0  # every env's first level (0: the nominal model; 1: the full ranges)
    step_up: float = 0.25  # the level gained after an episode that reached its goal
    step_down: float = 0.25  # the level lost after one that did not (down to start)


def validate(config: RandomizationCurriculumConfig, randomizes: bool) -> RandomizationCurriculumConfig:
    """Raise ValueError naming the key; ``randomizes``: whether the env draws anything (``randomization``)."""
    if not 0.0 <= config.start <= 1.0:
        raise ValueError(f"randomization_curriculum.start must be in [0, 1], got {config.start!r}")
    for key in ("step_up", "step_down"):
        if not 0.0 < getattr(config, key) <= 1.0:
            raise ValueError(f"randomization_curriculum.{key} must be in (0, 1], got {getattr(config, key)!r}")
    if config.enabled and not randomizes:
        raise ValueError(
            "randomization_curriculum.enabled needs ranges to widen: set env.randomization "
            "(e.g. friction: [0.5, 1.5]) or randomization_curriculum.enabled: false"
        )
    return config


def init(batch: int, config: RandomizationCurriculumConfig) -> jax.Array:
    """Every env's first level, (batch,) float32: ``start``, or 1 (the full ranges) when off."""
    return jnp.full((batch,), config.start if config.enabled else 1.0, jnp.float32)


def update(level: jax.Array, done: jax.Array, success: jax.Array, config: RandomizationCurriculumConfig) -> jax.Array:
    """The levels after a batch step: up by ``step_up`` where an episode reached its goal, down by
    ``step_down`` (not below ``start``) where one ended otherwise, unchanged where none ended."""
    up = jnp.minimum(level + config.step_up, 1.0)
    down = jnp.maximum(level - config.step_down, config.start)
    return jnp.where(done, jnp.where(success, up, down), level).astype(jnp.float32)


def totals(level: jax.Array) -> dict[str, jax.Array]:
    """Sums for a log period (summed over devices): envs, their levels, envs at the full ranges."""
    return {
        "randomization_envs": jnp.asarray(level.shape[0], jnp.float32),
        "randomization_level_sum": jnp.sum(level),
        "randomization_full": jnp.sum((level >= 1.0).astype(jnp.float32)),
    }


def summarize(sums: dict[str, float]) -> dict[str, float]:
    """``randomization_curriculum/mean_level`` and ``/full_share`` (of envs at the full ranges) from :func:`totals`."""
    envs = sums.get("randomization_envs", 0.0)
    if envs <= 0:
        return {}
    return {
        "randomization_curriculum/mean_level": sums["randomization_level_sum"] / envs,
        "randomization_curriculum/full_share": sums["randomization_full"] / envs,
    }
