"""Evaluation by terrain type and difficulty: ``python -m train.evaluate RUN --terrain-types all --levels 0,0.5,1``.

The run's env is rebuilt with ``tiles`` tiles per type and difficulty (one by default; each episode of a
random type plays one of them, drawn from its key; one atlas when the difficulties are evenly spaced
from 0, e.g. 0, 0.5, 1), and the episodes of one batch are split evenly over the
(type, difficulty) cells, each env reset on its cell's tile with the same goals in every cell. Per
type and difficulty it reports the success rate and the net progress towards the goal, prints them
as a table, writes ``terrain_eval.json`` and plots them.
"""

from __future__ import annotations

import dataclasses
import itertools
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from hsa_mjx.config import EnvConfig
from hsa_mjx.task import termination
from hsa_mjx.task.env import HSAEnv
from hsa_mjx.terrain.params import TERRAIN_TYPES

from ..run.plots import terrain_grid
from .diagnostics import failure_modes
from .failures import DEFAULT_RULE, FailureRule, episode_modes, mode_shares, shares

TRACK_TYPES = ("spiral",)  # a checkpoint track, not ground to reach goals on: only with goal.mode spiral


def resolve_types(types: tuple[str, ...] | str, config: EnvConfig) -> tuple[str, ...]:
    """``"all"`` (the run's own terrain types) or a tuple of terrain types, checked (ValueError)."""
    if types == "all":
        types = tuple(config.terrain.types) if config.scene == "terrain" else ("flat",)
    unknown = [t for t in types if t not in TERRAIN_TYPES]
    if not types or unknown or isinstance(types, str):
        raise ValueError(
            f"--terrain-types: unknown type(s) {unknown or [types]}; give 'all' or a comma-separated "
            f"list of {list(TERRAIN_TYPES)}"
        )
    if config.goal.mode != "spiral" and any(t in TRACK_TYPES for t in types):
        raise ValueError(
            f"--terrain-types: {list(TRACK_TYPES)} need goal.mode spiral; this run's goals are {config.goal.mode!r}"
        )
    return tuple(types)


def check_levels(levels: tuple[float, ...]) -> tuple[float, ...]:
    """Difficulties in [0, 1] (ValueError naming the bad ones)."""
    bad = [v for v in levels if not 0.0 <= v <= 1.0]
    if bad or not levels:
        raise ValueError(f"--levels: difficulties must be in [0, 1], got {bad or list(levels)}")
    return tuple(float(v) for v in levels)


def cell_config(config: EnvConfig, types: tuple[str, ...], levels: tuple[float, ...], tiles: int = 1) -> EnvConfig:
    """The env with ``tiles`` tiles of each random type of ``types`` per difficulty level (one of each
    deterministic type); ``levels`` must be one difficulty, or evenly spaced from 0 (``level_groups``)."""
    terrain = dataclasses.replace(
        config.terrain,
        types=types,
        proportions=(1.0 / len(types),) * len(types),
        levels=len(levels),
        difficulty=max(levels),
        per_env=True,
        tiles_per_type=tiles,
    )
    if not np.allclose(terrain.level_difficulties, levels):
        raise ValueError(f"difficulties {levels} are not one value or evenly spaced from 0")
    return dataclasses.replace(config, scene="terrain", terrain=terrain)


def level_groups(levels: tuple[float, ...]) -> list[tuple[float, ...]]:
    """The difficulties as few atlases as possible: all in one when they are 0, d, 2d, ... (one env, one
    compile, one rollout), else one each."""
    ordered = tuple(sorted(set(levels)))
    n = len(ordered)
    if n > 1 and np.allclose(ordered, [ordered[-1] * i / (n - 1) for i in range(n)]):
        return [ordered]
    return [(d,) for d in ordered]


def evaluate(
    config: EnvConfig,
    rollout: Callable[..., dict],
    types: tuple[str, ...],
    levels: tuple[float, ...],
    episodes: int,
    seed: int,
    tiles: int = 1,
    rule: FailureRule = DEFAULT_RULE,
    on_cell: Callable[[str, float, HSAEnv, dict], None] | None = None,
    copies: int = 1,
) -> list[list[dict[str, Any]]]:
    """Per copy (``copies`` policies played at once), one row per (type, difficulty): success rate, mean net
    progress (m), mean final distance, episodes, and how fast the goals that were reached were reached
    (``success_speed_m_s``: start distance over the episode's time, the mean over those episodes; ``None``
    where none was; ``benchmarks.terrain.ladders`` reads it).

    ``rollout(env, keys, cells) -> traces`` plays one episode per key on the given env and cells
    (``train.episodes.rollout.rollout`` with the policy bound); with ``copies`` > 1 it is given ``copies``
    x the keys and plays block c with policy c: one env, one compile, one rollout, every copy on the same
    cells and keys. ``tiles``: tiles per random type and difficulty, the episodes of a cell spread over
    them by their keys. ``ended_by`` gives each termination reason's share, ``time_out``'s, and the
    time-outs' modes (``time_out/stuck`` ...: ``rule``, ``train.episodes.failures``). ``on_cell(type,
    difficulty, env, traces)`` is given each cell's traces of the first copy, e.g. to render one.
    """
    rows: list[list[dict[str, Any]]] = [[] for _ in range(copies)]
    for group in level_groups(levels):
        # every (type, level) cell plays the same goal keys: the cells differ by their ground only
        type_of = np.tile(np.repeat(np.arange(len(types)), episodes), len(group))
        level_of = np.repeat(np.arange(len(group)), episodes * len(types))
        keys = jnp.tile(jax.random.split(jax.random.PRNGKey(seed), episodes), (len(types) * len(group) * copies, 1))
        cells = jnp.asarray(np.tile(np.stack([type_of, level_of], axis=-1), (copies, 1)), jnp.int32)
        env = HSAEnv(cell_config(config, types, group, tiles), num_envs=len(type_of) * copies)
        traces = {k: np.asarray(v) for k, v in jax.device_get(rollout(env, keys, cells)).items()}
        n = len(type_of)
        for c in range(copies):
            own = {k: v[c * n : (c + 1) * n] for k, v in traces.items()}
            shown = on_cell if c == 0 else None
            rows[c] += _rows(own, env, types, group, (type_of, level_of), rule, shown)
    return [sorted(own, key=lambda row: (types.index(row["type"]), row["difficulty"])) for own in rows]


def _rows(
    traces: dict[str, np.ndarray],
    env: HSAEnv,
    types: tuple[str, ...],
    group: tuple[float, ...],
    of: tuple[np.ndarray, np.ndarray],
    rule: FailureRule,
    on_cell: Callable[[str, float, HSAEnv, dict], None] | None,
) -> list[dict[str, Any]]:
    """The rows of one level group's episodes (``of``: each episode's type and level index)."""
    type_of, level_of = of
    outcome, modes, rows = episode_outcomes(traces), episode_modes(traces, env.dt, rule), []
    for (level, difficulty), (i, name) in itertools.product(enumerate(group), enumerate(types)):
        mine = (type_of == i) & (level_of == level)
        if on_cell is not None:
            on_cell(name, difficulty, env, {k: v[mine] for k, v in traces.items()})
        rows.append(
            {
                "type": name,
                "difficulty": difficulty,
                "episodes": int(mine.sum()),
                "success_rate": float(outcome["success"][mine].mean()),
                "mean_progress_m": float(outcome["progress"][mine].mean()),
                "mean_final_distance": float(outcome["final_distance"][mine].mean()),
                "ended_by": {**ended_by(outcome["reasons"][mine]), **shares(modes[mine])},
                "modes": mode_shares(modes[mine]),
                "success_speed_m_s": _success_speed(outcome, mine, env.dt),
            }
        )
    return rows


def episode_outcomes(traces: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Per episode: reached its goal, net progress towards it (m), final distance (m), termination flags."""
    alive = traces["alive"].astype(bool)
    last = np.maximum(alive.sum(axis=1) - 1, 0)
    rows = np.arange(alive.shape[0])
    final = traces["distance"][rows, last]
    return {
        "success": traces["success"][rows, last] > 0.5,
        "progress": traces["start_distance"] - final,
        "final_distance": final,
        "reasons": traces["reasons"][rows, last] > 0.5,
        "steps": last + 1,
        "start_distance": np.asarray(traces["start_distance"]),
    }


def _success_speed(outcome: dict[str, np.ndarray], mine: np.ndarray, dt: float) -> float | None:
    """Mean speed (m/s, start distance over episode time) of a cell's episodes that reached their goal."""
    reached = mine & outcome["success"]
    if not reached.any():
        return None
    return float(np.mean(outcome["start_distance"][reached] / (outcome["steps"][reached] * dt)))


def ended_by(reasons: np.ndarray) -> dict[str, float]:
    """Share of episodes per termination reason (``termination.REASONS``, those that occur) and ``time_out``
    for the episodes that ended with none (they ran out of steps); ``reasons`` is (episodes, reasons) bool."""
    shares = {name: float(reasons[:, i].mean()) for i, name in enumerate(termination.REASONS) if reasons[:, i].any()}
    shares["time_out"] = float((~reasons.any(axis=1)).mean())
    return shares


def table(rows: list[dict[str, Any]]) -> str:
    """The rows as a text table: one line per type, success rate and progress per difficulty, and the mean."""
    levels = sorted({r["difficulty"] for r in rows})
    types = list(dict.fromkeys(r["type"] for r in rows))
    cell = {(r["type"], r["difficulty"]): r for r in rows}
    head = f"{'type':<18}" + "".join(f"{f'd={d:g} success':>15}{'progress m':>12}" for d in levels)
    lines = [head, "-" * len(head)]
    for name in types + ["mean"]:
        parts = []
        for d in levels:
            group = [cell[(t, d)] for t in types] if name == "mean" else [cell[(name, d)]]
            parts.append(
                f"{np.mean([g['success_rate'] for g in group]):>15.0%}"
                f"{np.mean([g['mean_progress_m'] for g in group]):>12.2f}"
            )
        lines.append(f"{name:<18}" + "".join(parts))
    return "\n".join(lines)


def write(rows: list[dict[str, Any]], header: dict[str, Any], out: Path) -> list[Path]:
    """``terrain_eval.json``, ``terrain_eval.png`` (success rate and progress per type and difficulty) and
    ``failure_modes.png`` (how each cell's episodes ended)."""
    out.mkdir(parents=True, exist_ok=True)
    path = out / "terrain_eval.json"
    path.write_text(json.dumps({**header, "rows": rows}, indent=1))
    return [path, terrain_grid(rows, out / "terrain_eval.png"), failure_modes(rows, out / "failure_modes.png")]
