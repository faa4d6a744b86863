"""What ``python -m train.evaluate`` does, as a function: ``evaluate(EvalSpec(policy="flat", ...))`` plays the
episodes of the run or policy it names and writes their files; the command (``train.evaluate``) parses
its flags into the spec.

The command itself is ``train.evaluate`` (it sets up offscreen rendering before this module,
which imports MuJoCo, is imported). The episodes are played by ``train.episodes.rollout``, per terrain
type and difficulty by ``train.episodes.terrain_eval``.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Literal

import jax
import jax.numpy as jnp
import numpy as np

from hsa_mjx.deploy import policy_file
from hsa_mjx.sim.backend import for_one_env
from hsa_mjx.task.env import HSAEnv

from ..config import TrainConfig, assignments
from ..run import checkpoint
from ..run.folder import portable
from . import diagnostics, host_workers, terrain_eval
from .failures import DEFAULT_RULE, FailureRule
from .policy_sources import (
    default_goal_range,
    evaluation_env_config,
    load_policy,
    load_shipped_policy,
)
from .rollout import rollout, summarize

CPU_EPISODES, CPU_STEPS = 4, 1000  # --policy defaults: a CPU evaluates them in about a minute


TERRAIN_SEED_OFFSET = 1000  # --terrain-seed's default: the run's terrain seed + this (tiles not trained on)


@dataclasses.dataclass(frozen=True)
class EvalSpec:
    """What to evaluate and how: ``python -m train.evaluate``'s arguments as a value. Give ``run_dir`` or
    ``policy``; the rest have the command's defaults.

    ``overrides`` maps dotted env keys to values (``{"env.goal.radial_range": [4.0, 4.5]}``: the
    command's ``--set``); ``terrain_types`` (``"all"``: the run's own, or a tuple of names) and
    ``levels`` (a tuple of difficulties in [0, 1]) evaluate per terrain type and difficulty instead;
    there ``video`` renders the first episode of ``video_cell`` (type, difficulty; default the first type
    at the top difficulty)."""

    run_dir: str | None = None
    policy: str | None = None
    episodes: int | None = None
    steps: int | None = None
    goal_range: tuple[float, float] | None = None
    stochastic: bool = False
    video: bool = False
    out: str | None = None
    seed: int = 1
    overrides: Mapping[str, Any] = dataclasses.field(default_factory=dict)
    backend: str = "auto"
    terrain_types: tuple[str, ...] | Literal["all"] | None = None
    levels: tuple[float, ...] | None = None
    terrain_seed: int | None = None
    tiles: int = 1
    workers: int = 1
    checkpoint: str | None = None
    video_cell: tuple[str, float] | None = None
    stuck_window_s: float = DEFAULT_RULE.window_s
    stuck_distance_m: float = DEFAULT_RULE.stuck_m

    def failure_rule(self) -> FailureRule:
        """How a time-out's mode is told (``train.episodes.failures``; ValueError for a bad window)."""
        return FailureRule(self.stuck_window_s, self.stuck_distance_m)

    def override_items(self) -> tuple[str, ...]:
        """``overrides`` as ``env.KEY=VALUE`` strings (what the env loaders apply)."""
        return tuple(assignments(self.overrides))


def check_spec(spec: EvalSpec) -> None:
    """A ValueError naming a field of the wrong type (before anything loads)."""
    if not isinstance(spec.overrides, Mapping):
        raise ValueError(
            f"EvalSpec.overrides must map env keys to values, e.g. {{'env.goal.radial_range': [4.0, 4.5]}}; "
            f"got {spec.overrides!r}"
        )
    levels, types = spec.levels, spec.terrain_types
    if levels is not None and (not isinstance(levels, tuple) or not all(isinstance(v, (int, float)) for v in levels)):
        raise ValueError(f"EvalSpec.levels must be a tuple of difficulties in [0, 1], e.g. (0.0, 1.0); got {levels!r}")
    names = isinstance(types, tuple) and all(isinstance(t, str) for t in types)
    if types is not None and types != "all" and not names:
        raise ValueError(f"EvalSpec.terrain_types must be 'all' or a tuple of terrain type names; got {types!r}")


def load_subject(args: EvalSpec) -> tuple[TrainConfig, HSAEnv, Any, dict, Path]:
    """(config, env, policy fn, result header, output folder) of the run or policy the arguments name; for
    an evaluation per terrain cell the env only sizes the policy (``policy_sources.sizing_env_config``)."""
    check_spec(args)
    args.failure_rule()
    if args.video_cell is not None and not (args.video and (args.terrain_types or args.levels)):
        raise ValueError("--video-cell picks a terrain evaluation's rendered cell: add --video and --terrain-types")
    if (args.run_dir is None) == (args.policy is None):
        raise ValueError("give either a RUN_DIR or --policy NAME_OR_DIR (one of them)")
    if args.episodes is not None and args.episodes < 1:
        raise ValueError(f"--episodes must be >= 1, got {args.episodes}")
    if not 1 <= args.tiles <= 256:
        raise ValueError(f"--tiles must be between 1 and 256, got {args.tiles}")
    check_workers(args)
    by_cell = args.terrain_types is not None or args.levels is not None  # its env per cell: this one sizes it
    if args.policy is not None:
        if args.checkpoint is not None:
            raise ValueError("--checkpoint picks one of a RUN_DIR's checkpoints: a policy directory holds one policy")
        if args.stochastic:
            raise ValueError("--stochastic needs a RUN_DIR: a policy directory holds only the deterministic policy")
        directory = policy_file.locate(args.policy)
        config, env, policy, shipped = load_shipped_policy(
            directory, args.backend, episode_count(args, True), args.override_items(), by_cell
        )
        out = Path(args.out) if args.out else Path("runs") / f"eval_{directory.resolve().name}"
        header = {
            "policy_dir": portable(directory),
            "source": shipped.meta.get("source", {}),
            "step": shipped.meta.get("source", {}).get("env_steps"),
            **({"env_overrides": dict(args.overrides)} if args.overrides else {}),
        }
        return config, env, policy, header, out
    config, env, policy, path, step = load_policy(
        Path(args.run_dir),
        checkpoint_of(Path(args.run_dir), args.checkpoint),
        deterministic=not args.stochastic,
        backend=args.backend,
        num_envs=episode_count(args, False),
        overrides=args.override_items(),
        sizes_only=by_cell,
    )
    header = {
        "checkpoint": portable(path),
        "step": step,
        **({"env_overrides": dict(args.overrides)} if args.overrides else {}),
    }
    return config, env, policy, header, Path(args.out) if args.out else Path(args.run_dir) / "eval"


def checkpoint_of(run_dir: Path, which: str | None) -> Path | None:
    """The checkpoint ``--checkpoint`` names: a path, or a step the run saved (``40`` is ``checkpoints/
    step_000000000040``); None: the newest readable one. FileNotFoundError naming the saved steps."""
    if which is None:
        return None
    path = checkpoint.checkpoint_dir(run_dir) / f"step_{int(which):012d}" if which.isdigit() else Path(which)
    if not path.is_dir():
        saved = [int(p.name.split("_")[-1]) for p in checkpoint.list_checkpoints(run_dir)]
        raise FileNotFoundError(f"--checkpoint {which}: no checkpoint {path}; {run_dir} saved steps {saved}")
    return path


def check_workers(args: EvalSpec) -> None:
    """A ValueError when ``--workers`` is not a positive count or asks for processes where they cannot help
    (MJX batches the episodes on its device; the per-terrain evaluation plays its cells in one batch)."""
    if args.workers < 1:
        raise ValueError(f"--workers must be >= 1, got {args.workers}")
    if args.workers > 1 and for_one_env(args.backend) != "c":
        raise ValueError(
            f"--workers plays C MuJoCo episodes in processes; this evaluation runs on {args.backend!r} "
            "(add --backend c, or leave --workers out)"
        )
    if args.workers > 1 and (args.terrain_types is not None or args.levels is not None):
        raise ValueError("--workers applies to flat evaluations; leave it out with --terrain-types/--levels")


def check_goal_range(goal_range: list[float] | None, config: TrainConfig) -> None:
    """A ValueError when ``--goal-range`` is out of order or the env's goals are not radial (it would be ignored)."""
    if goal_range is None:
        return
    low, high = goal_range
    if not 0.0 < low <= high:
        raise ValueError(f"--goal-range MIN MAX must satisfy 0 < MIN <= MAX, got {low:g} {high:g}")
    if config.env.goal.mode != "radial":
        raise ValueError(
            f"--goal-range sets radial goal distances, but this env's goals are "
            f"{config.env.goal.mode!r} (env.goal.mode); add --set env.goal.mode=radial"
        )


def episode_count(args: EvalSpec, shipped: bool) -> int:
    """Episodes to play: as asked, else 16 for a run and CPU_EPISODES for a shipped policy."""
    return args.episodes or (CPU_EPISODES if shipped else 16)


def evaluate(spec: EvalSpec) -> dict:
    """Play the episodes ``spec`` asks for and write their files; returns what the JSON file holds
    (``eval.json``, or ``terrain_eval.json`` with ``rows`` per terrain type and difficulty).

    Raises:
        ValueError, FileNotFoundError: a bad argument, a missing run or policy (before any compile).
    """
    spec = dataclasses.replace(spec, backend=for_one_env(spec.backend))  # auto: C MuJoCo on a CPU
    config, env, policy, header, out = load_subject(spec)
    check_goal_range(spec.goal_range, config)
    if spec.terrain_types is not None or spec.levels is not None:
        return by_terrain(spec, config, policy, header, out)
    shipped = spec.policy is not None
    episodes = episode_count(spec, shipped)
    limit = config.env.termination.max_episode_steps
    steps = spec.steps or (min(CPU_STEPS, limit) if shipped else limit)
    goal_range = spec.goal_range or default_goal_range(config)
    keys = jax.random.split(jax.random.PRNGKey(spec.seed), episodes)
    if spec.workers > 1:
        traces = host_workers.play(load_subject, spec, np.asarray(keys), goal_range, steps, spec.workers)
    else:
        traces = jax.device_get(rollout(env, policy, keys, jnp.asarray(goal_range, jnp.float32), steps))
        traces = {k: np.asarray(v) for k, v in traces.items()}
    return write_result(spec, config, env, header, traces, (goal_range, steps), out)


def write_result(
    spec: EvalSpec, config: TrainConfig, env: HSAEnv, header: dict, traces: dict, played: tuple, out: Path
) -> dict:
    """A flat evaluation's ``eval.json`` and plots in ``out`` from its episodes' ``traces``; ``played``:
    the (goal range, steps) they were played with. Returns what ``eval.json`` holds."""
    goal_range, steps = played
    radial = config.env.goal.mode == "radial"  # other goal modes do not use the range
    result = {
        **header,
        "goal_range": list(goal_range) if radial else None,
        "policy": "stochastic" if spec.stochastic else "deterministic",
        "max_steps": steps,
        "physics": "c_mujoco" if env.physics_backend == "c" else f"mjx_{env.physics_backend}",
        **summarize(traces, env.dt, checkpoints=config.env.goal.mode == "spiral", rule=spec.failure_rule()),
    }
    out.mkdir(parents=True, exist_ok=True)
    written = diagnostics.write_all(traces, env, out, video=spec.video)
    result["files"] = [str(p) for p in written]
    (out / "eval.json").write_text(json.dumps(result, indent=1))
    return result


@dataclasses.dataclass(frozen=True)
class TerrainPlan:
    """A terrain evaluation's cells and episodes as the arguments ask them (``terrain_plan``)."""

    types: tuple[str, ...]
    levels: tuple[float, ...]
    episodes: int
    steps: int
    goal_range: jax.Array
    env_config: Any  # the run's env on unseen tiles (terrain seed), for the evaluation's backend
    header: dict  # what terrain_eval.json records of them


def terrain_plan(args: EvalSpec, config: TrainConfig) -> TerrainPlan:
    """The types, difficulties, episodes, steps, goals and unseen tiles of a terrain evaluation (ValueError
    for an unknown type or a difficulty out of range)."""
    types = terrain_eval.resolve_types(args.terrain_types or "all", config.env)
    levels = terrain_eval.check_levels(args.levels or (config.env.terrain.difficulty,))
    episodes = episode_count(args, args.policy is not None)
    steps = args.steps or config.env.termination.max_episode_steps
    goal_range = jnp.asarray(args.goal_range or default_goal_range(config), jnp.float32)
    trained_on = config.env.terrain.seed
    terrain_seed = trained_on + TERRAIN_SEED_OFFSET if args.terrain_seed is None else args.terrain_seed
    env_config = evaluation_env_config(config.env, args.backend)
    env_config = dataclasses.replace(env_config, terrain=dataclasses.replace(env_config.terrain, seed=terrain_seed))
    rule = args.failure_rule()
    header = {
        "goal_range": [float(v) for v in goal_range],
        "max_steps": steps,
        "policy": "stochastic" if args.stochastic else "deterministic",
        "episodes_per_cell": episodes,
        "terrain_seed": terrain_seed,
        "tiles_per_cell": args.tiles,
        "training_terrain_seed": trained_on,
        "training_seed": config.run.seed,
        "failure_rule": {"window_s": rule.window_s, "stuck_m": rule.stuck_m},
    }
    return TerrainPlan(types, levels, episodes, steps, goal_range, env_config, header)


def by_terrain(args: EvalSpec, config: TrainConfig, policy, header: dict, out: Path) -> dict:
    """``terrain_types`` / ``levels``: success and progress per terrain type and difficulty
    (``terrain_eval.json``'s content, with the files written)."""
    plan = terrain_plan(args, config)
    types, levels = plan.types, plan.levels

    def play(env: HSAEnv, keys: jax.Array, cells: jax.Array) -> dict:
        return rollout(env, policy, keys, plan.goal_range, plan.steps, cells=cells)

    rule, shown = args.failure_rule(), []
    chosen = args.video_cell or (types[0], max(levels))
    if args.video_cell is not None and (chosen[0] not in types or float(chosen[1]) not in levels):
        cells = f"types {list(types)}, levels {list(levels)}"
        raise ValueError(f"--video-cell {chosen[0]}:{chosen[1]:g} is no evaluated cell: {cells}")

    def render(name: str, difficulty: float, env: HSAEnv, traces: dict) -> None:
        if args.video and (name, difficulty) == tuple(chosen):
            shown.append(diagnostics.render_gif(traces, env, out / f"episode_{name}_{difficulty:g}.gif"))

    out.mkdir(parents=True, exist_ok=True)
    episodes, seed = plan.episodes, args.seed
    rows = terrain_eval.evaluate(plan.env_config, play, types, levels, episodes, seed, args.tiles, rule, render)[0]
    header = {**header, **plan.header}
    written = terrain_eval.write(rows, header, out) + shown
    return {**header, "rows": rows, "files": [str(p) for p in written]}
