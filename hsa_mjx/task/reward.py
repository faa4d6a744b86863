"""Reward terms: one small pure function per term, each returning its signed contribution.

Every term takes the :class:`RewardInputs` of one step and the traced :class:`RewardWeights`, and
returns the amount added to the step reward (costs are negative). ``compute_rewards`` returns a
dict of named components; the reward is their sum. The caps and clips of the cost terms are
weights too (``ctrl_cost_cap``, ``acceleration_clip``, ...; the original's constants by default).
Quirks of the original that are fixed here are listed in ``docs/environment.md``.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
from flax import struct

from hsa_mjx.config import RewardConfig

CONSTRAINT_LIMIT = jnp.pi  # |qA - qC| must stay below pi (minus the margin)


# The one table of reward weights and per-term parameters is RewardConfig: every float field of it is
# traced here, under the same name (the bool and int fields are static settings of the terms).
WEIGHT_NAMES = tuple(f.name for f in dataclasses.fields(RewardConfig) if f.type in (float, "float"))


@struct.dataclass
class RewardWeights:
    """RewardConfig's float fields as traced float32 scalars (may differ per env), read as attributes."""

    values: dict[str, jax.Array]

    def __getattr__(self, name: str) -> jax.Array:
        values = self.__dict__.get("values")
        if values is None or name not in values:
            raise AttributeError(f"RewardWeights has no weight {name!r}; weights: {list(WEIGHT_NAMES)}")
        return values[name]

    @classmethod
    def from_config(cls, config: RewardConfig) -> RewardWeights:
        """Every float field of ``config``."""
        return cls(values={n: jnp.asarray(getattr(config, n), jnp.float32) for n in WEIGHT_NAMES})

    def with_weights(self, **weights: float | jax.Array) -> RewardWeights:
        """These weights with some replaced (ValueError naming an unknown one)."""
        unknown = sorted(set(weights) - set(self.values))
        if unknown:
            raise ValueError(f"unknown reward weight(s) {unknown}; weights: {list(WEIGHT_NAMES)}")
        return RewardWeights(values={**self.values, **{k: jnp.asarray(v, jnp.float32) for k, v in weights.items()}})


@struct.dataclass
class RewardInputs:
    """Everything the reward terms read for one env step."""

    velocity: jax.Array  # (2,) robot xy velocity over the step (the terms clip it to +-velocity_clip)
    goal_direction: jax.Array  # (2,) unit vector from the robot to the current goal
    action: jax.Array  # (8,) normalised action of this step
    prev_action: jax.Array  # (8,)
    joint_pos: jax.Array  # (8,) actuated hinge angles
    joint_vel: jax.Array  # (8,)
    prev_joint_vel: jax.Array  # (8,)
    foot_force: jax.Array  # (4,) contact force magnitude on each foot (N)
    distance: jax.Array  # () distance to the current goal
    prev_distance: jax.Array  # () distance at the end of the last step (to the same goal)
    stagnation_progress: jax.Array  # () displacement over the stagnation window
    history_full: jax.Array  # () bool, the window holds enough positions
    checkpoint_collected: jax.Array  # () bool
    spiral_complete: jax.Array  # () bool
    goal_reached: jax.Array  # () bool (non-spiral success)
    failed: jax.Array  # () bool, terminated for a reason other than success
    terminated: jax.Array  # () bool
    heading_before: jax.Array  # (2,) unit robot axis (block A -> B) in XY before the step
    heading_after: jax.Array  # (2,) the same after the step
    dt: float = struct.field(pytree_node=False, default=0.02)  # env step length (static)
    rectified_forward: bool = struct.field(pytree_node=False, default=False)
    constraint_pairs: tuple = struct.field(pytree_node=False, default=((0, 4), (1, 5), (2, 6), (3, 7)))


def _velocity(x: RewardInputs, w: RewardWeights) -> jax.Array:
    """The robot's xy velocity, each component clipped to +-``velocity_clip``."""
    return jnp.clip(x.velocity, -w.velocity_clip, w.velocity_clip)


def forward(x: RewardInputs, w: RewardWeights) -> jax.Array:
    """Velocity towards the goal (signed; the original rectified it with max(0, .))."""
    speed = jnp.dot(_velocity(x, w), x.goal_direction)
    if x.rectified_forward:
        speed = jnp.maximum(speed, 0.0)
    return w.forward * speed


def lateral_cost(x: RewardInputs, w: RewardWeights) -> jax.Array:
    """World-Y speed as a cost (the original added it as a reward)."""
    return -w.lateral_cost * jnp.abs(_velocity(x, w)[1])


def ctrl_cost(x: RewardInputs, w: RewardWeights) -> jax.Array:
    """Action smoothness: squared change of the normalised action, capped."""
    return -jnp.minimum(w.ctrl_cost_cap, w.ctrl_cost * jnp.sum(jnp.square(x.action - x.prev_action)))


def contact_cost(x: RewardInputs, w: RewardWeights) -> jax.Array:
    """Foot contact force above the threshold, squared and capped (the original read torques)."""
    excess = jnp.maximum(0.0, x.foot_force - w.contact_force_threshold)
    return -jnp.minimum(w.contact_cost_cap, w.contact_cost * jnp.sum(jnp.square(excess)))


def _pair_differences(x: RewardInputs) -> jax.Array:
    pairs = jnp.asarray(x.constraint_pairs)
    return jnp.abs(x.joint_pos[pairs[:, 0]] - x.joint_pos[pairs[:, 1]])


def constraint_cost(x: RewardInputs, w: RewardWeights) -> jax.Array:
    """Paired hinges (kA, kC) whose angle difference reaches pi - margin: quadratic ramp to 1 each."""
    threshold = CONSTRAINT_LIMIT - w.constraint_margin
    over = jnp.clip((_pair_differences(x) - threshold) / w.constraint_margin, 0.0, 1.0)
    return -jnp.minimum(w.constraint_cost_cap, w.constraint_cost * jnp.sum(jnp.square(over)))


def constraint_bonus(x: RewardInputs, w: RewardWeights) -> jax.Array:
    """Bonus per pair that keeps its angle difference below pi - margin (now a config weight)."""
    ok = _pair_differences(x) <= CONSTRAINT_LIMIT - w.constraint_margin
    return w.constraint_bonus * jnp.sum(ok.astype(jnp.float32))


def acceleration_cost(x: RewardInputs, w: RewardWeights) -> jax.Array:
    """Hinge accelerations over the env step, clipped to +-50 each, squared, capped."""
    acc = jnp.clip((x.joint_vel - x.prev_joint_vel) / x.dt, -w.acceleration_clip, w.acceleration_clip)
    return -jnp.minimum(w.acceleration_cost_cap, w.acceleration_cost * jnp.sum(jnp.square(acc)))


def joint_velocity_cost(x: RewardInputs, w: RewardWeights) -> jax.Array:
    """Hinge velocities clipped to +-50 each, squared, capped."""
    vel = jnp.clip(x.joint_vel, -w.joint_velocity_clip, w.joint_velocity_clip)
    return -jnp.minimum(w.joint_velocity_cost_cap, w.joint_velocity_cost * jnp.sum(jnp.square(vel)))


def distance(x: RewardInputs, w: RewardWeights) -> jax.Array:
    """Progress towards the goal: decrease of the distance over the step."""
    return w.distance * (x.prev_distance - x.distance)


def stagnation_cost(x: RewardInputs, w: RewardWeights) -> jax.Array:
    """Linear penalty when the robot moved less than the threshold over the full window."""
    shortfall = jnp.maximum(0.0, 1.0 - x.stagnation_progress / w.stagnation_threshold)
    return -jnp.where(x.history_full, w.stagnation_cost * shortfall, 0.0)


def checkpoint(x: RewardInputs, w: RewardWeights) -> jax.Array:
    """Bonus for collecting the current spiral checkpoint."""
    return jnp.where(x.checkpoint_collected, w.checkpoint, 0.0)


def spiral_completion(x: RewardInputs, w: RewardWeights) -> jax.Array:
    """Bonus when the last spiral checkpoint is collected (hard-coded 100 in the original)."""
    return jnp.where(x.spiral_complete, w.spiral_completion, 0.0)


def goal_bonus(x: RewardInputs, w: RewardWeights) -> jax.Array:
    """Bonus for reaching a non-spiral goal (hard-coded 40 in the original)."""
    return jnp.where(x.goal_reached, w.goal_bonus, 0.0)


def alive(x: RewardInputs, w: RewardWeights) -> jax.Array:
    """Bonus for every step that did not terminate."""
    return jnp.where(x.terminated, 0.0, w.alive)


def termination(x: RewardInputs, w: RewardWeights) -> jax.Array:
    """Penalty for an early termination other than success (the original ignored its weight)."""
    return -jnp.where(x.failed, w.termination, 0.0)


def heading_alignment(x: RewardInputs, w: RewardWeights) -> jax.Array:
    """Turning towards the goal: change of |cos| between the robot's axis and the goal direction.

    Shaping added here (weight 0 keeps the original's reward). Both ends of the axis count, as the
    robot crawls either way; both angles are taken against this step's goal direction, so the term
    pays rotation only, adds up to 0 over a full spin, and a checkpoint switch makes it jump nowhere.
    """
    before = jnp.abs(jnp.dot(x.heading_before, x.goal_direction))
    after = jnp.abs(jnp.dot(x.heading_after, x.goal_direction))
    return w.heading_alignment * (after - before)


TERMS = (
    forward,
    lateral_cost,
    ctrl_cost,
    contact_cost,
    constraint_cost,
    constraint_bonus,
    acceleration_cost,
    joint_velocity_cost,
    distance,
    stagnation_cost,
    checkpoint,
    spiral_completion,
    goal_bonus,
    alive,
    termination,
    heading_alignment,
)
TERM_NAMES = tuple(term.__name__ for term in TERMS)


def compute_rewards(x: RewardInputs, w: RewardWeights) -> dict[str, jax.Array]:
    """All reward components by name; the step reward is their sum."""
    return {term.__name__: term(x, w).astype(jnp.float32) for term in TERMS}


def total_reward(components: dict[str, jax.Array]) -> jax.Array:
    """Sum of the named components."""
    return jnp.sum(jnp.stack(list(components.values())))
