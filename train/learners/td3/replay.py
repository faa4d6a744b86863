"""The replay buffer on the device: one ring of ``capacity`` steps per env, and n-step samples from it.

Every env step of the batch writes one row (the same slot of every env's ring), so a sample is an
(env, start) pair and its n steps are the env's next rows: no per-transition bookkeeping, and an
episode's end inside the window is read from the rows' own flags. A row holds the network input before
the step, the action, the reward, the network input after it (before the auto-reset: the true last
observation of an episode that ended), whether the episode ended there and whether by a termination
(a truncation is bootstrapped, a termination is not).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct


@struct.dataclass
class Transition:
    """One env step of every env (leading axis: envs), or a buffer of them (steps, envs, ...)."""

    obs: jax.Array
    action: jax.Array
    reward: jax.Array
    next_obs: jax.Array
    ended: jax.Array  # the episode ended at this step (a termination or a truncation), float32
    terminal: jax.Array  # it ended by a termination: no bootstrap, float32


@struct.dataclass
class ReplayBuffer:
    """``capacity`` steps of every env of one device, the next row to write and how many are filled."""

    rows: Transition  # (capacity, envs, ...)
    position: jax.Array  # int32: the row the next step writes
    filled: jax.Array  # int32: rows written so far, at most capacity


@struct.dataclass
class NStep:
    """An n-step sample: the start's input and action, the discounted rewards up to the window's end or
    the episode's, the input to bootstrap from and its discount (0 after a termination)."""

    obs: jax.Array
    action: jax.Array
    reward: jax.Array
    next_obs: jax.Array
    discount: jax.Array
    age: jax.Array  # env steps since the start was written


def init(capacity: int, example: Transition) -> ReplayBuffer:
    """An empty buffer for rows shaped as ``example`` (one step of every env)."""
    rows = jax.tree.map(lambda x: jnp.zeros((capacity, *x.shape), x.dtype), example)
    return ReplayBuffer(rows=rows, position=jnp.zeros((), jnp.int32), filled=jnp.zeros((), jnp.int32))


def add(buffer: ReplayBuffer, step: Transition) -> ReplayBuffer:
    """``buffer`` with every env's step written at the next row (the oldest overwritten when full)."""
    capacity = buffer.rows.reward.shape[0]
    rows = jax.tree.map(lambda b, x: b.at[buffer.position].set(x.astype(b.dtype)), buffer.rows, step)
    return ReplayBuffer(
        rows=rows,
        position=(buffer.position + 1) % capacity,
        filled=jnp.minimum(buffer.filled + 1, capacity),
    )


def end_newest(buffer: ReplayBuffer, cut: jax.Array) -> ReplayBuffer:
    """``buffer`` with the newest step of the envs where ``cut`` (envs,) marked as an episode's end by
    truncation (their episode was cut after it, e.g. by a terrain re-draw: no window runs past it)."""
    newest = (buffer.position - 1) % buffer.rows.reward.shape[0]
    ended = buffer.rows.ended.at[newest].max(cut.astype(buffer.rows.ended.dtype))
    return buffer.replace(rows=buffer.rows.replace(ended=ended))


def sample(buffer: ReplayBuffer, key: jax.Array, batch: int, n_step: int, discounting: float) -> NStep:
    """``batch`` n-step samples, envs and start rows uniform among the windows the buffer holds whole
    (``filled`` >= ``n_step`` is the caller's to ensure). The window stops at the first episode end in it:
    its rewards after that are not summed, the bootstrap is from that step's next input."""
    capacity, envs = buffer.rows.reward.shape[:2]
    k_env, k_start = jax.random.split(key)
    env = jax.random.randint(k_env, (batch,), 0, envs)
    offset = jax.random.randint(k_start, (batch,), 0, jnp.maximum(buffer.filled - n_step + 1, 1))
    start = (buffer.position - buffer.filled + offset) % capacity
    rows = (start[:, None] + jnp.arange(n_step)[None, :]) % capacity  # (batch, n)

    def window(x: jax.Array) -> jax.Array:  # (batch, n, ...)
        return x[rows, env[:, None]]

    reward, ended, terminal = window(buffer.rows.reward), window(buffer.rows.ended), window(buffer.rows.terminal)
    # alive[k]: no episode end among steps 0..k-1, so step k's reward still belongs to the start's episode
    alive = jnp.cumprod(jnp.concatenate([jnp.ones((batch, 1)), 1.0 - ended[:, :-1]], axis=1), axis=1)
    powers = discounting ** jnp.arange(n_step, dtype=jnp.float32)
    last = jnp.sum(alive, axis=1).astype(jnp.int32) - 1  # the window's last step: n - 1 or the episode's end
    pick = jnp.arange(batch)
    next_obs = buffer.rows.next_obs[rows[pick, last], env]
    return NStep(
        obs=buffer.rows.obs[start, env],
        action=buffer.rows.action[start, env],
        reward=jnp.sum(alive * powers * reward, axis=1),
        next_obs=next_obs,
        discount=discounting ** (last + 1.0) * (1.0 - terminal[pick, last]),
        age=((buffer.position - start - 1) % capacity).astype(jnp.float32),
    )
