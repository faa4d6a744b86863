"""Run-to-run determinism per physics backend: the same seed, played twice, gives the same trajectories?

For each backend and terrain, one jitted program resets a batch from fixed keys and plays fixed
random actions for K env steps under ``lax.scan``; it is called twice (the second call a fresh
execution of the same compiled program on the same inputs) and the two final states are compared:
how many envs differ at all, the largest hinge-angle and block-position differences, and the
step at which the first difference appears. A third call of a freshly compiled copy of the same
program checks compile-to-compile determinism too.

    python -m benchmarks.speed.determinism [--backends jax,warp] [--terrains flat,heightfield]
        [--envs 1024] [--steps 200] [--out-dir benchmarks/results/determinism]

Writes ``determinism_<gpu>.{json,md}`` (temp file + rename).
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import jax
import numpy as np

from benchmarks.fidelity.guard import SHIPPED_BY_SCENE
from benchmarks.run_info import run_info
from benchmarks.speed.cases import TERRAINS
from benchmarks.speed.throughput import bench_env

SCENES = {"flat": "flat", "heightfield": "terrain"}


def play(env, envs: int, steps: int) -> Callable[[jax.Array], dict[str, jax.Array]]:
    """A jittable rollout from ``key``: qpos after every step (steps, envs, nq) and the final blocks."""

    def run(key: jax.Array) -> dict[str, jax.Array]:
        reset_key, action_key = jax.random.split(key)
        state = jax.vmap(env.reset)(jax.random.split(reset_key, envs))
        actions = jax.random.uniform(action_key, (steps, envs, env.action_size), minval=-1.0, maxval=1.0)

        def body(state, action):
            state = jax.vmap(env.step)(state, action)
            return state, state.pipeline_state.physics.qpos

        state, qpos = jax.lax.scan(body, state, actions)
        return {"qpos": qpos, "blocks": state.pipeline_state.physics.xpos[:, env.index.block_body]}

    return run


def compare(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> dict[str, Any]:
    """How far two rollouts of the same inputs are apart."""
    dq = np.abs(a["qpos"] - b["qpos"]).max(axis=-1)  # (steps, envs)
    differs = dq > 0
    first = np.argmax(differs.any(axis=1)) if differs.any() else None
    return {
        "bitwise_equal": not differs.any(),
        "envs_differing": int(differs.any(axis=0).sum()),
        "first_differing_step": None if first is None else int(first) + 1,
        "max_qpos_diff": float(dq.max()),
        "max_block_diff_m": float(np.abs(a["blocks"] - b["blocks"]).max()),
        "envs_block_diff_over_1mm": int((np.abs(a["blocks"] - b["blocks"]).max(axis=(-2, -1)) > 1e-3).sum()),
    }


def measure(backend: str, terrain: str, envs: int, steps: int, seed: int) -> dict[str, Any]:
    """One backend and terrain: two calls of one compiled program, and one of a recompiled copy."""
    setting = SHIPPED_BY_SCENE[SCENES[terrain]]
    env = bench_env(terrain, setting, backend, num_envs=envs)
    key = jax.random.PRNGKey(seed)
    compiled = jax.jit(play(env, envs, steps)).lower(key).compile()
    first, second = (jax.device_get(compiled(key)) for _ in range(2))
    recompiled = jax.device_get(jax.jit(play(env, envs, steps)).lower(key).compile()(key))
    finite = bool(np.isfinite(first["qpos"]).all())
    return {
        "backend": env.physics_backend,
        "terrain": terrain,
        "setting": setting,
        "envs": envs,
        "steps": steps,
        "seed": seed,
        "finite": finite,
        "same_program": compare(first, second),
        "recompiled": compare(first, recompiled),
    }


def markdown(rows: list[dict[str, Any]], info: dict[str, Any]) -> str:
    """The rows as a markdown table with their provenance."""
    flags = {k: v for k, v in info.get("environment", {}).items() if v}
    lines = [
        f"Run-to-run determinism on {info['device']}, {info['date']}; command `{info['command']}`"
        f"{'; environment ' + str(flags) if flags else ''}.",
        "",
        "| backend | terrain | envs | steps | run | bitwise equal | envs differing | first differing step "
        "| max hinge/qpos diff | max block diff (m) | envs with blocks > 1 mm apart |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        for run in ("same_program", "recompiled"):
            c = row[run]
            lines.append(
                f"| {row['backend']} | {row['terrain']} | {row['envs']:,} | {row['steps']} | {run} | "
                f"{'yes' if c['bitwise_equal'] else 'no'} | {c['envs_differing']} | "
                f"{c['first_differing_step'] or '-'} | {c['max_qpos_diff']:.3g} | "
                f"{c['max_block_diff_m']:.3g} | {c['envs_block_diff_over_1mm']} |"
            )
    return "\n".join(lines) + "\n"


def write(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` through a temporary file and a rename."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.")
    with os.fdopen(fd, "w") as f:
        f.write(text)
    os.replace(tmp, path)


def main(argv: Sequence[str] | None = None) -> None:
    """Measure every backend and terrain asked for; write JSON and markdown."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--backends", default="jax,warp", help="comma list of jax, warp, auto")
    p.add_argument("--terrains", default="flat,heightfield", help=f"comma list of {sorted(TERRAINS)}")
    p.add_argument("--envs", type=int, default=1024)
    p.add_argument("--steps", type=int, default=200)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out-dir", type=Path, default=Path("benchmarks/results/determinism"))
    args = p.parse_args(argv)
    terrains = args.terrains.split(",")
    unknown = sorted(set(terrains) - set(TERRAINS))
    if unknown:
        raise ValueError(f"--terrains: unknown {unknown}; choose from {sorted(TERRAINS)}")
    info = run_info()
    rows = []
    for backend in args.backends.split(","):
        for terrain in terrains:
            rows.append(measure(backend, terrain, args.envs, args.steps, args.seed))
            r = rows[-1]
            print(r["backend"], terrain, "same program:", r["same_program"], "recompiled:", r["recompiled"], flush=True)
    stem = args.out_dir / ("determinism_" + info["device"].lower().replace(" ", "_"))
    write(stem.with_suffix(".json"), json.dumps({**info, "rows": rows}, indent=1))
    write(stem.with_suffix(".md"), markdown(rows, info))
    print(f"wrote {stem}.json, {stem}.md")


if __name__ == "__main__":
    main()
