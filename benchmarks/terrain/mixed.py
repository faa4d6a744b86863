"""Mixed terrain at scale: a batch resets onto per-env terrain tiles, steps, and every robot settles on its own.

    python -m benchmarks.terrain.mixed --envs 1024 --steps 15        # ten types, the original's solver
    python -m benchmarks.terrain.mixed --envs 16384 --types craters --backend warp
    python -m benchmarks.terrain.mixed --envs 16384 --types craters --shared   # one terrain for every env

Prints timings (compile and run, reset and step), the height of each block above the surface
under it per terrain type after the steps (flat-ground rest: 0.138-0.140 m), terminations and
non-finite values. ``--shared`` sets ``terrain.per_env: false`` (one terrain for every env).
Actions are zero (the servos hold: a settling test) unless ``--random-actions``.
"""

from __future__ import annotations

import argparse
import time

import jax
import jax.numpy as jnp
import numpy as np

import hsa_mjx
from hsa_mjx.terrain import TERRAIN_TYPES

ALL_BUT_SPIRAL = [t for t in TERRAIN_TYPES if t != "spiral"]  # the spiral needs goal.mode spiral


def _timed(fn, *args):
    """Run ``fn(*args)`` to completion; return (result, seconds)."""
    start = time.perf_counter()
    out = jax.block_until_ready(fn(*args))
    return out, time.perf_counter() - start


def build(args: argparse.Namespace) -> hsa_mjx.HSAEnv:
    """The mixed-terrain env with the requested solver overrides."""
    overrides = {"terrain__types": args.types, "terrain__per_env": not args.shared}
    if args.iterations:
        overrides["physics__iterations"] = args.iterations
    if args.ls_iterations:
        overrides["physics__ls_iterations"] = args.ls_iterations
    if args.solver:
        overrides["physics__solver"] = args.solver
    overrides["physics__backend"] = args.backend
    return hsa_mjx.make_env(args.config, num_envs=args.envs, **overrides)


def heights_over_ground(env: hsa_mjx.HSAEnv, state) -> np.ndarray:
    """Block-origin height above the surface under each block, shape (envs, 2)."""
    xpos = state.pipeline_state.physics.xpos[:, env.index.block_body]
    ground = jax.vmap(env.world.ground)(state.pipeline_state.task.tile, xpos[..., :2])
    return np.asarray(xpos[..., 2] - ground)


def report(env: hsa_mjx.HSAEnv, state, ids: np.ndarray) -> None:
    """Settling heights per terrain type, terminations and finiteness."""
    rel = heights_over_ground(env, state)
    print("height of the block origins above their own ground (m):")
    rows = [(TERRAIN_TYPES[t], rel[ids == t]) for t in np.unique(ids)] + [("all", rel)]
    for name, r in rows:
        print(
            f"  {name:18s} envs {len(r):5d}  mean {r.mean():.4f}  min {r.min():.4f}  max {r.max():.4f}"
            f"  within 0.14 +- 0.01: {np.mean(np.all(np.abs(r - 0.14) < 0.01, axis=1)):.1%}"
        )
    ended = {
        k[12:]: int(np.asarray(v).sum())
        for k, v in state.metrics.items()
        if k.startswith("termination/") and np.asarray(v).sum() > 0
    }
    print(
        f"terminations at the last step: {ended or 'none'}; done {int(np.asarray(state.done).sum())}; "
        f"all finite: {bool(np.all(np.isfinite(np.asarray(state.obs))))}"
    )


def main() -> None:
    """Command line: build, reset, step and report."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--config", default="mixed", help="preset name or YAML path (default: mixed)")
    parser.add_argument("--types", nargs="+", default=ALL_BUT_SPIRAL, help="terrain types to mix (equal shares)")
    parser.add_argument("--envs", type=int, default=1024)
    parser.add_argument("--steps", type=int, default=10)
    parser.add_argument("--iterations", type=int, default=0, help="solver iterations (0: the config's)")
    parser.add_argument("--ls-iterations", type=int, default=0, help="line-search iterations (0: the config's)")
    parser.add_argument("--solver", default="", help="newton | cg ('': the config's)")
    parser.add_argument("--shared", action="store_true", help="one terrain shared by every env")
    parser.add_argument("--random-actions", action="store_true")
    parser.add_argument("--backend", choices=("jax", "warp", "auto"), default="auto", help="physics backend")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    start = time.perf_counter()
    env = build(args)
    print(
        f"backend {jax.default_backend()}, physics {env.physics_backend}, {args.envs} envs, per_env {not args.shared}, "
        f"solver {env.config.physics.solver} {env.config.physics.iterations}/{env.config.physics.ls_iterations}, "
        f"env built in {time.perf_counter() - start:.1f} s"
    )
    reset, step = jax.jit(jax.vmap(env.reset)), jax.jit(jax.vmap(env.step))
    key, act_key = jax.random.split(jax.random.PRNGKey(args.seed))
    keys = jax.random.split(key, args.envs)
    state, first = _timed(reset, keys)
    state, again = _timed(reset, jax.random.split(act_key, args.envs))
    ids = np.asarray(state.pipeline_state.task.terrain_id)
    print(
        f"reset: compile + run {first:.1f} s, run {again:.2f} s; "
        f"spawn height over own ground {heights_over_ground(env, state).mean():.4f} m"
    )
    actions = jnp.zeros((args.envs, env.action_size))
    state, first = _timed(step, state, actions)
    times = []
    for k in jax.random.split(act_key, args.steps - 1):
        if args.random_actions:
            actions = jax.random.uniform(k, actions.shape, minval=-1.0, maxval=1.0)
        state, dt = _timed(step, state, actions)
        times.append(dt)
    per_step = float(np.mean(times)) if times else float("nan")
    print(
        f"step: compile + run {first:.1f} s, then {per_step:.2f} s per step "
        f"({args.envs / per_step:.0f} env-steps/s) over {len(times)} steps"
    )
    report(env, state, ids)


if __name__ == "__main__":
    main()
