"""Env-steps/s of the single Gymnasium env on this machine's CPU: C MuJoCo substeps against MJX.

Modes, each one ``env.step`` call per env step with random actions, as a Gymnasium learner makes them:

- ``host_physics``: ``gymnasium.make("hsa_mjx/HSA-v0")`` as it is on a CPU: the physics substeps in
  C MuJoCo (``hsa_mjx.sim.host_physics``), everything else the env's jitted code.
- ``mjx``: the same env with ``physics__backend="jax"``: the whole step in MJX's JAX implementation.
- ``c_mujoco``: the bare substep loop of the same model in C MuJoCo (``mj_step`` x frame_skip through the
  env's control law, no observation, reward or Python env around it): the ceiling.

Each mode plays ``--repeats`` rounds of ``--steps`` steps (episodes reset when they end), each round
followed at once by as many steps of the ceiling, so a machine whose speed drifts (a shared CPU) slows
both sides of a round alike: ``share_of_c_mujoco`` is the median over rounds of the ceiling's time over
the mode's, the rates are the medians of the rounds. One warm-up episode (the compile) first.
Settings: the ``flat`` preset as ``gymnasium.make`` builds it (the original's physics: Euler, Newton
100/50) and, with ``--setting``, a setting of ``benchmarks.fidelity.guard.SETTINGS``. Results:
``--out``.json and .md (provenance included).

    python -m benchmarks.speed.single_env [--steps 500] [--repeats 30] [--setting NAME]
        [--out benchmarks/results/throughput/single_env_cpu]
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import gymnasium
import numpy as np

import hsa_mjx
from benchmarks.fidelity.guard import SETTINGS
from benchmarks.speed.c_loop import c_loop
from benchmarks.speed.vector_env import write_results

MODES = {"host_physics": {"physics__backend": "c"}, "mjx": {"physics__backend": "jax"}}


def env_loop(overrides: dict[str, Any], seed: int = 0) -> tuple[Callable[[int], float], float]:
    """(``run(n)``: seconds for ``n`` random-action steps of one Gymnasium env, the first step's seconds)."""
    env = gymnasium.make("hsa_mjx/HSA-v0", **overrides)
    actions = np.random.default_rng(seed).uniform(-1, 1, (256, 8)).astype(np.float32)
    env.reset(seed=seed)
    tic = time.perf_counter()
    env.step(actions[0])
    first = time.perf_counter() - tic

    def run(n: int) -> float:
        tic = time.perf_counter()
        for i in range(n):
            _, _, terminated, truncated, _ = env.step(actions[i % len(actions)])
            if terminated or truncated:
                env.reset()
        return time.perf_counter() - tic

    return run, first


def interleaved(mode: Callable[[int], float], ceiling: Callable[[int], float], steps: int, repeats: int) -> dict:
    """Rounds of ``steps`` steps of ``mode`` each followed by as many of ``ceiling``: median rates and
    the median share of the ceiling."""
    mode(steps), ceiling(steps)  # warm caches and branch predictors on both sides
    rounds = [(mode(steps), ceiling(steps)) for _ in range(repeats)]
    return {
        "env_steps_per_s": round(steps / statistics.median(m for m, _ in rounds), 1),
        "ms_per_step": round(1000 * statistics.median(m for m, _ in rounds) / steps, 3),
        "c_mujoco_env_steps_per_s": round(steps / statistics.median(c for _, c in rounds), 1),
        "share_of_c_mujoco": round(statistics.median(c / m for m, c in rounds), 3),
        "share_range": [round(min(c / m for m, c in rounds), 3), round(max(c / m for m, c in rounds), 3)],
        "steps": steps,
        "repeats": repeats,
    }


def measure(setting: str | None, steps: int, repeats: int) -> list[dict[str, Any]]:
    """Rows of every mode for one physics setting (None: the preset's own), each against the ceiling."""
    overrides = {k.replace(".", "__"): v for k, v in SETTINGS[setting].items()} if setting else {}
    name = setting or "flat preset (Euler, Newton 100/50)"
    ceiling = c_loop(hsa_mjx.make_env("flat", physics__backend="jax", **overrides))
    rows = []
    for mode, extra in MODES.items():
        run, first = env_loop({**overrides, **extra})
        # MJX's step is about 20 times slower: fewer steps a round keep its rounds as long
        n = steps if mode == "host_physics" else max(1, steps // 10)
        rows.append(
            {"setting": name, "mode": mode, "first_step_s": round(first, 2), **interleaved(run, ceiling, n, repeats)}
        )
        print(rows[-1], flush=True)
    return rows


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(
        prog="python -m benchmarks.speed.single_env",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--steps", type=int, default=500, help="env steps a round (MJX: a tenth)")
    p.add_argument("--repeats", type=int, default=30, help="rounds")
    p.add_argument(
        "--setting",
        choices=sorted(SETTINGS),
        default=None,
        help="also measure this physics setting (default: the preset's only)",
    )
    p.add_argument("--out", type=Path, default=Path("benchmarks/results/throughput/single_env_cpu"))
    args = p.parse_args(argv)
    if args.steps < 1 or args.repeats < 1:
        p.error("--steps and --repeats must be positive")
    tic = time.perf_counter()
    rows = measure(None, args.steps, args.repeats)
    if args.setting:
        rows += measure(args.setting, args.steps, args.repeats)
    caption = (
        f"One Gymnasium env on the CPU, one `step` call per env step, random actions: {args.repeats} rounds "
        "each followed by as many steps of the bare C MuJoCo loop; medians over rounds, the share of the "
        "C loop and its range over rounds."
    )
    columns = [
        "setting",
        "mode",
        "env_steps_per_s",
        "ms_per_step",
        "c_mujoco_env_steps_per_s",
        "share_of_c_mujoco",
        "share_range",
        "steps",
        "repeats",
    ]
    write_results(args.out, caption, rows, tic, columns)
    print(f"wrote {args.out}.json and .md", flush=True)


if __name__ == "__main__":
    main()
