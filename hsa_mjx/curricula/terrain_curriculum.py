"""The terrain curriculum: every env's terrain type and difficulty level, moved up or down per episode.

As in legged_gym and Isaac Lab, each env keeps a terrain type for the whole run (the batch is split
over ``terrain.types`` by their proportions) and a difficulty level (``terrain.levels`` of them,
``terrain.level_difficulties``). An episode that reaches its goal, or covers at least
``promote_progress`` of its start distance, moves its env one level up; one that ends short of
``demote_progress`` moves it one level down; levels stay within 0..levels - 1. At the start the
levels are spread uniformly over the lowest ``initial_spread`` of the range, so the batch meets
every easy level at once instead of all envs starting on level ground.

The state is one pytree of per-env arrays (:class:`TerrainLevels`) that travels with the env batch:
updated inside the jitted step where an episode ends, sharded with the envs over devices, saved in
checkpoints. It composes with the goal-distance curriculum (``hsa_mjx.curricula.goal_curriculum``), which sets how
far the goals are; this one sets on which ground.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from hsa_mjx.terrain.params import TerrainConfig

REDRAW_SALT = 0x5EED  # folded into an env's key for its top-level re-draw (independent of its reset draws)
START_SALT = 0x7E11  # folded into an env's key for its start level
OUTCOME_KEYS = ("cell_episodes", "cell_success")
FIELDS = (
    "terrain_type",
    "level",
)  # of TerrainLevels, in the order of to_host's arrays  # per-cell sums in the batch totals (arrays)


@dataclasses.dataclass(frozen=True)
class TerrainCurriculumConfig:
    """When envs move between difficulty levels (fractions of the episode's start distance to its goal)."""

    enabled: bool = False
    promote_progress: float = 0.8  # reaching the goal, or covering this share of the distance: one level up
    demote_progress: float = 0.3  # ending (not at the goal) with less than this share covered: one level down
    initial_spread: float = 0.5  # start levels uniform over the lowest round(spread x (levels - 1)) + 1 levels
    # an env promoted from the top level moves to a uniformly drawn level instead of staying there
    # (legged_gym's rule): solved types keep meeting every level, and the top level's share no longer
    # saturates, so per-level success (terrain/success/<type>/L<level>) is what shows mastery
    top_redraw: bool = False


def validate(
    config: TerrainCurriculumConfig, terrain: TerrainConfig, per_env: bool, goal_mode: str
) -> TerrainCurriculumConfig:
    """Raise ValueError naming the key on settings that cannot work; return the config."""
    if not 0.0 <= config.demote_progress <= config.promote_progress <= 1.0:
        raise ValueError(
            "terrain_curriculum needs 0 <= demote_progress <= promote_progress <= 1, got "
            f"{config.demote_progress}, {config.promote_progress}"
        )
    if not 0.0 <= config.initial_spread <= 1.0:
        raise ValueError(f"terrain_curriculum.initial_spread must be in [0, 1], got {config.initial_spread}")
    if config.enabled and not per_env:
        raise ValueError(
            "terrain_curriculum.enabled needs per-env terrain: env.scene 'terrain' with env.terrain.per_env: true"
        )
    if config.enabled and goal_mode == "spiral":
        raise ValueError(
            "terrain_curriculum.enabled needs goals at a distance (env.goal.mode radial or random); "
            "the spiral's checkpoints are a fixed track"
        )
    return config


@struct.dataclass
class TerrainLevels:
    """Every env's terrain cell: its terrain type (index into ``terrain.types``) and difficulty level,
    (B,) int32 each."""

    terrain_type: jax.Array
    level: jax.Array

    def cells(self) -> jax.Array:
        """(B, 2) int32 (terrain type, level) pairs: each env's ``EnvParams.terrain_cell``."""
        return jnp.stack([self.terrain_type, self.level], axis=-1)


def type_indices(batch: int, proportions: tuple[float, ...]) -> np.ndarray:
    """Each env's terrain type, split over the batch in proportion (env i takes the type whose cumulative
    share covers (i + 0.5) / batch), (batch,) int32."""
    edges = np.cumsum(np.asarray(proportions, np.float64))
    types = np.searchsorted(edges, (np.arange(batch) + 0.5) / batch, side="right")
    return np.minimum(types, len(proportions) - 1).astype(np.int32)


def initial_max_level(config: TerrainCurriculumConfig, levels: int) -> int:
    """The highest level an env may start on."""
    return int(round(config.initial_spread * (levels - 1)))


def init(keys: jax.Array, config: TerrainCurriculumConfig, terrain: TerrainConfig) -> TerrainLevels:
    """Start levels of a batch (one PRNG key per env): types by proportion, levels spread from the keys."""
    batch = keys.shape[0]
    top = initial_max_level(config, terrain.levels)
    level = jax.vmap(lambda k: jax.random.randint(jax.random.fold_in(k, START_SALT), (), 0, top + 1))(keys)
    return TerrainLevels(
        terrain_type=jnp.asarray(type_indices(batch, terrain.proportions)), level=level.astype(jnp.int32)
    )


def placeholder(batch: int) -> TerrainLevels:
    """Zeros in the state's shape, for batches without the curriculum (the pytree keeps one structure)."""
    zeros = jnp.zeros((batch,), jnp.int32)
    return TerrainLevels(terrain_type=zeros, level=zeros)


def update(
    state: TerrainLevels,
    done: jax.Array,
    success: jax.Array,
    progress: jax.Array,
    config: TerrainCurriculumConfig,
    levels: int,
    keys: jax.Array | None = None,
) -> TerrainLevels:
    """Move every env whose episode ended (``done``) up or down a level by its outcome.

    ``progress``: the share of the start distance covered, (start - final) / start. ``keys`` (one
    PRNG key per env) draw the new level of envs promoted from the top with ``top_redraw``.
    """
    done = done.astype(bool)
    up = done & (success.astype(bool) | (progress >= config.promote_progress))
    down = done & jnp.logical_not(up) & (progress < config.demote_progress)
    level = jnp.clip(state.level + up.astype(jnp.int32) - down.astype(jnp.int32), 0, levels - 1)
    if config.top_redraw:
        if keys is None:
            raise ValueError("terrain_curriculum.top_redraw needs one PRNG key per env")
        drawn = jax.vmap(lambda k: jax.random.randint(jax.random.fold_in(k, REDRAW_SALT), (), 0, levels))(keys)
        level = jnp.where(up & (state.level == levels - 1), drawn.astype(jnp.int32), level)
    return state.replace(level=level)


def cell_index(state: TerrainLevels, levels: int) -> jax.Array:
    """Each env's cell as one index, terrain type x levels + level, (B,) int32 (the outcome arrays' layout)."""
    return state.terrain_type * levels + state.level


def cell_outcomes(
    state: TerrainLevels, done: jax.Array, success: jax.Array, cells: int, levels: int
) -> dict[str, jax.Array]:
    """Episodes ended and goals reached this step per cell (the level the episode ran on), (cells,) each."""
    index = cell_index(state, levels)
    ended = done.astype(jnp.float32)
    return {
        OUTCOME_KEYS[0]: jax.ops.segment_sum(ended, index, num_segments=cells),
        OUTCOME_KEYS[1]: jax.ops.segment_sum(ended * success.astype(jnp.float32), index, num_segments=cells),
    }


def name_outcomes(sums: dict[str, jax.Array], types: tuple[str, ...], levels: int) -> dict[str, jax.Array]:
    """The outcome arrays as one scalar per cell: ``terrain_<cell_episodes|cell_success>/<type>/<level>``."""
    out = {}
    for key in OUTCOME_KEYS:
        for i, name in enumerate(types):
            for level in range(levels):
                out[f"terrain_{key}/{name}/{level}"] = sums[key][i * levels + level]
    return out


def totals(state: TerrainLevels, types: tuple[str, ...], levels: int) -> dict[str, jax.Array]:
    """Per-type sums of envs, levels and envs at the top level (summed over devices, then over epochs)."""
    out = {}
    top = state.level == levels - 1
    for i, name in enumerate(types):
        mine = state.terrain_type == i
        out[f"terrain_envs/{name}"] = jnp.sum(mine, dtype=jnp.float32)
        out[f"terrain_level_sum/{name}"] = jnp.sum(jnp.where(mine, state.level, 0), dtype=jnp.float32)
        out[f"terrain_top/{name}"] = jnp.sum(mine & top, dtype=jnp.float32)
    return out


def summarize(sums: dict[str, float], levels: int) -> dict[str, float]:
    """``terrain/mean_level/<type>`` (0..levels - 1), ``terrain/top_share/<type>`` and overall, from drained sums."""
    out, envs, top = {}, 0.0, 0.0
    for key, count in sums.items():
        if not key.startswith("terrain_envs/") or count <= 0:
            continue
        name = key.split("/", 1)[1]
        out[f"terrain/mean_level/{name}"] = sums[f"terrain_level_sum/{name}"] / count
        out[f"terrain/top_share/{name}"] = sums[f"terrain_top/{name}"] / count
        envs, top = envs + count, top + sums[f"terrain_top/{name}"]
    out.update(_cell_success(sums))
    if envs > 0:
        out["terrain/top_share"] = top / envs
        out["terrain/mean_level"] = sum(sums[k] for k in sums if k.startswith("terrain_level_sum/")) / envs
        out["terrain/levels"] = float(levels)
    return out


def _cell_success(sums: dict[str, float]) -> dict[str, float]:
    """``terrain/success/<type>/L<level>``: goals reached per episode ended on that cell (cells with episodes),
    and ``terrain/episodes/<type>``: the episodes that ended on each type."""
    out = {}
    prefix = f"terrain_{OUTCOME_KEYS[0]}/"
    for key, episodes in sums.items():
        if key.startswith(prefix) and episodes > 0:
            name, level = key[len(prefix) :].rsplit("/", 1)
            out[f"terrain/success/{name}/L{level}"] = sums[f"terrain_{OUTCOME_KEYS[1]}/{name}/{level}"] / episodes
            out[f"terrain/episodes/{name}"] = out.get(f"terrain/episodes/{name}", 0.0) + episodes
    return out


def to_host(states: list[TerrainLevels]) -> dict[str, np.ndarray]:
    """One flat (envs,) array per field from per-device states (device order), for a checkpoint."""
    return {name: np.concatenate([np.asarray(getattr(s, name)).reshape(-1) for s in states]) for name in FIELDS}


def from_host(saved: dict[str, np.ndarray], batch: int, seed: int = 0) -> TerrainLevels:
    """The saved levels for a batch of ``batch`` envs: as saved when the size matches, else each new env
    takes the cell of a randomly chosen saved env (the same distribution over types and levels)."""
    kind, level = (np.asarray(saved[k], np.int32).reshape(-1) for k in FIELDS)
    if kind.shape[0] != batch:
        pick = np.random.default_rng(seed).integers(0, kind.shape[0], batch)
        kind, level = kind[pick], level[pick]
    return TerrainLevels(terrain_type=jnp.asarray(kind), level=jnp.asarray(level))
