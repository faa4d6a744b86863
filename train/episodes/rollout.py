"""Playing episodes with a policy, one per key, all at once under ``vmap``, and what they add up to.

``rollout`` returns per-step traces (positions, joints, goals, how each episode ended) of episodes
frozen once they end; ``summarize`` turns them into the success rate, distances, speed and end
reasons that ``eval.json`` reports.
"""

from __future__ import annotations

import functools
import inspect
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from hsa_mjx.sim import backend
from hsa_mjx.task import observation, termination
from hsa_mjx.task.env import HSAEnv
from hsa_mjx.task.params import FREE_CELL, EnvParams
from hsa_mjx.task.randomization import NEVER

from .failures import DEFAULT_RULE, FailureRule, episode_modes, shares


def _while(simulate: Any, alive: jax.Array) -> Any:
    """``simulate`` for one episode: where it takes ``idle`` (``HostPhysics``), an ended episode runs no
    substeps (its frozen state is kept, so whatever they would return is discarded)."""
    if "idle" not in inspect.signature(simulate).parameters:
        return simulate
    return lambda data, targets, fields: simulate(data, targets, fields, idle=~alive)


def rollout(
    env: HSAEnv,
    policy,
    keys: jax.Array,
    goal_range: jax.Array,
    steps: int,
    params: Any = None,
    simulate: Any = None,
    cells: jax.Array | None = None,
    randomization: dict | None = None,
) -> dict[str, jax.Array]:
    """Play one episode per key (frozen after it ends); return per-step traces, shape (N, T, ...).

    ``policy(obs, key) -> (action, extras)``; with ``params`` (a pytree with a leading episode
    axis) ``policy(params_i, obs, key)`` instead, so that one compiled rollout plays several
    parameter sets (e.g. a policy against a zero policy). ``simulate``: another physics engine for
    ``env.step_with`` (e.g. ``hsa_mjx.sim.host_physics.HostPhysics``); default the env's MJX step.
    ``cells``: each episode's terrain cell (type row, level), (N, 2) int32; default a free draw.
    ``randomization``: each episode's physical scales and latency instead of the env's draws,
    ``{"physics": PhysicsScales, "latency": int32, "pushes": bool (optional)}`` with a leading episode
    axis (the env must randomise the scales it sets, allow the latency and, for pushes, push).
    """
    idx = env.index
    simulate = env.host_physics if simulate is None else simulate  # C MuJoCo: ended episodes run no substeps

    def one(key, p, cell, fixed):
        act = policy if params is None else functools.partial(policy, p)
        state = env.reset(key, EnvParams.make(goal_range, FREE_CELL if cell is None else cell))
        if fixed is not None:
            state = with_randomization(state, fixed["physics"], fixed["latency"], fixed.get("pushes"))

        def step(carry, k_act):
            s, alive = carry
            action, _ = act(s.obs, k_act)
            ns = env.step(s, action) if simulate is None else env.step_with(_while(simulate, alive), s, action)
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
        traces["start_heading"] = observation.heading(state.pipeline_state.physics, idx)
        traces["start_distance"] = state.metrics["distance_to_goal"]
        return traces

    in_axes = (0, None if params is None else 0, None if cells is None else 0, None if randomization is None else 0)
    return jax.jit(jax.vmap(one, in_axes=in_axes))(keys, params, cells, randomization)


def with_randomization(state: Any, physics: Any, latency: jax.Array, pushes: jax.Array | None = None) -> Any:
    """An env state whose episode runs with these physical scales and this action latency, and without
    the env's pushes where ``pushes`` is false (its drawn push times where true)."""
    sim = state.pipeline_state
    drawn = sim.task.randomization
    randomization = drawn.replace(physics=physics, latency=jnp.asarray(latency, jnp.int32))
    if pushes is not None:
        randomization = randomization.replace(next_push=jnp.where(pushes, drawn.next_push, NEVER))
    return state.replace(pipeline_state=sim.replace(task=sim.task.replace(randomization=randomization)))


def episode_success(traces: dict[str, np.ndarray]) -> np.ndarray:
    """Whether each evaluated episode reached its goal (its success flag at its last live step), (episodes,)."""
    last = np.maximum(traces["alive"].astype(bool).sum(axis=1) - 1, 0)
    return traces["success"][np.arange(last.shape[0]), last] > 0.5


BEARING_BINS = (0, 30, 60, 90)  # degrees between the robot's axis at the start and its goal, folded


def by_goal_bearing(traces: dict[str, np.ndarray], success: np.ndarray) -> dict[str, float | None]:
    """Success rate by the goal's bearing from the robot's axis at the start (block A to B), folded onto
    0-90 degrees (either end of the axis): the hardware profiles' policies crawl across the axis, so a
    policy that cannot turn reaches the goals at 60-90 degrees only. Keys ``"0-30"`` ...; None for a bin
    without episodes."""
    to_goal = traces["goal"][:, 0] - traces["start_xy"]
    along = np.abs(np.sum(to_goal * traces["start_heading"], axis=-1)) / np.maximum(
        np.linalg.norm(to_goal, axis=-1), 1e-9
    )
    angle = np.degrees(np.arccos(np.clip(along, 0.0, 1.0)))
    out = {}
    for low, high in zip(BEARING_BINS[:-1], BEARING_BINS[1:]):
        inside = (angle >= low) & ((angle < high) | (high == BEARING_BINS[-1]))
        out[f"{low}-{high}"] = float(success[inside].mean()) if inside.any() else None
    return out


def summarize(
    traces: dict[str, np.ndarray], dt: float, checkpoints: bool = False, rule: FailureRule = DEFAULT_RULE
) -> dict[str, Any]:
    """Success rate, mean final distance and mean speed of the evaluated episodes (spiral: checkpoints each),
    how they ended, and what the robot did in those that ran out of time (``rule``: ``train.episodes.failures``)."""
    alive = traces["alive"].astype(bool)
    length = alive.sum(axis=1)
    last = np.maximum(length - 1, 0)
    rows = np.arange(alive.shape[0])
    final_xy, final_distance = traces["xy"][rows, last], traces["distance"][rows, last]
    success = episode_success(traces)
    displacement = np.linalg.norm(final_xy - traces["start_xy"], axis=-1)
    speed = displacement / np.maximum(length * dt, dt)
    ended = traces["done"][rows, last] > 0.5
    reasons = traces["reasons"][rows, last] > 0.5  # (episodes, reasons)
    ends = {f"termination/{r}": float(np.mean(ended & reasons[:, i])) for i, r in enumerate(termination.REASONS)}
    for group, members in termination.GROUPS.items():  # the two kinds of failure, apart
        hit = reasons[:, [termination.REASONS.index(name) for name in members]].any(axis=1)
        ends[f"termination/{group}"] = float(np.mean(ended & hit))
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
    if "start_heading" in traces and not checkpoints:
        progress["success_by_goal_bearing"] = by_goal_bearing(traces, success)
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
        **shares(episode_modes(traces, dt, rule)),
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
