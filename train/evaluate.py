"""Evaluate a trained run or a shipped policy on the device.

``python -m train.evaluate RUN_DIR [--episodes N] [--video]``: loads the run's config and latest
checkpoint and runs N episodes at once with the deterministic policy (its mean action;
``--stochastic`` samples as in training; each env plays exactly one episode).
``python -m train.evaluate --policy NAME_OR_DIR [--episodes N] [--video]``: the same for a policy
directory (``policies/<NAME>`` or a path; ``hsa_mjx/deploy/policy.py``), its env rebuilt from its
``policy.json`` and its network run from its ``policy.npz``; defaults sized for a CPU (4 episodes
of at most 1,000 steps).

Prints success rate, mean final distance, mean speed and how the episodes ended (termination
reasons, ``time_out`` at the env's episode limit, ``not_finished`` at a shorter step cap), and
writes eval.json, the diagnostic plots (and with ``--video`` a GIF) into ``--out`` (default
``RUN_DIR/eval/`` or ``runs/eval_<NAME>/``).

``--set env.KEY=VALUE`` (repeatable) evaluates on a changed env, e.g. goals farther than training's
(``--set env.goal.radial_range=[4.0,4.5]``); the observation cannot change.

``--terrain-types all|T1,T2 --levels 0,0.5,1``: instead, ``--episodes`` episodes per terrain type
and difficulty, printed as a table of success rate and net progress and written to
terrain_eval.json and terrain_eval.png (``train/terrain_eval.py``).
"""

from __future__ import annotations

import argparse
import ctypes.util
import dataclasses
import functools
import json
import os
import sys
from pathlib import Path
from typing import Any

# --video renders offscreen; mujoco picks its GL backend when first imported (below, via hsa_mjx.task.env).
# EGL only where its library exists: mujoco's import fails under MUJOCO_GL=egl on a machine without it.
if ctypes.util.find_library("EGL"):
    os.environ.setdefault("MUJOCO_GL", "egl")

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from hsa_mjx.config import BACKENDS, EnvConfig  # noqa: E402
from hsa_mjx.curricula import goal as cur  # noqa: E402
from hsa_mjx.deploy import policy as pol  # noqa: E402
from hsa_mjx.sim import backend  # noqa: E402
from hsa_mjx.sim.backend import for_one_env  # noqa: E402
from hsa_mjx.task import observation, termination  # noqa: E402
from hsa_mjx.task.env import HSAEnv  # noqa: E402
from hsa_mjx.task.params import FREE_CELL, EnvParams  # noqa: E402
from train import checkpoint  # noqa: E402
from train import config as tcfg  # noqa: E402

CPU_EPISODES, CPU_STEPS = 4, 1000  # --policy defaults: a CPU evaluates them in about a minute


def evaluation_env_config(config: EnvConfig, backend: str | None = None) -> EnvConfig:
    """The env that evaluates a run: its training env, with spiral episodes started at the origin
    as in the original (``goal.track_starts`` is a training aid), on ``backend`` when given."""
    physics = config.physics if backend is None else dataclasses.replace(config.physics, backend=backend)
    return dataclasses.replace(config, goal=dataclasses.replace(config.goal, track_starts=0), physics=physics)


def load_policy(
    run_dir: Path,
    checkpoint_path: Path | None = None,
    deterministic: bool = True,
    backend: str | None = None,
    num_envs: int = 1,
    overrides: tuple[str, ...] = (),
):
    """(config, env, policy fn, checkpoint path, step) of a run: the mean action, or sampled as in training;
    ``backend`` replaces the run's physics backend, ``num_envs`` sizes Warp's shared contact buffer,
    ``overrides`` (``env.KEY=VALUE``, ``env_overrides``) change the env it is evaluated on."""
    from brax.training.agents.ppo import networks as ppo_networks

    path = checkpoint_path or checkpoint.latest(run_dir)
    meta = checkpoint.read_meta(path)
    config = tcfg.from_dict(env_overrides(meta["config"], overrides))
    env = HSAEnv(evaluation_env_config(config.env, backend), num_envs=num_envs)
    networks, ts = load_training_state(config, path, env.observation_size, env.action_size)
    policy = ppo_networks.make_inference_fn(networks)((ts.normalizer, ts.params.policy), deterministic=deterministic)
    return config, env, policy, path, int(meta["step"])


def check_env_overrides(overrides: tuple[str, ...] | list[str]) -> None:
    """Refuse ``--set`` keys an evaluation may not change: goals, terrain, termination, reward, physics,
    randomisation and observation noise may change; the observation's layout (the policy's input) and
    the ppo, run and curriculum sections may not."""
    for item in overrides:
        key = item.split("=", 1)[0].strip()
        layout = key.startswith("env.observation") and not key.startswith("env.observation.noise.")
        if not key.startswith("env.") or layout:
            raise ValueError(
                f"evaluate --set {key!r}: only env keys may change (env.goal.*, env.terrain.*, "
                "env.randomization.*, env.observation.noise.*, ...), not the observation's layout "
                "(env.observation.*) or the ppo, run and curriculum sections"
            )


def env_overrides(data: dict, overrides: tuple[str, ...] | list[str]) -> dict:
    """A run's config data with ``--set env.KEY=VALUE`` applied (``check_env_overrides`` first); goals
    other than radial turn the goal curriculum off (it only draws training goals from its range)."""
    check_env_overrides(overrides)
    data = tcfg.apply_overrides(data, list(overrides))
    if data["env"].get("goal", {}).get("mode", "radial") != "radial":
        data = tcfg.apply_overrides(data, ["curriculum.enabled=false"])
    return data


def load_training_state(config: tcfg.TrainConfig, path: Path, observation_size: int, action_size: int):
    """(PPO networks, training state) of the checkpoint at ``path`` written with ``config``."""
    from train.ppo import init_training_state, make_networks, privileged_size

    extra = privileged_size(config)  # a privileged critic's inputs: in the checkpoint, never in the policy's input
    networks = make_networks(config, observation_size, action_size, extra)
    template_ts = init_training_state(config, networks, jax.random.PRNGKey(0), observation_size + extra)
    template = {"training_state": template_ts, "curriculum": cur.init(config.curriculum), "rng": jax.random.PRNGKey(0)}
    restored = checkpoint.load(path, template)
    return networks, jax.tree.map(jnp.asarray, restored["training_state"])


def default_goal_range(config: tcfg.TrainConfig) -> tuple[float, float]:
    """The radial goal range to evaluate on: the curriculum's target, or the range training used."""
    if config.curriculum.enabled:
        return tuple(config.curriculum.target_range)
    return tuple(config.env.goal.radial_range)


def rollout(
    env: HSAEnv,
    policy,
    keys: jax.Array,
    goal_range: jax.Array,
    steps: int,
    params: Any = None,
    simulate: Any = None,
    cells: jax.Array | None = None,
    realism: dict | None = None,
) -> dict[str, jax.Array]:
    """Play one episode per key (frozen after it ends); return per-step traces, shape (N, T, ...).

    ``policy(obs, key) -> (action, extras)``; with ``params`` (a pytree with a leading episode
    axis) ``policy(params_i, obs, key)`` instead, so that one compiled rollout plays several
    parameter sets (e.g. a policy against a zero policy). ``simulate``: another physics engine for
    ``env.step_with`` (e.g. ``hsa_mjx.sim.host_physics.HostPhysics``); default the env's MJX step.
    ``cells``: each episode's terrain cell (type row, level), (N, 2) int32; default a free draw.
    ``realism``: each episode's physical scales and latency instead of the env's draws,
    ``{"physics": PhysicsScales, "latency": int32}`` with a leading episode axis (the env must
    randomise the scales it sets, and allow the latency).
    """
    idx = env.index
    env_step = env.step if simulate is None else functools.partial(env.step_with, simulate)

    def one(key, p, cell, fixed):
        act = policy if params is None else functools.partial(policy, p)
        state = env.reset(key, EnvParams.make(goal_range, FREE_CELL if cell is None else cell))
        if fixed is not None:
            state = with_realism(state, fixed["physics"], fixed["latency"])

        def step(carry, k_act):
            s, alive = carry
            action, _ = act(s.obs, k_act)
            ns = env_step(s, action)
            ns = backend.where(alive, ns, s)
            data = ns.pipeline_state.physics
            trace = {
                "action": action,
                "alive": alive,
                "xy": observation.robot_xy(data, idx),
                "joint_pos": observation.joint_positions(data, idx),
                "joint_vel": observation.joint_velocities(data, idx),
                "qpos": data.qpos,
                "goal": ns.pipeline_state.task.goal_xy,
                "distance": ns.metrics["distance_to_goal"],
                "success": ns.metrics["termination/goal_reached"],
                "done": ns.done,
                "checkpoint": ns.metrics["checkpoint_index"],
                "reasons": jnp.stack([ns.metrics[f"termination/{r}"] for r in termination.REASONS]),
            }
            return (ns, alive & (ns.done < 0.5)), trace

        act_keys = jax.random.split(jax.random.fold_in(key, 1), steps)
        (_, _), traces = jax.lax.scan(step, (state, jnp.ones((), bool)), act_keys)
        traces["start_xy"] = observation.robot_xy(state.pipeline_state.physics, idx)
        traces["start_distance"] = state.metrics["distance_to_goal"]
        return traces

    in_axes = (0, None if params is None else 0, None if cells is None else 0, None if realism is None else 0)
    return jax.jit(jax.vmap(one, in_axes=in_axes))(keys, params, cells, realism)


def with_realism(state: Any, physics: Any, latency: jax.Array) -> Any:
    """An env state whose episode runs with these physical scales and this action latency."""
    sim = state.pipeline_state
    realism = sim.task.realism.replace(physics=physics, latency=jnp.asarray(latency, jnp.int32))
    return state.replace(pipeline_state=sim.replace(task=sim.task.replace(realism=realism)))


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
    progress = (
        {
            "mean_checkpoints_collected": float(collected.mean()),
            "checkpoints_per_episode": [int(c) for c in collected],
            "checkpoint_timeline": checkpoint_timeline(traces["checkpoint"], alive),
        }
        if checkpoints
        else {"mean_progress_m": float(np.mean(traces["start_distance"] - final_distance))}
    )
    return {
        "episodes": int(alive.shape[0]),
        "success_rate": float(success.mean()),
        "mean_final_distance": float(final_distance.mean()),
        "mean_speed_m_per_s": float(speed.mean()),
        "mean_start_distance": float(traces["start_distance"].mean()),
        **progress,
        "mean_episode_steps": float(length.mean()),
        **{k: v for k, v in ends.items() if v > 0},
        "time_out": float(np.mean(ended & ~reasons.any(axis=1))),
        "not_finished": float(np.mean(~ended)),
    }


def checkpoint_timeline(index: np.ndarray, alive: np.ndarray) -> list[dict[str, float]]:
    """Per checkpoint k = 1, 2, ... that any episode collected: how many episodes did, and the mean
    env step at which they did (where on the track the episodes slow down or stop)."""
    held = np.where(alive.astype(bool), index, -1)  # (episodes, steps); steps after an end do not count
    timeline = []
    for k in range(1, int(held.max(initial=0)) + 1):
        reached = held >= k
        got = reached.any(axis=1)
        first = reached.argmax(axis=1) + 1  # steps taken when the count first reached k
        timeline.append({"checkpoint": k, "episodes": int(got.sum()), "mean_step": float(first[got].mean())})
    return timeline


def shipped_policy_apply(policy: pol.NumpyPolicy):
    """``apply(params, obs, key) -> (action, {})``: the policy file's deterministic forward in JAX."""
    net = policy.meta["network"]

    def apply(params: dict, obs: jax.Array, key: jax.Array):
        return pol.forward(params, obs, net["activation"], net["output"], float(net["observation_clip"]), xp=jnp), {}

    return apply


def load_shipped_policy(
    directory: Path, backend: str | None = None, num_envs: int = 1, overrides: tuple[str, ...] = ()
):
    """(config, env, policy fn, policy) of a policy directory: the env rebuilt from its policy.json (on
    ``backend`` when given, with ``env.KEY=VALUE`` ``overrides``), the network from its policy.npz."""
    check_env_overrides(overrides)
    policy = pol.load_policy(directory)
    try:
        config = tcfg.from_dict(policy.meta["config"])
    except (KeyError, ValueError) as err:
        raise ValueError(f"policy {directory}: its {pol.META_FILE} holds no usable training config ({err})") from err
    if overrides:
        config = tcfg.from_dict(env_overrides(tcfg.to_dict(config), overrides))
    env = HSAEnv(evaluation_env_config(config.env, backend), num_envs=num_envs)
    if (env.observation_size, env.action_size) != (policy.observation_size, policy.action_size):
        raise ValueError(
            f"policy {directory} maps {policy.observation_size} observations to {policy.action_size} "
            f"actions; its env has {env.observation_size} and {env.action_size}"
        )
    params = jax.tree.map(jnp.asarray, policy.params)
    return config, env, functools.partial(shipped_policy_apply(policy), params), policy


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    """The command line's arguments."""
    parser = argparse.ArgumentParser(
        prog="python -m train.evaluate", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("run_dir", nargs="?", help="a run directory written by python -m train")
    parser.add_argument(
        "--policy",
        default=None,
        metavar="NAME_OR_DIR",
        help="evaluate a policy directory instead: a folder name under policies/ or a path",
    )
    parser.add_argument(
        "--episodes", type=int, default=None, help=f"episodes (default 16 for a run, {CPU_EPISODES} for --policy)"
    )
    parser.add_argument(
        "--steps",
        type=int,
        default=None,
        help="max steps per episode (default: the env's "
        f"max_episode_steps for a run, at most {CPU_STEPS} for --policy)",
    )
    parser.add_argument(
        "--goal-range",
        type=float,
        nargs=2,
        default=None,
        metavar=("MIN", "MAX"),
        help="radial goal distance range (default: the curriculum's target range, or "
        "the env's goal.radial_range when the curriculum is off)",
    )
    parser.add_argument(
        "--stochastic",
        action="store_true",
        help="sample actions from the policy as in training (default: its mean action; run directories only)",
    )
    parser.add_argument("--video", action="store_true", help="render the first episode to episode.gif")
    parser.add_argument("--out", default=None, help="output folder (default: RUN_DIR/eval or runs/eval_<NAME>)")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="env.KEY=VALUE",
        help="evaluate on a changed env, e.g. --set env.goal.radial_range=[4.0,4.5] (repeatable; "
        "not env.observation.*)",
    )
    (
        parser.add_argument(
            "--backend",
            choices=BACKENDS,
            default="auto",
            help="physics to evaluate on (env.physics.backend): c, the substeps in C MuJoCo "
            "(hsa_mjx.sim.host_physics), several times faster on a CPU; jax or warp, MJX's; "
            "auto (default): c on a CPU, MJX on a GPU (Warp when installed)",
        ),
    )
    parser.add_argument(
        "--terrain-types",
        default=None,
        metavar="all|T1,T2",
        help="evaluate per terrain type: 'all' (the run's types) or a list (with --levels)",
    )
    parser.add_argument(
        "--levels",
        default=None,
        metavar="D1,D2",
        help="terrain difficulties in [0, 1] to evaluate each type at (default: the run's top)",
    )
    return parser.parse_args(argv)


def load_subject(args: argparse.Namespace) -> tuple[tcfg.TrainConfig, HSAEnv, Any, dict, Path]:
    """(config, env, policy fn, result header, output folder) of the run or policy the arguments name."""
    if (args.run_dir is None) == (args.policy is None):
        raise ValueError("give either a RUN_DIR or --policy NAME_OR_DIR (one of them)")
    if args.episodes is not None and args.episodes < 1:
        raise ValueError(f"--episodes must be >= 1, got {args.episodes}")
    if args.policy is not None:
        if args.stochastic:
            raise ValueError("--stochastic needs a RUN_DIR: a policy directory holds only the deterministic policy")
        directory = pol.locate(args.policy)
        config, env, policy, shipped = load_shipped_policy(
            directory, args.backend, _episodes(args, True), tuple(args.overrides)
        )
        out = Path(args.out) if args.out else Path("runs") / f"eval_{directory.resolve().name}"
        header = {
            "policy_dir": str(directory),
            "source": shipped.meta.get("source", {}),
            "step": shipped.meta.get("source", {}).get("env_steps"),
            **({"env_overrides": args.overrides} if args.overrides else {}),
        }
        return config, env, policy, header, out
    run_dir = Path(args.run_dir)
    if not run_dir.is_dir():
        raise FileNotFoundError(f"run directory not found: {run_dir}")
    config, env, policy, path, step = load_policy(
        run_dir,
        deterministic=not args.stochastic,
        backend=args.backend,
        num_envs=_episodes(args, False),
        overrides=tuple(args.overrides),
    )
    header = {"checkpoint": str(path), "step": step, **({"env_overrides": args.overrides} if args.overrides else {})}
    return config, env, policy, header, Path(args.out) if args.out else run_dir / "eval"


def check_goal_range(goal_range: list[float] | None, config: tcfg.TrainConfig) -> None:
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


def _episodes(args: argparse.Namespace, shipped: bool) -> int:
    """Episodes to play: as asked, else 16 for a run and CPU_EPISODES for a shipped policy."""
    return args.episodes or (CPU_EPISODES if shipped else 16)


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``python -m train.evaluate``."""
    args = parse_args(argv)
    args.backend = for_one_env(args.backend)  # auto: C MuJoCo on a CPU, where MJX batches of one env are slow
    try:
        config, env, policy, header, out = load_subject(args)
        check_goal_range(args.goal_range, config)
    except (ValueError, FileNotFoundError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    shipped = args.policy is not None
    if args.terrain_types is not None or args.levels is not None:
        return by_terrain(args, config, policy, header, out)
    episodes = _episodes(args, shipped)
    steps = args.steps or (
        min(CPU_STEPS, config.env.termination.max_episode_steps)
        if shipped
        else config.env.termination.max_episode_steps
    )
    goal_range = args.goal_range or default_goal_range(config)
    keys = jax.random.split(jax.random.PRNGKey(args.seed), episodes)
    traces = jax.device_get(rollout(env, policy, keys, jnp.asarray(goal_range, jnp.float32), steps))
    traces = {k: np.asarray(v) for k, v in traces.items()}
    radial = config.env.goal.mode == "radial"  # other goal modes do not use the range
    result = {
        **header,
        "goal_range": list(goal_range) if radial else None,
        "policy": "stochastic" if args.stochastic else "deterministic",
        "max_steps": steps,
        "physics": "c_mujoco" if env.physics_backend == "c" else f"mjx_{env.physics_backend}",
        **summarize(traces, env.dt, checkpoints=config.env.goal.mode == "spiral"),
    }
    out.mkdir(parents=True, exist_ok=True)
    from train import diagnostics

    written = diagnostics.write_all(traces, env, out, video=args.video)
    result["files"] = [str(p) for p in written]
    (out / "eval.json").write_text(json.dumps(result, indent=1))
    for key, value in result.items():
        if key not in ("files", "source"):
            print(f"{key}: {value:.4g}" if isinstance(value, float) else f"{key}: {value}")
    print(f"wrote {len(written)} files to {out}")
    return 0


def by_terrain(args: argparse.Namespace, config: tcfg.TrainConfig, policy, header: dict, out: Path) -> int:
    """``--terrain-types`` / ``--levels``: the table of success and progress per terrain type and difficulty."""
    from train import terrain_eval

    try:
        types = terrain_eval.parse_types(args.terrain_types or "all", config.env)
        levels = terrain_eval.parse_levels(args.levels or str(config.env.terrain.difficulty))
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    episodes = _episodes(args, args.policy is not None)
    steps = args.steps or config.env.termination.max_episode_steps
    goal_range = jnp.asarray(args.goal_range or default_goal_range(config), jnp.float32)
    env_config = evaluation_env_config(config.env, args.backend)

    def play(env: HSAEnv, keys: jax.Array, cells: jax.Array) -> dict:
        return rollout(env, policy, keys, goal_range, steps, cells=cells)

    rows = terrain_eval.evaluate(env_config, play, types, levels, episodes, args.seed)
    print(terrain_eval.table(rows))
    header = {
        **header,
        "goal_range": [float(v) for v in goal_range],
        "max_steps": steps,
        "policy": "stochastic" if args.stochastic else "deterministic",
        "episodes_per_cell": episodes,
    }
    written = terrain_eval.write(rows, header, out)
    print(f"wrote {len(written)} files to {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
