"""Where the learner's state lives on several devices: copies along a leading device axis.

Shared by the collection strategies (``train.strategies``, ``train.thread_per_device``).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import jax

from . import compat
from .learner import AXIS, PPOLearner


def replicate(tree: Any, devices: Sequence[jax.Device]) -> Any:
    """Copy a pytree onto each device along a new leading axis, laid out as pmapped functions return it.

    ``device_put_replicated`` places the copies on a mesh axis of its own name; a pmapped function's
    outputs live on its ``devices`` axis, and feeding the former to the first epoch and the latter to
    the second made ``pmap`` compile the epoch twice. A pmapped identity puts the copies on that axis.
    """
    return jax.pmap(lambda x: x, axis_name=AXIS)(compat.device_put_replicated(tree, list(devices)))


def first_copy(tree: Any) -> Any:
    """The first device's copy of a pytree with a leading device axis."""
    return jax.tree.map(lambda x: x[0], tree)


def check_env_size(learner: PPOLearner, devices: Sequence[jax.Device]) -> None:
    """The learner's env must be built for the batch each device steps (Warp's shared contact buffer)."""
    per_device = learner.config.run.num_envs // (len(devices) * jax.process_count())
    if learner.env.num_envs != per_device:
        raise ValueError(
            f"the env is built for batches of {learner.env.num_envs}, but each of the {len(devices)} devices "
            f"steps {per_device} envs (run.num_envs {learner.config.run.num_envs}): build it with "
            f"HSAEnv(config.env, num_envs={per_device}) (train.strategies.build does)"
        )
