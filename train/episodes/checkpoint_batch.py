"""Several checkpoints of one run evaluated in one rollout: ``python -m train.evaluate RUN --checkpoint A B ...``.

Each checkpoint's mean action (the arrays its policy file would hold, ``train.export``) plays the same
goals from the same keys (on terrain the same cells and tiles too), and all the checkpoints' episodes run
as one batch: one process, one compile and one pass on the device for K checkpoints, where K evaluations
would each pay the interpreter, the env's build, the compile and a rollout too small to fill a GPU. Each
checkpoint's result is written as its own evaluation's would be, in ``OUT/<checkpoint folder>/``
(``eval.json`` or ``terrain_eval.json``, and their plots). The mean action only: a stochastic evaluation
takes one checkpoint a call.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from hsa_mjx.deploy import policy_file
from hsa_mjx.sim.backend import for_one_env

from ..learners.registry import learner_of
from ..run import saved
from ..run.folder import portable
from . import terrain_eval
from .play import EvalSpec, checkpoint_of, episode_count, load_subject, terrain_plan, write_result
from .policy_sources import default_goal_range
from .rollout import rollout


def check_many(spec: EvalSpec, names: list[str]) -> None:
    """A ValueError where several checkpoints cannot be evaluated in one batch (before anything loads)."""
    if spec.run_dir is None:
        raise ValueError("several --checkpoint values need a RUN_DIR (a policy directory holds one policy)")
    terrain = spec.terrain_types is not None or spec.levels is not None
    if spec.stochastic or spec.workers > 1 or (spec.video and terrain):
        raise ValueError(
            "several checkpoints are evaluated in one batch with the mean action (on terrain without a video): "
            "leave out --stochastic, --workers (and --video with --terrain-types), or give one --checkpoint a call"
        )
    if spec.out is None:
        raise ValueError("several checkpoints need --out DIR: each is written to DIR/<checkpoint folder>/")
    if len(set(names)) != len(names):
        raise ValueError(f"--checkpoint names a checkpoint twice: {names}")


def _arrays(run_dir: Path, path: Path, observation_size: int, action_size: int) -> tuple[dict, int]:
    """(the deterministic policy's arrays, the checkpoint's env steps) of one checkpoint."""
    config, path, step = saved.open_run(run_dir, path)
    _, ts = saved.load_training_state(config, path, observation_size, action_size)
    arrays = learner_of(config).policy_arrays(config, ts, action_size)
    return jax.tree.map(jnp.asarray, arrays), step


def _apply(config):
    """``apply(arrays, obs, key) -> (action, {})``: the policy file's forward in JAX for the run's network."""
    network = learner_of(config).network_description(config)
    squash = policy_file.SQUASH[network["distribution_type"]]

    def apply(arrays: dict, obs: jax.Array, key: jax.Array):
        action = policy_file.forward(
            arrays, obs, network["activation"], squash, float(network["observation_clip"]), xp=jnp
        )
        return action, {}

    return apply


def evaluate_many(spec: EvalSpec, names: list[str]) -> list[dict]:
    """Evaluate the run's checkpoints ``names`` (steps or folders) in one rollout, each on the same
    ``spec.episodes`` goals; returns each one's ``eval.json`` content, in the order given."""
    check_many(spec, names)
    spec = dataclasses.replace(spec, backend=for_one_env(spec.backend))  # auto: C MuJoCo on a CPU
    run_dir, episodes = Path(spec.run_dir), episode_count(spec, False)
    paths = [checkpoint_of(run_dir, name) for name in names]
    batch = dataclasses.replace(spec, checkpoint=str(paths[0]), episodes=episodes * len(paths))
    config, env, _, _, out = load_subject(batch)  # the env sized for the whole batch (Warp's contact buffer)
    loaded = [_arrays(run_dir, path, env.observation_size, env.action_size) for path in paths]
    if spec.terrain_types is not None or spec.levels is not None:
        return _by_terrain(spec, config, paths, loaded, out)
    params = jax.tree.map(lambda *xs: jnp.repeat(jnp.stack(xs), episodes, axis=0), *[a for a, _ in loaded])
    steps = spec.steps or config.env.termination.max_episode_steps
    goal_range = spec.goal_range or default_goal_range(config)
    keys = jnp.tile(jax.random.split(jax.random.PRNGKey(spec.seed), episodes), (len(paths), 1))
    traces = rollout(env, _apply(config), keys, jnp.asarray(goal_range, jnp.float32), steps, params=params)
    traces = {k: np.asarray(v) for k, v in jax.device_get(traces).items()}
    results = []
    for i, (path, (_, step)) in enumerate(zip(paths, loaded)):
        own = {k: v[i * episodes : (i + 1) * episodes] for k, v in traces.items()}
        header = {"checkpoint": portable(path), "step": step}
        if spec.overrides:
            header["env_overrides"] = dict(spec.overrides)
        results.append(write_result(spec, config, env, header, own, (goal_range, steps), out / path.name))
    return results


def _by_terrain(spec: EvalSpec, config, paths: list[Path], loaded: list, out: Path) -> list[dict]:
    """The checkpoints per terrain type and difficulty, as one rollout; each one's ``terrain_eval.json``."""
    plan, count = terrain_plan(spec, config), len(paths)
    stacked = jax.tree.map(lambda *xs: jnp.stack(xs), *[a for a, _ in loaded])

    def play(env, keys: jax.Array, cells: jax.Array) -> dict:
        params = jax.tree.map(lambda x: jnp.repeat(x, keys.shape[0] // count, axis=0), stacked)
        return rollout(env, _apply(config), keys, plan.goal_range, plan.steps, params=params, cells=cells)

    rule, tiles = spec.failure_rule(), spec.tiles
    copies = terrain_eval.evaluate(
        plan.env_config, play, plan.types, plan.levels, plan.episodes, spec.seed, tiles, rule, copies=count
    )
    results = []
    for path, (_, step), rows in zip(paths, loaded, copies):
        header = {"checkpoint": portable(path), "step": step, **plan.header}
        if spec.overrides:
            header["env_overrides"] = dict(spec.overrides)
        written = terrain_eval.write(rows, header, out / path.name)
        results.append({**header, "rows": rows, "files": [str(p) for p in written]})
    return results
