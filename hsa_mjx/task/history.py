"""A short history of observations and actions in the policy's input (``observation.history_steps``).

With ``history_steps: K`` the observation ends with K rows, newest first: row k holds the observation
the policy saw k steps ago (without the height scan and without its own history) and the action it
then took (clipped to [-1, 1], as the servos received it). A policy can then identify the model it
runs on from how it responded (implicit identification): friction, masses, springs, servo gain or
latency it cannot see. An episode starts with zero rows. The rows are built from the previous
observation, so no extra state is carried; the env and the deployment loop both use
:func:`advance`, with JAX or numpy arrays.
"""

from __future__ import annotations

from typing import Any

import numpy as np

PREFIX = "prev"  # a history slot's label: prev<k>_<slot>, k = 1 for the newest row
ACTION_LABEL = "action"


def labels(core: tuple[str, ...], steps: int, action_size: int) -> tuple[str, ...]:
    """The history slots' labels for the core observation slots ``core``, newest row first."""
    row = tuple(core) + tuple(f"{ACTION_LABEL}_{i}" for i in range(action_size))
    return tuple(f"{PREFIX}{k}_{label}" for k in range(1, steps + 1) for label in row)


def is_history(label: str) -> bool:
    """Whether an observation label names a history slot."""
    head, _, rest = label.partition("_")
    return bool(rest) and head.startswith(PREFIX) and head[len(PREFIX) :].isdigit()


def size(core_size: int, steps: int, action_size: int) -> int:
    """Number of history values."""
    return steps * (core_size + action_size)


def advance(previous: Any, core: Any, action: Any, steps: int, xp: Any = np) -> Any:
    """The history after a step: the newest row (``core`` observation and ``action``) first, the oldest
    row of ``previous`` dropped. ``xp``: ``numpy`` or ``jax.numpy``."""
    row = xp.concatenate([xp.asarray(core, xp.float32), xp.asarray(action, xp.float32)])
    if steps == 0:
        return xp.zeros((0,), xp.float32)
    return xp.concatenate([row, xp.asarray(previous, xp.float32)[: (steps - 1) * row.shape[0]]])
