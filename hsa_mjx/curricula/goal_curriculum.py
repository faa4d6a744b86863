"""The goal-distance curriculum as a device-resident pytree, updated from whole batches of episodes.

The original kept a Python list of the last ``window_size`` episode outcomes in each worker process
and widened (or narrowed) the goal range when the success rate in a full window crossed a
threshold. Here the same rule runs inside jit over a batch: every env's finished episodes are
written into one ring buffer per update, so thousands of envs feed one shared curriculum.

Differences from the original, deliberately:
- Outcomes of one batch step are inserted together and the rule is checked once per step (the
  original checked after every single episode). When more than ``window_size`` episodes end in one
  step only the last ``window_size`` are kept.
- Under ``pmap`` the outcomes of all devices are gathered first, so every device applies the same
  update and the curriculum stays identical everywhere (the original's workers each had their own
  manager, and its resume never restored the workers' state).
- ``progress`` is 1.0 when the start and target maxima coincide (the original divided by zero).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
from flax import struct


@dataclasses.dataclass(frozen=True)
class GoalCurriculumConfig:
    """Static settings (the original's shipped values as defaults). The range starts where the env's
    goals start, ``env.goal.radial_range``: every function takes that ``start`` range as an argument."""

    enabled: bool = True
    target_range: tuple[float, float] = (1.5, 4.5)
    success_threshold: float = 0.75
    failure_threshold: float = 0.30
    expansion_step: float = 0.15
    window_size: int = 100
    min_episodes: int = 100
    dead_zone_radius: float = 1.2


Range = tuple[float, float]


def min_distance(config: GoalCurriculumConfig, start: Range) -> float:
    """Fixed lower end of the goal distance range."""
    return max(start[0], config.dead_zone_radius)


def validate(config: GoalCurriculumConfig, start: Range) -> GoalCurriculumConfig:
    """Raise ValueError (naming the key) on inconsistent settings; return the config."""
    (i_lo, i_hi), (t_lo, t_hi) = start, config.target_range
    if not 0 <= i_lo <= i_hi:
        raise ValueError(
            f"the goal curriculum's start (env.goal.radial_range) must satisfy 0 <= min <= max, got {start}"
        )
    if not 0 <= t_lo <= t_hi or t_hi < i_hi:
        raise ValueError(
            f"goal_curriculum.target_range must satisfy 0 <= min <= max and max >= the start's max, "
            f"got {config.target_range} (start, env.goal.radial_range: {start})"
        )
    if not 0 <= config.failure_threshold <= config.success_threshold <= 1:
        raise ValueError(
            "goal_curriculum thresholds must satisfy 0 <= failure_threshold <= success_threshold <= 1, "
            f"got {config.failure_threshold}, {config.success_threshold}"
        )
    for key in ("window_size", "min_episodes"):
        if getattr(config, key) < 1:
            raise ValueError(f"goal_curriculum.{key} must be >= 1, got {getattr(config, key)}")
    if config.expansion_step <= 0 or config.dead_zone_radius < 0:
        raise ValueError("goal_curriculum.expansion_step must be > 0 and goal_curriculum.dead_zone_radius >= 0")
    if min_distance(config, start) > i_hi:
        raise ValueError(
            f"goal_curriculum: max(env.goal.radial_range[0], dead_zone_radius) = {min_distance(config, start)} "
            f"exceeds env.goal.radial_range[1] = {i_hi}"
        )
    return config


@struct.dataclass
class GoalCurriculumState:
    """Goal curriculum state (all traced; identical on every device)."""

    max_distance: jax.Array  # () current upper end of the goal distance range (m)
    outcomes: jax.Array  # (window,) bool ring buffer of the latest episode outcomes
    filled: jax.Array  # () int32 outcomes written since the last change (ring position = filled % window)
    episode_count: jax.Array  # () int32 episodes recorded in total
    episodes_since_change: jax.Array  # () int32 episodes since the range last changed


def init(config: GoalCurriculumConfig, start: Range) -> GoalCurriculumState:
    """The state at the start of training: the start range, an empty window."""
    return GoalCurriculumState(
        max_distance=jnp.asarray(start[1], jnp.float32),
        outcomes=jnp.zeros((config.window_size,), bool),
        filled=jnp.zeros((), jnp.int32),
        episode_count=jnp.zeros((), jnp.int32),
        episodes_since_change=jnp.zeros((), jnp.int32),
    )


def goal_range(state: GoalCurriculumState, config: GoalCurriculumConfig, start: Range) -> jax.Array:
    """The (min, max) goal distance new episodes sample from, shape (2,)."""
    return jnp.stack([jnp.asarray(min_distance(config, start), jnp.float32), state.max_distance])


def success_rate(state: GoalCurriculumState) -> jax.Array:
    """Mean outcome over the filled part of the window (0 when empty)."""
    window = state.outcomes.shape[0]
    count = jnp.minimum(state.filled, window)
    return jnp.where(count > 0, jnp.sum(state.outcomes) / jnp.maximum(count, 1), 0.0).astype(jnp.float32)


def _insert(state: GoalCurriculumState, success: jax.Array, done: jax.Array) -> GoalCurriculumState:
    """Write the outcomes of the finished episodes (``done``) into the ring, keeping the last ``window``."""
    window = state.outcomes.shape[0]
    done = done.astype(bool).reshape(-1)
    n = jnp.sum(done, dtype=jnp.int32)
    rank = jnp.cumsum(done, dtype=jnp.int32) - 1
    keep = done & (rank >= n - window)
    position = jnp.where(keep, (state.filled + rank) % window, window)  # out of range: dropped
    outcomes = state.outcomes.at[position].set(success.astype(bool).reshape(-1), mode="drop")
    return state.replace(
        outcomes=outcomes,
        filled=state.filled + n,
        episode_count=state.episode_count + n,
        episodes_since_change=state.episodes_since_change + n,
    )


def update(
    state: GoalCurriculumState, success: jax.Array, done: jax.Array, config: GoalCurriculumConfig, start: Range
) -> GoalCurriculumState:
    """Record a batch of episode ends and widen or narrow the range by the original's rule.

    ``success`` and ``done`` are boolean arrays of any (equal) shape; only entries with ``done``
    count. The rule fires once the window is full and ``min_episodes`` have passed since the last
    change: rate >= success_threshold widens by ``expansion_step`` (up to the target maximum), rate <
    failure_threshold narrows (down to the start maximum); a real change clears the window.
    """
    if not config.enabled:
        return state
    state = _insert(state, success, done)
    rate = success_rate(state)
    ready = (state.episodes_since_change >= config.min_episodes) & (state.filled >= config.window_size)
    step = jnp.float32(config.expansion_step)
    wider = jnp.minimum(state.max_distance + step, config.target_range[1])
    narrower = jnp.maximum(state.max_distance - step, start[1])
    new_max = jnp.where(
        ready & (rate >= config.success_threshold),
        wider,
        jnp.where(ready & (rate < config.failure_threshold), narrower, state.max_distance),
    )
    changed = new_max != state.max_distance
    zero = jnp.zeros((), jnp.int32)
    return state.replace(
        max_distance=new_max.astype(jnp.float32),
        outcomes=jnp.where(changed, jnp.zeros_like(state.outcomes), state.outcomes),
        filled=jnp.where(changed, zero, state.filled),
        episodes_since_change=jnp.where(changed, zero, state.episodes_since_change),
    )


def metrics(state: GoalCurriculumState, config: GoalCurriculumConfig, start: Range) -> dict[str, jax.Array]:
    """The original's ``curriculum/*`` log keys as arrays."""
    span = config.target_range[1] - start[1]
    progress = (state.max_distance - start[1]) / span if span > 0 else jnp.ones(())
    return {
        "curriculum/max_distance": state.max_distance,
        "curriculum/success_rate": success_rate(state),
        "curriculum/episode_count": state.episode_count.astype(jnp.float32),
        "curriculum/episodes_since_change": state.episodes_since_change.astype(jnp.float32),
        "curriculum/progress": jnp.asarray(progress, jnp.float32),
    }
