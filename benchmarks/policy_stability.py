"""Does a trained policy blow the physics up? Per-dof acceleration spikes under a run's policy.

Plays ``--episodes`` episodes (goals over ``--goal-range``) of a run's latest checkpoint with the
``qacc_limit`` termination switched off, once per physics setting, and re-runs every env step's
substeps alongside to record, per dof, the largest |qacc| over the substeps and at the last substep
(the original checked only the last). Counts the env steps on which any dof passed the limit (what
would have ended the episode), the episodes that would have ended, the largest |qvel| seen and the
success rate without the limit. Used to decide the training physics (docs/training.md).

    python -m benchmarks.policy_stability RUN_DIR [--settings NAME ...] [--episodes 16] [--steps 800]
                                          [--out benchmarks/results/policy_stability_cpu.json]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import mjx

from benchmarks.run_info import run_info
from hsa_mjx import control
from hsa_mjx.config import with_overrides
from hsa_mjx.env import HSAEnv
from train.evaluate import load_policy

# Physics overrides (dotted env-config keys) on top of the run's own config.
SETTINGS: dict[str, dict[str, Any]] = {
    "euler_dt1ms_newton4_ls8": {"physics.integrator": "euler", "physics.iterations": 4, "physics.ls_iterations": 8},
    "euler_dt0.5ms_newton4_ls8": {"physics.integrator": "euler", "physics.timestep": 0.0005,
                                  "control.frame_skip": 40, "physics.iterations": 4, "physics.ls_iterations": 8},
    "implicitfast_dt1ms_newton4_ls8": {"physics.integrator": "implicitfast", "physics.iterations": 4,
                                       "physics.ls_iterations": 8},
}


def substep_trace(env: HSAEnv, state, action: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Replay one env step's substeps: per-dof max |qacc|, last-substep |qacc| and max |qvel|."""
    cfg, idx = env.config, env.index
    data = state.pipeline_state.physics
    start = data.ctrl[idx.servo_ids]
    clean, _ = control.sanitize_action(action)
    end = control.next_targets(start, clean, cfg.control.max_increment, cfg.control.servo_target_limit)
    targets = control.substep_targets(start, end, cfg.control.frame_skip, cfg.control.smooth_positions)
    model = env.world.model_for(env.robot.mjx_model, state.pipeline_state.task.terrain)

    def substep(d, target):
        d = mjx.step(model, d.replace(ctrl=d.ctrl.at[idx.servo_ids].set(target)))
        return d, (jnp.abs(d.qacc), jnp.abs(d.qvel))

    _, (qacc, qvel) = jax.lax.scan(substep, data, targets)
    return qacc.max(0), qacc[-1], qvel.max(0)


def play(env: HSAEnv, policy, keys: jax.Array, goal_range: jax.Array, steps: int) -> dict[str, np.ndarray]:
    """Per-step traces (N, T, ...) of one episode per key, frozen after it ends."""
    def one(key):
        state = env.reset_with_goal_range(key, goal_range)

        def body(carry, _):
            s, alive = carry
            action, _ = policy(s.obs, jax.random.PRNGKey(0))
            qacc_max, qacc_last, qvel_max = substep_trace(env, s, action)
            ns = env.step(s, action)
            ns = jax.tree.map(lambda new, old: jnp.where(alive, new, old), ns, s)
            trace = dict(qacc_max=qacc_max, qacc_last=qacc_last, qvel_max=qvel_max, alive=alive,
                         success=ns.metrics["termination/goal_reached"])
            return (ns, alive & (ns.done < 0.5)), trace

        return jax.lax.scan(body, (state, jnp.ones((), bool)), None, length=steps)[1]

    return jax.device_get(jax.jit(jax.vmap(one))(keys))


def summarize(traces: dict[str, np.ndarray], limit: float, dof_names: list[str]) -> dict[str, Any]:
    """Spike counts, episodes the limit would end, largest |qvel| and success without the limit."""
    alive = traces["alive"].astype(bool)
    over_any = (traces["qacc_max"] > limit) & alive[..., None]
    over_last = (traces["qacc_last"] > limit) & alive[..., None]
    per_dof = {dof_names[d]: [int(over_any[..., d].sum()), int(over_last[..., d].sum())]
               for d in range(over_any.shape[-1]) if over_any[..., d].any() or over_last[..., d].any()}
    alive_steps = int(alive.sum())
    spikes = int(over_any.any(-1).sum())
    return {
        "alive_steps": alive_steps,
        "spike_steps_any_substep": spikes,
        "spike_steps_last_substep": int(over_last.any(-1).sum()),
        "spikes_per_1k_steps": round(1000.0 * spikes / max(alive_steps, 1), 3),
        "episodes_the_limit_would_end": int(over_any.any(-1).any(-1).sum()),
        "episodes": int(alive.shape[0]),
        "max_abs_qvel": float(np.where(alive[..., None], traces["qvel_max"], 0).max()),
        "max_abs_qacc": float(np.where(alive[..., None], traces["qacc_max"], 0).max()),
        "success_rate_without_limit": float((traces["success"].max(1) > 0.5).mean()),
        "spike_steps_per_dof_any_last": per_dof,
    }


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run_dir", type=Path)
    parser.add_argument("--settings", nargs="+", default=list(SETTINGS), choices=sorted(SETTINGS))
    parser.add_argument("--episodes", type=int, default=16)
    parser.add_argument("--steps", type=int, default=800)
    parser.add_argument("--goal-range", type=float, nargs=2, default=(1.5, 4.5))
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/policy_stability_cpu.json"))
    args = parser.parse_args(argv)
    config, _, policy, path, step = load_policy(args.run_dir)
    limit = config.env.termination.qacc_limit
    rows = []
    for name in args.settings:
        overrides = {**SETTINGS[name], "termination.qacc_limit": 1e30}
        env = HSAEnv(with_overrides(config.env, **overrides))
        m = env.robot.mj_model
        names = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, m.dof_jntid[d]) for d in range(m.nv)]
        keys = jax.random.split(jax.random.PRNGKey(args.seed), args.episodes)
        t0 = time.time()
        traces = play(env, policy, keys, jnp.asarray(args.goal_range, jnp.float32), args.steps)
        row = {"setting": name, "overrides": SETTINGS[name], "physics": dataclasses.asdict(env.config.physics),
               "frame_skip": env.config.control.frame_skip, "qacc_limit": limit, "wall_s": round(time.time() - t0, 1),
               **summarize(traces, limit, names)}
        print(json.dumps({k: v for k, v in row.items() if k != "spike_steps_per_dof_any_last"}), flush=True)
        rows.append(row)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    meta = {"checkpoint": str(path), "checkpoint_step": step, "episodes": args.episodes, "steps": args.steps,
            "goal_range": list(args.goal_range), **run_info()}
    args.out.write_text(json.dumps({"meta": meta, "rows": rows}, indent=1))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
