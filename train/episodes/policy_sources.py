"""Where a policy to evaluate comes from: a run's checkpoint or a policy directory, with the env it runs in.

Both give ``(config, env, policy fn, ...)``: the training config, an env rebuilt from it for
evaluation (``evaluation_env_config``: spiral episodes from the origin, on the physics backend asked
for, with ``env.KEY=VALUE`` overrides), and ``policy(obs, key) -> (action, extras)`` in JAX. Used by
``python -m train.evaluate``, the per-terrain evaluation and ``benchmarks.robustness.score``.
"""

from __future__ import annotations

import hsa_mjx.sim.backend  # noqa: F401  (MJX imported quietly, before Brax imports it)

# isort: split
import dataclasses
import functools
from pathlib import Path

import jax
import jax.numpy as jnp

from hsa_mjx.config import EnvConfig
from hsa_mjx.deploy import policy_file
from hsa_mjx.task.env import HSAEnv

from ..config import TrainConfig, apply_overrides, from_dict, to_dict
from ..learners.registry import learner_of
from ..run import saved


def evaluation_env_config(config: EnvConfig, backend: str | None = None) -> EnvConfig:
    """The env that evaluates a run: its training env, with spiral episodes started at the origin
    as in the original (``goal.track_starts`` is a training aid), on ``backend`` when given."""
    physics = config.physics if backend is None else dataclasses.replace(config.physics, backend=backend)
    return dataclasses.replace(config, goal=dataclasses.replace(config.goal, track_starts=0), physics=physics)


def sizing_env_config(config: EnvConfig) -> EnvConfig:
    """``config`` on one tile of its first terrain type at one level (at most one goal site): the same
    observation and action sizes, for an evaluation that builds its own env per cell (per terrain type and
    difficulty) and needs this one for the policy's sizes only. Its build skips the run's tile pool and its
    goal sites' distance fields: 3 s against 29 s for the rough task on a CPU. A plane scene is kept."""
    if config.scene != "terrain":
        return config
    terrain = config.terrain
    reach = dataclasses.replace(terrain.reachability, goal_sites=min(terrain.reachability.goal_sites, 1))
    one = dataclasses.replace(
        terrain, types=terrain.types[:1], proportions=(1.0,), levels=1, tiles_per_type=1, reachability=reach
    )
    return dataclasses.replace(config, terrain=one)


def _evaluation_env(config: EnvConfig, backend: str | None, num_envs: int, sizes_only: bool) -> HSAEnv:
    """The env a policy is evaluated on (``evaluation_env_config``), or with ``sizes_only`` its sizing env."""
    config = evaluation_env_config(config, backend)
    return HSAEnv(sizing_env_config(config) if sizes_only else config, num_envs=num_envs)


def load_policy(
    run_dir: Path,
    checkpoint_path: Path | None = None,
    deterministic: bool = True,
    backend: str | None = None,
    num_envs: int = 1,
    overrides: tuple[str, ...] = (),
    sizes_only: bool = False,
):
    """(config, env, policy fn, checkpoint path, step) of a run: the mean action, or sampled as in training;
    ``backend`` replaces the run's physics backend, ``num_envs`` sizes Warp's shared contact buffer,
    ``overrides`` (``env.KEY=VALUE``, ``env_overrides``) change the env it is evaluated on; ``sizes_only``:
    the env is ``sizing_env_config``'s (an evaluation per terrain cell builds its own)."""
    config, path, step = saved.open_run(run_dir, checkpoint_path, lambda data: env_overrides(data, overrides))
    env = _evaluation_env(config.env, backend, num_envs, sizes_only)
    networks, ts = saved.load_training_state(config, path, env.observation_size, env.action_size)
    policy = learner_of(config).inference_fn(networks, ts, deterministic)
    return config, env, policy, path, step


def check_env_overrides(overrides: tuple[str, ...] | list[str]) -> None:
    """Refuse ``--set`` keys an evaluation may not change: goals, terrain, termination, reward, physics,
    randomisation and observation noise may change; the observation's layout (the policy's input) and
    the ppo, run and curricula sections may not."""
    for item in overrides:
        key = item.split("=", 1)[0].strip()
        layout = key.startswith("env.observation") and not key.startswith("env.observation.noise.")
        if not key.startswith("env.") or layout:
            raise ValueError(
                f"evaluate --set {key!r}: only env keys may change (env.goal.*, env.terrain.*, "
                "env.randomization.*, env.observation.noise.*, ...), not the observation's layout "
                "(env.observation.*) or the ppo, run and curricula sections"
            )


def env_overrides(data: dict, overrides: tuple[str, ...] | list[str]) -> dict:
    """A run's config data with ``--set env.KEY=VALUE`` applied (``check_env_overrides`` first); goals
    other than radial turn the goal curriculum off (it only draws training goals from its range)."""
    check_env_overrides(overrides)
    data = apply_overrides(data, list(overrides))
    if data["env"].get("goal", {}).get("mode", "radial") != "radial":
        data = apply_overrides(data, ["goal_curriculum.enabled=false"])
    return data


def default_goal_range(config: TrainConfig) -> tuple[float, float]:
    """The radial goal range to evaluate on: the goal curriculum's target, or the range training used."""
    if config.goal_curriculum.enabled:
        return tuple(config.goal_curriculum.target_range)
    return tuple(config.env.goal.radial_range)


def shipped_policy_apply(policy: policy_file.NumpyPolicy):
    """``apply(params, obs, key) -> (action, {})``: the policy file's deterministic forward in JAX."""
    net = policy.meta["network"]

    def apply(params: dict, obs: jax.Array, key: jax.Array):
        return policy_file.forward(
            params, obs, net["activation"], net["output"], float(net["observation_clip"]), xp=jnp
        ), {}

    return apply


def load_shipped_policy(
    directory: Path,
    backend: str | None = None,
    num_envs: int = 1,
    overrides: tuple[str, ...] = (),
    sizes_only: bool = False,
):
    """(config, env, policy fn, policy) of a policy directory: the env rebuilt from its policy.json (on
    ``backend`` when given, with ``env.KEY=VALUE`` ``overrides``; ``sizes_only`` as ``load_policy``), the
    network from its policy.npz."""
    check_env_overrides(overrides)
    policy = policy_file.load_policy(directory)
    try:
        config = from_dict(policy.meta["config"])
    except (KeyError, ValueError) as err:
        raise ValueError(
            f"policy {directory}: its {policy_file.META_FILE} holds no usable training config ({err})"
        ) from err
    if overrides:
        config = from_dict(env_overrides(to_dict(config), overrides))
    env = _evaluation_env(config.env, backend, num_envs, sizes_only)
    if (env.observation_size, env.action_size) != (policy.observation_size, policy.action_size):
        raise ValueError(
            f"policy {directory} maps {policy.observation_size} observations to {policy.action_size} "
            f"actions; its env has {env.observation_size} and {env.action_size}"
        )
    params = jax.tree.map(jnp.asarray, policy.params)
    return config, env, functools.partial(shipped_policy_apply(policy), params), policy
