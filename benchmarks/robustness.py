"""How a policy fares on models that differ from the one it trained on: ``python -m benchmarks.robustness POLICY``.

The grid crosses floor friction x0.5 / x1 / x1.5, block masses -20 % / +20 %, HSA tendon stiffness
-30 % / +30 %, action latency 0 / 20 / 40 ms and observation noise off / on (``NOISE_ON``): 72 cells.
Every cell plays ``--episodes`` episodes from the same starts and goals (the policy's training goal
range) with the policy's mean action, for at most ``--steps`` steps; a cell's success rate, mean net
progress towards the goal and how its failed episodes ended (each termination reason's share,
``time_out`` at the env's episode limit, ``not_finished`` at a shorter ``--steps``) go into
``robustness_<tag>.json``, a table (``.md``) and a heat map (``.png``) under ``--out-dir``.
``--where FACTOR=VALUE`` (repeatable) keeps only the matching cells.

One compiled rollout serves every cell of a noise setting: the env randomises the four factors over
the grid's span and each episode's draws are then set to its cell's values
(``hsa_mjx.task.randomization``), so the cells differ only in those values.
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import json
import sys
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from benchmarks.run_info import run_info
from hsa_mjx.config import BACKENDS
from hsa_mjx.deploy import policy_file
from hsa_mjx.deploy.loop import latency_steps
from hsa_mjx.randomization_config import RandomizationConfig
from hsa_mjx.sim.backend import for_one_env
from hsa_mjx.task.randomization import PhysicsScales
from hsa_mjx_train.config import from_dict
from hsa_mjx_train.policy_sources import default_goal_range, load_shipped_policy
from hsa_mjx_train.rollout import rollout, summarize

GRID = {
    "friction": (0.5, 1.0, 1.5),
    "block_mass": (0.8, 1.2),
    "hsa_stiffness": (0.7, 1.3),
    "latency_ms": (0, 20, 40),
    "noise": (False, True),
}
# observation noise when a cell has it on: uniform +-value (about 1 degree on the hinge encoders,
# 1 cm on the position tracker; configs/train_flat_dr.yaml trains with the same)
NOISE_ON = {
    "hinge_angles": 0.02,
    "hinge_velocities": 0.2,
    "position": 0.01,
    "velocity": 0.02,
    "goal": 0.01,
    "heading": 0.02,
}
RESULTS = Path(__file__).resolve().parent / "results" / "robustness"


def cells() -> list[dict[str, Any]]:
    """Every combination of the grid's values, in a fixed order."""
    return [dict(zip(GRID, values)) for values in itertools.product(*GRID.values())]


def env_overrides(noise: bool, max_latency_steps: int) -> tuple[str, ...]:
    """``env.KEY=VALUE`` overrides: the grid's span randomised, every other randomisation off, the noise setting.

    Everything is set, not only the grid's factors, so that a policy trained with randomisation (whose
    config carries its pushes, noise and other ranges) is scored on the cell's model alone."""
    ranges = {
        **dataclasses.asdict(RandomizationConfig()),  # the defaults: every randomisation off
        **{name: [min(GRID[name]), max(GRID[name])] for name in ("friction", "block_mass", "hsa_stiffness")},
        "latency_steps": [0, max_latency_steps],
    }
    out = [
        f"env.randomization.{name}={json.dumps(list(value) if isinstance(value, tuple) else value)}"
        for name, value in ranges.items()
    ]
    out += [f"env.observation.noise.{group}={value if noise else 0}" for group, value in NOISE_ON.items()]
    return tuple(out)


def cell_randomization(group: list[dict], episodes: int, dt: float) -> dict[str, Any]:
    """Each episode's physical scales and latency, (cells x episodes,) leading axis."""

    def per_episode(name: str) -> jnp.ndarray:
        return jnp.repeat(jnp.asarray([c[name] for c in group], jnp.float32), episodes)

    nominal = PhysicsScales.nominal()
    count = len(group) * episodes
    physics = nominal.replace(
        friction=per_episode("friction"),
        block_mass=jnp.repeat(per_episode("block_mass")[:, None], 2, axis=1),
        hsa_stiffness=per_episode("hsa_stiffness"),
        hsa_damping=jnp.ones(count),
        servo_gain=jnp.ones(count),
        servo_force_limit=jnp.full(count, jnp.inf),
    )
    latency = jnp.repeat(jnp.asarray([latency_steps(c["latency_ms"], dt) for c in group], jnp.int32), episodes)
    return {"physics": physics, "latency": latency}


def run_group(
    directory: Path, group: list[dict], episodes: int, steps: int | None, backend: str, seed: int
) -> list[dict[str, Any]]:
    """The cells of one noise setting in one rollout: a result row per cell."""
    dt = from_dict(policy_file.load_policy(directory).meta["config"]).env.dt
    overrides = env_overrides(group[0]["noise"], max(latency_steps(c["latency_ms"], dt) for c in group))
    config, env, policy, _ = load_shipped_policy(directory, backend, len(group) * episodes, overrides)
    steps = steps or config.env.termination.max_episode_steps
    keys = jnp.tile(jax.random.split(jax.random.PRNGKey(seed), episodes), (len(group), 1))  # same episodes per cell
    goal_range = jnp.asarray(default_goal_range(config), jnp.float32)
    traces = jax.device_get(
        rollout(env, policy, keys, goal_range, steps, randomization=cell_randomization(group, episodes, env.dt))
    )
    rows = []
    for i, cell in enumerate(group):
        part = {k: np.asarray(v)[i * episodes : (i + 1) * episodes] for k, v in traces.items()}
        summary = summarize(part, env.dt)
        rows.append(
            {
                **cell,
                "success_rate": summary["success_rate"],
                "mean_progress_m": summary["mean_progress_m"],
                "mean_final_distance": summary["mean_final_distance"],
                "episodes": episodes,
                "failures": failures(summary),
            }
        )
    return rows


def failures(summary: dict[str, Any]) -> dict[str, float]:
    """How the failed episodes ended: each termination reason's share, ``time_out`` (the env's episode
    limit) and ``not_finished`` (``--steps`` below that limit)."""
    ends = {
        k.removeprefix("termination/"): v
        for k, v in summary.items()
        if k.startswith("termination/") and k != "termination/goal_reached"
    }
    timing = {"time_out": summary["time_out"], "not_finished": summary["not_finished"]}
    return {k: v for k, v in {**ends, **timing}.items() if v > 0}


def select(where: list[str]) -> list[dict[str, Any]]:
    """The grid's cells whose factors match every ``KEY=VALUE`` (ValueError naming the valid keys and values)."""
    chosen = cells()
    for item in where:
        key, _, text = item.partition("=")
        if key not in GRID:
            raise ValueError(f"--where {item!r}: unknown factor {key!r}; factors: {', '.join(GRID)}")
        values = (
            {"off": False, "false": False, "on": True, "true": True}
            if key == "noise"
            else {f"{v:g}": v for v in GRID[key]}
        )
        text = text.strip().lower()
        try:
            text = text if key == "noise" else f"{float(text):g}"
        except ValueError:
            pass
        if text not in values:
            raise ValueError(f"--where {item!r}: {key} takes one of {', '.join(values)}")
        chosen = [c for c in chosen if c[key] == values[text]]
    return chosen


def table(rows: list[dict]) -> str:
    """A markdown table: one row per cell."""
    head = (
        "| friction | block mass | HSA stiffness | latency (ms) | noise | success | progress (m) | failures ended by |"
    )
    lines = [head, "|" + "---|" * 8]
    for r in rows:
        ended = ", ".join(f"{k} {v:.0%}" for k, v in r["failures"].items()) or "-"
        lines.append(
            f"| x{r['friction']:g} | x{r['block_mass']:g} | x{r['hsa_stiffness']:g} | {r['latency_ms']:g} | "
            f"{'on' if r['noise'] else 'off'} | {r['success_rate']:.0%} | {r['mean_progress_m']:.2f} | {ended} |"
        )
    return "\n".join(lines)


def heat_map(rows: list[dict], path: Path, title: str) -> None:
    """Success rate as a heat map: model (friction, mass, stiffness) down, sensing (latency, noise) across."""
    from matplotlib.figure import Figure

    models = list(dict.fromkeys((r["friction"], r["block_mass"], r["hsa_stiffness"]) for r in rows))
    sensing = list(dict.fromkeys((r["latency_ms"], r["noise"]) for r in rows))
    grid = np.full((len(models), len(sensing)), np.nan)
    for r in rows:
        grid[
            models.index((r["friction"], r["block_mass"], r["hsa_stiffness"])),
            sensing.index((r["latency_ms"], r["noise"])),
        ] = r["success_rate"]
    fig = Figure(figsize=(1.2 * len(sensing) + 3, 0.45 * len(models) + 1.5))
    ax = fig.subplots()
    image = ax.imshow(grid, vmin=0, vmax=1, cmap="RdYlGn", aspect="auto")
    for (i, j), value in np.ndenumerate(grid):
        ax.text(j, i, f"{value:.0%}", ha="center", va="center", fontsize=8)
    ax.set_xticks(range(len(sensing)), [f"{ms:g} ms\nnoise {'on' if n else 'off'}" for ms, n in sensing], fontsize=8)
    ax.set_yticks(
        range(len(models)), [f"friction x{f:g}, mass x{m:g}, stiffness x{k:g}" for f, m, k in models], fontsize=8
    )
    ax.set_title(title, fontsize=10)
    fig.colorbar(image, ax=ax, label="success rate")
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    """The command line's arguments."""
    parser = argparse.ArgumentParser(
        prog="python -m benchmarks.robustness",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("policy", metavar="NAME_OR_DIR", help="a shipped policy's name or a policy directory")
    parser.add_argument("--episodes", type=int, default=16, help="episodes per cell (default 16)")
    parser.add_argument("--steps", type=int, default=None, help="max steps per episode (default: the env's limit)")
    parser.add_argument(
        "--backend",
        choices=BACKENDS,
        default="auto",
        help="physics: auto (C MuJoCo on a CPU, MJX on a GPU), c, jax or warp",
    )
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument(
        "--where",
        action="append",
        default=[],
        metavar="FACTOR=VALUE",
        help="only the cells with this factor value, e.g. --where hsa_stiffness=1.3 (repeatable)",
    )
    parser.add_argument("--tag", default=None, help="file name tag (default: the policy folder's name)")
    parser.add_argument("--out-dir", default=str(RESULTS))
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``python -m benchmarks.robustness``."""
    args = parse_args(argv)
    try:
        if args.episodes < 1 or (args.steps is not None and args.steps < 1):
            raise ValueError(f"--episodes and --steps must be >= 1, got {args.episodes} and {args.steps}")
        directory = policy_file.locate(args.policy)
        backend = for_one_env(args.backend)
        chosen = select(args.where)
        rows = []
        for noise in GRID["noise"]:
            group = [c for c in chosen if c["noise"] == noise]
            rows += run_group(directory, group, args.episodes, args.steps, backend, args.seed) if group else []
    except (ValueError, FileNotFoundError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    tag = args.tag or directory.resolve().name
    out = Path(args.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    worst = min(rows, key=lambda r: r["success_rate"])
    result = {
        **run_info(),
        "policy": str(directory),
        "episodes_per_cell": args.episodes,
        "max_steps": args.steps,
        "physics_backend": backend,
        "where": args.where,
        "noise_on": NOISE_ON,
        "cells": rows,
        "min_success_rate": worst["success_rate"],
        "mean_success_rate": float(np.mean([r["success_rate"] for r in rows])),
    }
    (out / f"robustness_{tag}.json").write_text(json.dumps(result, indent=1))
    (out / f"robustness_{tag}.md").write_text(f"# {tag}: success per perturbed model\n\n{table(rows)}\n")
    heat_map(rows, out / f"robustness_{tag}.png", f"{tag}: success rate per cell ({args.episodes} episodes each)")
    print(table(rows))
    print(
        f"lowest success {worst['success_rate']:.0%} (cell { ({k: worst[k] for k in GRID}) }); "
        f"mean {result['mean_success_rate']:.0%}; wrote {out}/robustness_{tag}.{{json,md,png}}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
