"""Env-steps/s of the single Gymnasium env on this machine's CPU: C MuJoCo substeps against MJX.

Modes, each one ``env.step`` call per env step with random actions, as a Gymnasium learner makes them:

- ``host_physics``: ``gymnasium.make("hsa_mjx/HSA-v0")`` as it is on a CPU: the physics substeps in
  C MuJoCo (``hsa_mjx.sim.host_physics``), everything else the env's jitted code.
- ``mjx``: the same env with ``physics__backend="jax"``: the whole step in MJX's JAX implementation.
- ``c_mujoco``: the bare substep loop of the same model in C MuJoCo (``mj_step`` x frame_skip, no
  observation, reward or Python env around it): the ceiling; each row gives its share of it.

Settings: the ``flat`` preset as ``gymnasium.make`` builds it (the original's physics: Euler, Newton
100/50) and, with ``--setting``, a setting of ``benchmarks.fidelity.guard.SETTINGS``. One warm-up episode
(the compile), then ``--repeats`` runs of ``--steps`` steps (episodes reset when they end); the median
is reported. Results: ``--out``.json and .md (provenance included).

    python -m benchmarks.speed.single_env [--steps 2000] [--repeats 3] [--setting NAME]
        [--out benchmarks/results/throughput/single_env_cpu]
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path
from typing import Any

import gymnasium
import numpy as np

import hsa_mjx
from benchmarks.fidelity.guard import SETTINGS
from benchmarks.speed.throughput import cpu_baseline
from benchmarks.speed.vector_env import write_results

MODES = {"host_physics": {"physics__backend": "c"}, "mjx": {"physics__backend": "jax"}}


def time_env(overrides: dict[str, Any], steps: int, repeats: int, seed: int = 0) -> dict[str, Any]:
    """Median env-steps/s of ``steps`` random-action steps of one Gymnasium env."""
    env = gymnasium.make("hsa_mjx/HSA-v0", **overrides)
    rng = np.random.default_rng(seed)
    actions = rng.uniform(-1, 1, (256, 8)).astype(np.float32)
    env.reset(seed=seed)
    tic = time.perf_counter()
    env.step(actions[0])
    first = time.perf_counter() - tic
    runs, episodes = [], 0
    for _ in range(repeats):
        tic = time.perf_counter()
        for i in range(steps):
            _, _, terminated, truncated, _ = env.step(actions[i % len(actions)])
            if terminated or truncated:
                env.reset()
                episodes += 1
        runs.append(time.perf_counter() - tic)
    env.close()
    seconds = statistics.median(runs)
    return {
        "env_steps_per_s": round(steps / seconds, 1),
        "ms_per_step": round(1000 * seconds / steps, 3),
        "first_step_s": round(first, 2),
        "steps": steps,
        "repeats": repeats,
        "episodes_ended": episodes,
    }


def measure(setting: str | None, steps: int, repeats: int) -> list[dict[str, Any]]:
    """Rows of every mode for one physics setting (None: the preset's own)."""
    overrides = {k.replace(".", "__"): v for k, v in SETTINGS[setting].items()} if setting else {}
    name = setting or "flat preset (Euler, Newton 100/50)"
    rows = []
    for mode, extra in MODES.items():
        rows.append({"setting": name, "mode": mode, **time_env({**overrides, **extra}, steps, repeats)})
        print(rows[-1], flush=True)
    env = hsa_mjx.make_env("flat", physics__backend="jax", **overrides)
    rows.append({"setting": name, "mode": "c_mujoco", **cpu_baseline(env, seconds=3.0)})
    rows[-1]["env_steps_per_s"] = rows[-1].pop("cpu_mujoco_env_steps_per_s")
    print(rows[-1], flush=True)
    for row in rows:  # the share of the C ceiling each mode reaches
        row["share_of_c_mujoco"] = round(row["env_steps_per_s"] / rows[-1]["env_steps_per_s"], 3)
    return rows


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(
        prog="python -m benchmarks.speed.single_env",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--steps", type=int, default=2000, help="env steps per timed run")
    p.add_argument("--repeats", type=int, default=3)
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
        f"One Gymnasium env on the CPU, one `step` call per env step, median of {args.repeats} runs "
        f"of {args.steps} random-action steps."
    )
    columns = ["setting", "mode", "env_steps_per_s", "ms_per_step", "share_of_c_mujoco", "steps", "repeats"]
    write_results(args.out, caption, rows, tic, columns)
    print(f"wrote {args.out}.json and .md", flush=True)


if __name__ == "__main__":
    main()
