"""State pytrees: the task state of one env, the simulator state and the Brax-compatible EnvState."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from brax.envs.base import State as BraxState
from flax import struct

from hsa_mjx.sim.backend import mjx
from hsa_mjx.task.randomization import RandomizationState


@struct.dataclass
class TaskState:
    """Per-env task state (all traced arrays): the goal and bookkeeping that change every step, and
    this episode's terrain tile, drawn at reset."""

    goal_xy: jax.Array  # (2,) current goal (the current checkpoint on the spiral)
    checkpoints: jax.Array  # (N, 2) this env's checkpoint sequence (N static; 1 when unused)
    checkpoint_index: jax.Array  # () int32, index of the current checkpoint
    prev_action: jax.Array  # (8,) last normalised action (zeros after reset)
    prev_joint_vel: jax.Array  # (8,) actuated hinge velocities at the end of the last step
    prev_distance: jax.Array  # () distance to the goal at the end of the last step
    start_distance: jax.Array  # () distance to the goal when it was set (reset, set_goal)
    com_history: jax.Array  # (W, 2) ring buffer of robot positions for the stagnation term
    history_count: jax.Array  # () int32, positions written since reset
    step_count: jax.Array  # () int32, env steps since reset
    rng: jax.Array  # PRNG key of this env
    tile: jax.Array  # () int32, this episode's tile of the run's terrain atlas (0 on a plane or shared terrain)
    terrain_id: jax.Array  # () int32, this env's terrain type (index into hsa_mjx.terrain.TERRAIN_TYPES)
    site: jax.Array  # () int32, the goal's site on the tile (its distance field; -1: none, straight line)
    randomization: RandomizationState  # this episode's physical scales, latency and next push
    tracker: jax.Array  # (2, 3) the position tracker's last two readings of the robot (observation.velocity)

    @classmethod
    def start(cls, action_size: int, window: int, **drawn: jax.Array) -> TaskState:
        """An episode's first task state: ``drawn`` gives its goal, checkpoints and index, key, tile,
        terrain type, site and randomisation; actions, distances, histories and counters start at zero."""
        zero = jnp.zeros(())
        return cls(
            prev_action=jnp.zeros(action_size),
            prev_joint_vel=jnp.zeros(action_size),
            prev_distance=zero,
            start_distance=zero,
            com_history=jnp.zeros((window, 2)),
            history_count=jnp.zeros((), jnp.int32),
            step_count=jnp.zeros((), jnp.int32),
            tracker=jnp.zeros((2, 3)),
            **drawn,
        )


@struct.dataclass
class SimState:
    """What Brax calls the pipeline state: the physics and the task, reset together."""

    physics: mjx.Data
    task: TaskState


@struct.dataclass
class EnvState(BraxState):
    """Brax ``State`` whose ``pipeline_state`` is a :class:`SimState`.

    Fields: ``pipeline_state`` (SimState), ``obs`` (24,) plus the optional entries of
    ``observation``, ``reward`` (), ``done`` () float 0/1 (terminated or truncated), ``metrics``
    (named reward components, termination reasons, counters), ``info`` (``truncation``: 1.0 when
    the episode hit ``max_episode_steps``).
    """


@struct.dataclass
class PhysicsCall:
    """One env step's physics, as its first half (``HSAEnv.before_physics``) leaves it: the substeps run
    ``targets`` (frame_skip, 8) from ``data`` with this episode's model ``fields``; the rest is what the
    second half (``HSAEnv.after_physics``) reads from before them."""

    data: mjx.Data
    targets: jax.Array
    fields: dict[str, jax.Array]
    action: jax.Array  # (8,) the sanitised action
    bad_action: jax.Array  # () bool, the action had a non-finite entry
    before: tuple[jax.Array, jax.Array]  # the robot's xy and heading before the substeps
