"""The run state a checkpoint holds, and every way of reading it back into a training state.

A checkpoint's payload (``train.run.checkpoint`` writes and reads the files) is one pytree:

- ``training_state``: the learner's state (PPO's: parameters, optimiser, observation statistics);
- ``curriculum``: the goal curriculum's state (its on-disk name since format 1);
- ``rng``: the training loop's PRNG key;
- ``terrain_levels`` (with the terrain curriculum): every env's terrain cell, ``row`` (its terrain
  type, the on-disk name since format 1) and ``level``, (envs,) arrays in process and device order;
- ``randomization_levels`` (with the randomisation curriculum): every env's level, (envs,) float32.

The trainer (save, resume), warm starts (another run's networks or a policy file's) and the tools
(evaluation, export) all read it through this module; what the learner state holds is the learner's
(``train.learners.registry``).
"""

from __future__ import annotations

import hsa_mjx.sim.backend  # noqa: F401  (MJX imported quietly, before Brax imports it)

# isort: split
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from hsa_mjx.curricula import goal_curriculum, terrain_curriculum
from hsa_mjx.curricula.state import EnvLevels

from ..config import TrainConfig, from_dict
from ..learners.registry import learner_of
from . import checkpoint

ON_DISK_TERRAIN = {"terrain_type": "row", "level": "level"}  # TerrainLevels field -> payload key


def payload(
    ts: Any,
    goal: goal_curriculum.GoalCurriculumState,
    key: jax.Array,
    terrain: dict | None = None,
    randomization: np.ndarray | None = None,
) -> dict[str, Any]:
    """What a checkpoint holds; ``terrain``: every env's terrain levels (``terrain_curriculum.to_host``'s
    arrays); ``randomization``: every env's randomisation level."""
    saved = {"training_state": ts, "curriculum": goal, "rng": key}
    if terrain is not None:
        saved["terrain_levels"] = {disk: terrain[field] for field, disk in ON_DISK_TERRAIN.items()}
    if randomization is not None:
        saved["randomization_levels"] = np.asarray(randomization, np.float32)
    return saved


def restore(
    path: str | Path, ts: Any, goal: goal_curriculum.GoalCurriculumState, key: jax.Array
) -> tuple[Any, goal_curriculum.GoalCurriculumState, jax.Array]:
    """(learner state, goal curriculum, PRNG key) of the checkpoint at ``path``, restored into the
    structure of the given ones (a checkpoint of another shape is refused with a ValueError)."""
    restored = checkpoint.load(path, payload(ts, goal, key))
    ts, goal = jax.tree.map(jnp.asarray, (restored["training_state"], restored["curriculum"]))
    return ts, goal, jnp.asarray(restored["rng"], jnp.uint32)


def restore_training_state(path: str | Path, ts: Any, source: TrainConfig) -> Any:
    """The learner state of the checkpoint at ``path`` (written with ``source``), in the structure of ``ts``."""
    start = tuple(source.env.goal.radial_range)
    template_goal = goal_curriculum.init(source.goal_curriculum, start)
    return restore(path, ts, template_goal, jax.random.PRNGKey(0))[0]


def load_training_state(config: TrainConfig, path: str | Path, observation_size: int, action_size: int) -> tuple:
    """(networks, learner state) of the checkpoint at ``path`` written with ``config``."""
    networks, template = learner_of(config).fresh_state(config, observation_size, action_size)
    return networks, restore_training_state(path, template, config)


def restore_levels(config: TrainConfig, meta: dict, batch: int) -> EnvLevels | None:
    """The checkpoint's per-env levels for this process's ``batch`` envs (None: start them all afresh)."""
    levels = EnvLevels(restore_terrain(config, meta, batch), restore_randomization(config, meta, batch))
    return None if levels.terrain is None and levels.randomization is None else levels


def restore_randomization(config: TrainConfig, meta: dict, batch: int) -> jax.Array | None:
    """The checkpoint's per-env randomisation levels for this process's ``batch`` envs (None: start afresh,
    as for a checkpoint written without them). A different env count draws from the saved levels."""
    saved = meta.get("randomization_envs")
    if not config.randomization_curriculum.enabled or not saved:
        return None
    template = {"randomization_levels": np.zeros((saved,), np.float32)}
    level = np.asarray(checkpoint.load(meta["path"], template)["randomization_levels"], np.float32)
    if saved == batch * jax.process_count():  # every process's envs, in process order: this one's share
        level = level[jax.process_index() * batch : (jax.process_index() + 1) * batch]
    else:
        level = level[np.random.default_rng(config.run.seed).integers(0, saved, batch)]
    return jnp.asarray(np.clip(level, config.randomization_curriculum.start, 1.0))


def restore_terrain(config: TrainConfig, meta: dict, batch: int) -> terrain_curriculum.TerrainLevels | None:
    """The checkpoint's per-env terrain levels for this process's ``batch`` envs (None: start them afresh)."""
    saved = meta.get("terrain_envs")
    if not config.terrain_curriculum.enabled or not saved:
        return None
    template = {"terrain_levels": {disk: np.zeros((saved,), np.int32) for disk in ON_DISK_TERRAIN.values()}}
    on_disk = checkpoint.load(meta["path"], template)["terrain_levels"]
    restored = {field: on_disk[disk] for field, disk in ON_DISK_TERRAIN.items()}
    if (
        int(np.max(restored["terrain_type"], initial=0)) >= len(config.env.terrain.types)
        or int(np.max(restored["level"], initial=0)) >= config.env.terrain.levels
    ):
        raise ValueError(f"checkpoint {meta['path']}: its terrain levels do not fit env.terrain (types, levels)")
    if saved == batch * jax.process_count():  # every process's envs, in process order: this one's share
        start = jax.process_index() * batch
        restored = {k: v[start : start + batch] for k, v in restored.items()}
    return terrain_curriculum.from_host(restored, batch, config.run.seed)


def open_run(
    source: Path, checkpoint_path: Path | None = None, edit: Callable[[dict], dict] | None = None
) -> tuple[TrainConfig, Path, int]:
    """(config, checkpoint dir, step) of a run: ``source`` is a run dir (its newest readable checkpoint,
    or ``checkpoint_path``) or one checkpoint dir. ``edit`` changes the saved config's data before it is
    built (an evaluation's env overrides). A missing folder is a FileNotFoundError, a config this code
    cannot build a ValueError, each naming the path."""
    source = Path(source)
    if not source.is_dir():
        raise FileNotFoundError(f"run directory not found: {source}")
    path = Path(checkpoint_path) if checkpoint_path else None
    if path is None:
        path = source if (source / checkpoint.META_FILE).is_file() else checkpoint.latest(source)
    if not path.is_dir():
        raise FileNotFoundError(f"checkpoint directory not found: {path}")
    meta = checkpoint.read_meta(path)
    data = meta["config"] if edit is None else edit(meta["config"])
    try:
        config = from_dict(data)
    except ValueError as err:
        raise ValueError(f"checkpoint {path} was written with a config this code cannot build: {err}") from err
    return config, path, int(meta["step"])
