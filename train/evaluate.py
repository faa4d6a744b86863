"""Evaluate a trained run: ``python -m train.evaluate RUN_DIR [--episodes N] [--video]``.

Loads the run's config and latest checkpoint, runs N episodes at once on the device with the
deterministic policy (its mean action; ``--stochastic`` samples as in training; each env plays
exactly one episode), prints success rate, mean final distance, mean speed and how the episodes
ended (termination reasons, ``not_finished`` at the step cap), and writes the diagnostic plots
(and optionally a GIF/MP4) into
``RUN_DIR/eval/``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from hsa_mjx import curriculum as cur
from hsa_mjx import observation, termination
from hsa_mjx.config import EnvConfig
from hsa_mjx.env import HSAEnv
from train import checkpoint
from train import config as tcfg


def evaluation_env_config(config: EnvConfig) -> EnvConfig:
    """The env that evaluates a run: its training env, with spiral episodes started at the origin
    as in the original (``goal.track_starts`` is a training aid)."""
    return dataclasses.replace(config, goal=dataclasses.replace(config.goal, track_starts=0))


def load_policy(run_dir: Path, checkpoint_path: Path | None = None, deterministic: bool = True):
    """(config, env, policy fn, checkpoint path, step) of a run: the mean action, or sampled as in training."""
    from brax.training.agents.ppo import networks as ppo_networks
    path = checkpoint_path or checkpoint.latest(run_dir)
    meta = checkpoint.read_meta(path)
    config = tcfg.from_dict(meta["config"])
    env = HSAEnv(evaluation_env_config(config.env))
    networks, ts = load_training_state(config, path, env.observation_size, env.action_size)
    policy = ppo_networks.make_inference_fn(networks)((ts.normalizer, ts.params.policy), deterministic=deterministic)
    return config, env, policy, path, int(meta["step"])


def load_training_state(config: tcfg.TrainConfig, path: Path, observation_size: int, action_size: int):
    """(PPO networks, training state) of the checkpoint at ``path`` written with ``config``."""
    from train.ppo import init_training_state, make_networks
    networks = make_networks(config, observation_size, action_size)
    template_ts = init_training_state(config, networks, jax.random.PRNGKey(0), observation_size)
    template = {"training_state": template_ts, "curriculum": cur.init(config.curriculum),
                "rng": jax.random.PRNGKey(0)}
    restored = checkpoint.load(path, template)
    return networks, jax.tree.map(jnp.asarray, restored["training_state"])


def default_goal_range(config: tcfg.TrainConfig) -> tuple[float, float]:
    """The radial goal range to evaluate on: the curriculum's target, or the range training used."""
    if config.curriculum.enabled:
        return tuple(config.curriculum.target_range)
    return tuple(config.env.goal.radial_range)


def rollout(env: HSAEnv, policy, keys: jax.Array, goal_range: jax.Array, steps: int) -> dict[str, jax.Array]:
    """Play one episode per key (frozen after it ends); return per-step traces, shape (N, T, ...)."""
    idx = env.index

    def one(key):
        state = env.reset_with_goal_range(key, goal_range)

        def step(carry, k_act):
            s, alive = carry
            action, _ = policy(s.obs, k_act)
            ns = env.step(s, action)
            ns = jax.tree.map(lambda new, old: jnp.where(alive, new, old), ns, s)
            data = ns.pipeline_state.physics
            trace = {"action": action, "alive": alive, "xy": observation.robot_xy(data, idx),
                     "joint_pos": observation.joint_positions(data, idx),
                     "joint_vel": observation.joint_velocities(data, idx), "qpos": data.qpos,
                     "goal": ns.pipeline_state.task.goal_xy, "distance": ns.metrics["distance_to_goal"],
                     "success": ns.metrics["termination/goal_reached"], "done": ns.done,
                     "checkpoint": ns.metrics["checkpoint_index"],
                     "reasons": jnp.stack([ns.metrics[f"termination/{r}"] for r in termination.REASONS])}
            return (ns, alive & (ns.done < 0.5)), trace

        act_keys = jax.random.split(jax.random.fold_in(key, 1), steps)
        (_, _), traces = jax.lax.scan(step, (state, jnp.ones((), bool)), act_keys)
        traces["start_xy"] = observation.robot_xy(state.pipeline_state.physics, idx)
        traces["start_distance"] = state.metrics["distance_to_goal"]
        return traces

    return jax.jit(jax.vmap(one))(keys)


def summarize(traces: dict[str, np.ndarray], dt: float, checkpoints: bool = False) -> dict[str, Any]:
    """Success rate, mean final distance and mean speed over the evaluated episodes (spiral: checkpoints per episode)."""
    alive = traces["alive"].astype(bool)
    length = alive.sum(axis=1)
    last = np.maximum(length - 1, 0)
    rows = np.arange(alive.shape[0])
    final_xy, final_distance = traces["xy"][rows, last], traces["distance"][rows, last]
    success = traces["success"][rows, last] > 0.5
    displacement = np.linalg.norm(final_xy - traces["start_xy"], axis=-1)
    speed = displacement / np.maximum(length * dt, dt)
    ended = traces["done"][rows, last] > 0.5
    reasons = traces["reasons"][rows, last] > 0.5  # (episodes, reasons)
    ends = {f"termination/{r}": float(np.mean(ended & reasons[:, i])) for i, r in enumerate(termination.REASONS)}
    # net progress towards the goal; with spiral checkpoints the goal moves, so count those instead
    collected = traces["checkpoint"][rows, last]
    progress = {"mean_checkpoints_collected": float(collected.mean()),
                "checkpoints_per_episode": [int(c) for c in collected]} if checkpoints \
        else {"mean_progress_m": float(np.mean(traces["start_distance"] - final_distance))}
    return {"episodes": int(alive.shape[0]), "success_rate": float(success.mean()),
            "mean_final_distance": float(final_distance.mean()), "mean_speed_m_per_s": float(speed.mean()),
            "mean_start_distance": float(traces["start_distance"].mean()), **progress,
            "mean_episode_steps": float(length.mean()), **{k: v for k, v in ends.items() if v > 0},
            "not_finished": float(np.mean(~ended))}


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="python -m train.evaluate", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("run_dir", help="a run directory written by python -m train")
    parser.add_argument("--episodes", type=int, default=16)
    parser.add_argument("--steps", type=int, default=0, help="max steps per episode (0: the env's max_episode_steps)")
    parser.add_argument("--goal-range", type=float, nargs=2, default=None, metavar=("MIN", "MAX"),
                        help="radial goal distance range (default: the curriculum's target range, or "
                             "the env's goal.radial_range when the curriculum is off)")
    parser.add_argument("--stochastic", action="store_true",
                        help="sample actions from the policy as in training (default: its mean action)")
    parser.add_argument("--video", action="store_true", help="render the first episode to eval/episode.gif")
    parser.add_argument("--seed", type=int, default=1)
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``python -m train.evaluate``."""
    args = parse_args(argv)
    try:
        if args.episodes < 1:
            raise ValueError(f"--episodes must be >= 1, got {args.episodes}")
        run_dir = Path(args.run_dir)
        if not run_dir.is_dir():
            raise FileNotFoundError(f"run directory not found: {run_dir}")
        config, env, policy, path, step = load_policy(run_dir, deterministic=not args.stochastic)
    except (ValueError, FileNotFoundError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    goal_range = args.goal_range or default_goal_range(config)
    steps = args.steps or config.env.termination.max_episode_steps
    keys = jax.random.split(jax.random.PRNGKey(args.seed), args.episodes)
    traces = jax.device_get(rollout(env, policy, keys, jnp.asarray(goal_range, jnp.float32), steps))
    traces = {k: np.asarray(v) for k, v in traces.items()}
    radial = config.env.goal.mode == "radial"  # other goal modes do not use the range
    result = {"checkpoint": str(path), "step": step, "goal_range": list(goal_range) if radial else None,
              "policy": "stochastic" if args.stochastic else "deterministic", "max_steps": steps,
              **summarize(traces, env.dt, checkpoints=config.env.goal.mode == "spiral")}
    out = run_dir / "eval"
    out.mkdir(exist_ok=True)
    from train import diagnostics
    written = diagnostics.write_all(traces, env, out, video=args.video)
    result["files"] = [str(p) for p in written]
    (out / "eval.json").write_text(json.dumps(result, indent=1))
    for key, value in result.items():
        if key != "files":
            print(f"{key}: {value:.4g}" if isinstance(value, float) else f"{key}: {value}")
    print(f"wrote {len(written)} files to {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
