"""Throughput harness: the full env step against the bare physics loop, over backends, batch sizes and terrains.

For every (physics backend, terrain, physics setting, batch) it measures, in one process:

- **env**: K env steps per call of the training batch step (``hsa_mjx.batch.auto_reset.AutoResetEnv``:
  physics, observation, reward, termination, auto-reset with each env's episode parameters; results
  recorded before the curricula moved into the training loop say "AutoResetEnv + curriculum")
  under ``lax.scan`` in one jitted call, random actions drawn on the device. If that module is
  missing or its API differs, ``jit(vmap(env.step))`` is timed instead and the row says
  ``full_step: false``.
- **ceiling**: the bare ``mjx.step`` loop of the same model and settings (``frame_skip`` substeps
  over interpolated position targets in ``lax.scan``, vmapped), nothing else.
- compile time of each (AOT ``lower().compile()``), memory (state bytes per env, XLA's compiled
  buffer sizes per env, the device's peak bytes in use where JAX reports it), NaN terminations
  per million env steps and whether any observation was non-finite.
- once per (terrain, setting): single-env C MuJoCo env-steps/s on the host CPU (the baseline).

Timing: one warm-up call, then ``--repeats`` calls each ended by ``block_until_ready``; the
median is reported. Results go to ``--out-dir`` as JSON (rewritten after every row, so a killed
run keeps what it measured), a markdown table and a log-log plot.

The terrains: ``flat`` is the plane scene; ``heightfield`` the terrain scene with per-env terrain
on: every env draws its own tile at each reset from a pool of all random and deterministic types
but the spiral (``benchmarks.speed.cases``); ``heightfield_reachable`` the same with radial goals drawn on
reachable ground (``terrain.reachability``); ``heightfield_geodesic`` with goals at 32 sites a tile and
progress measured along the ground (``reward.progress: geodesic``). ``--backends jax,warp`` measures MJX's JAX and Warp
implementations side by side (each row records its backend).

    python -m benchmarks.speed.throughput [--backends jax,warp] [--batches 4096,16384,65536]
        [--terrains flat,heightfield,heightfield_reachable,heightfield_geodesic] [--settings NAME ...]
        [--observations original,heading,heading+scan,heading+randomized,stress_corner1,...]
        [--steps K] [--repeats R] [--episode-steps N] [--regenerate-every K] [--no-ceiling] [--append]
        [--out-dir benchmarks/results/throughput] [--quick]
"""

from __future__ import annotations

import argparse
import itertools
import statistics
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import jax

import benchmarks.speed.report
import hsa_mjx
import hsa_mjx.sim.backend
from benchmarks.fidelity.guard import SETTINGS, SHIPPED_BY_SCENE
from benchmarks.run_info import row_provenance, run_info
from benchmarks.speed.c_loop import cpu_baseline
from benchmarks.speed.cases import OBSERVATIONS, TERRAINS
from benchmarks.speed.loops import (
    CEILING_FIELDS,
    Timed,
    device_bytes,
    env_loop,
    measure_ceiling,
    per_env,
    time_loop,
    tree_bytes,
)

DEFAULT_BATCHES = (1024, 4096, 16384, 65536)
ENV_STEPS_PER_CALL = 2**17  # default K = this / batch, within [2, 20]: ~1-3 s per call on an H200
QUICK = {"batches": (8,), "steps": 2, "repeats": 2, "baseline_s": 0.5}


def bench_env(
    terrain: str,
    setting: str,
    backend: str = "auto",
    num_envs: int = 1,
    observation: str = "original",
    episode_steps: int | None = None,
) -> hsa_mjx.HSAEnv:
    """The training env (radial goals for the curriculum) on ``terrain`` with ``setting``'s physics and
    ``observation`` (``OBSERVATIONS``), on ``backend``, sized for batches of ``num_envs`` (Warp's shared
    contact buffer); ``episode_steps`` shortens the episodes (resets in every timed call)."""
    short = {} if episode_steps is None else {"termination.max_episode_steps": episode_steps}
    return hsa_mjx.make_env(
        "flat",
        num_envs=num_envs,
        **{
            "goal.mode": "radial",
            "physics.backend": backend,
            **TERRAINS[terrain],
            **SETTINGS[setting],
            **OBSERVATIONS[observation](),
            **short,
        },
    )


def batch_wrapper(env: hsa_mjx.HSAEnv, regenerate_every: int = 0) -> tuple[Any | None, str]:
    """The batch env with auto-reset (``AutoResetEnv``; re-drawing the random terrain tiles every
    ``regenerate_every`` steps when > 0), or None and why not."""
    try:
        from hsa_mjx.batch.auto_reset import AutoResetEnv

        return AutoResetEnv(env, regenerate_every), "AutoResetEnv"
    except (ImportError, AttributeError, TypeError, ValueError) as err:  # API not there (yet)
        return None, f"no AutoResetEnv ({type(err).__name__}: {err}); timed jit(vmap(env.step))"


def measure(
    env: hsa_mjx.HSAEnv,
    wrapper: Any | None,
    batch: int,
    steps: int,
    repeats: int,
    seed: int = 0,
    ceiling: bool = True,
) -> dict[str, Any]:
    """Env loop and (unless ``ceiling`` is False) physics ceiling at one batch size: rates, compile times,
    memory, NaN counts. Without the ceiling its fields are None."""
    key = jax.random.PRNGKey(seed)
    donate = jax.default_backend() != "cpu"  # CPU buffers cannot be donated (JAX warns)
    reset, run = env_loop(env, wrapper, steps)
    before = device_bytes("bytes_in_use")
    state = jax.jit(reset)(jax.random.split(key, batch))
    state_bytes = tree_bytes(state)
    env_t, state = time_loop(run, state, key, repeats, donate)
    after = device_bytes("bytes_in_use")
    live = None if before is None or after is None else after - before
    del state
    env_s, measured = statistics.median(env_t.seconds), batch * steps * repeats
    return {
        "batch": batch,
        "steps_per_call": steps,
        "repeats": repeats,
        "env_steps_per_s": round(batch * steps / env_s, 1),
        "env_call_s": [round(s, 5) for s in env_t.seconds],
        "compile_s_env": round(env_t.compile_s, 2),
        "state_bytes_per_env": per_env(state_bytes, batch),
        "env_compiled_bytes_per_env": per_env(env_t.compiled_bytes, batch),
        "device_live_bytes_per_env": per_env(live, batch),  # env state + executables, after the timed calls
        "device_peak_bytes_in_use": device_bytes("peak_bytes_in_use"),  # process high-water mark
        "env_steps_measured": measured,
        **_env_counts(env_t, measured),
        **(
            measure_ceiling(env, key, batch, steps, repeats, donate, env_s)
            if ceiling
            else dict.fromkeys(CEILING_FIELDS)
        ),
    }


def _env_counts(env_t: Timed, measured: int) -> dict[str, Any]:
    """NaN terminations, termination reasons, non-finite observations and episodes over the timed calls."""
    return {
        "nan_terminations": int(env_t.counters.get("termination/non_finite", 0)),
        "nan_terminations_per_million_env_steps": round(
            1e6 * env_t.counters.get("termination/non_finite", 0) / measured, 3
        ),
        "terminations_per_million_env_steps": {
            name.split("/", 1)[1]: round(1e6 * value / measured, 1)
            for name, value in env_t.counters.items()
            if name.startswith("termination/") and value
        },
        "obs_non_finite_seen": bool(env_t.counters.get("obs_non_finite", 0) > 0),
        "episodes_ended": int(env_t.counters.get("done", 0)),
    }


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    """Command-line options; ``--quick`` shrinks everything for a CPU pipeline check."""

    def ints(s):
        return tuple(int(v) for v in s.split(","))

    def names(s):
        return tuple(v for v in s.split(",") if v)

    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--batches", type=ints, default=None, help=f"comma list (default {DEFAULT_BATCHES})")
    p.add_argument(
        "--backends",
        type=names,
        default=("auto",),
        help=f"comma list of physics backends {list(hsa_mjx.sim.backend.BACKENDS)} (default auto)",
    )
    p.add_argument("--terrains", type=names, default=("flat", "heightfield"), help=f"comma list of {sorted(TERRAINS)}")
    p.add_argument(
        "--settings",
        nargs="+",
        default=None,
        help="physics settings from benchmarks.fidelity.guard.SETTINGS (space or comma separated); "
        f"default per scene {SHIPPED_BY_SCENE}",
    )
    p.add_argument(
        "--observations",
        type=names,
        default=("original",),
        help=f"comma list of {sorted(OBSERVATIONS)} (default original)",
    )
    p.add_argument(
        "--steps",
        type=int,
        default=None,
        help=f"env steps per timed call (lax.scan length); default {ENV_STEPS_PER_CALL} / batch in [2, 20]",
    )
    p.add_argument("--repeats", type=int, default=None, help="timed calls per measurement (default 3)")
    p.add_argument(
        "--episode-steps",
        type=int,
        default=None,
        help="end every episode after this many steps, so that resets run in the timed calls (the reset's cost)",
    )
    p.add_argument(
        "--no-ceiling",
        dest="ceiling",
        action="store_false",
        help="time the env loop only, not the bare physics loop beside it (long stability runs)",
    )
    p.add_argument("--baseline-seconds", type=float, default=None, help="C MuJoCo baseline duration (default 2)")
    p.add_argument("--budget-s", type=float, default=480.0, help="start no new measurement after this many s")
    p.add_argument("--out-dir", type=Path, default=Path("benchmarks/results/throughput"))
    p.add_argument("--append", action="store_true", help="merge into an existing results file")
    p.add_argument("--tag", default="", help="suffix of the output file names (e.g. stability)")
    p.add_argument("--compile-cache", type=Path, default=None, help="JAX persistent compilation cache dir")
    p.add_argument(
        "--regenerate-every",
        type=int,
        default=0,
        metavar="K",
        help="re-draw the random terrain tiles on the device every K steps of the timed loop (0: never)",
    )
    p.add_argument("--quick", action="store_true", help=f"pipeline check: {QUICK}")
    args = p.parse_args(argv)
    quick = QUICK if args.quick else {"batches": DEFAULT_BATCHES, "steps": None, "repeats": 3, "baseline_s": 2.0}
    args.batches = args.batches or quick["batches"]
    args.steps, args.repeats = args.steps or quick["steps"], args.repeats or quick["repeats"]
    args.baseline_seconds = args.baseline_seconds or quick["baseline_s"]
    if args.settings is not None:
        args.settings = [name for arg in args.settings for name in arg.split(",") if name]
    bad = (
        sorted(set(args.terrains) - set(TERRAINS))
        + sorted(set(args.settings or ()) - set(SETTINGS))
        + sorted(set(args.observations) - set(OBSERVATIONS))
    )
    if args.regenerate_every < 0:
        p.error(f"--regenerate-every must be >= 0, got {args.regenerate_every}")
    if args.episode_steps is not None and args.episode_steps < 1:
        p.error(f"--episode-steps must be >= 1, got {args.episode_steps}")
    if bad:
        p.error(
            f"unknown terrain/setting/observation {bad}; terrains {sorted(TERRAINS)}, settings {sorted(SETTINGS)}, "
            f"observations {sorted(OBSERVATIONS)}"
        )
    try:
        args.backends = tuple(dict.fromkeys(hsa_mjx.sim.backend.resolve(b) for b in args.backends))
    except ValueError as err:
        p.error(str(err))
    return args


def settings_for(terrain: str, settings: Sequence[str] | None) -> list[str]:
    """The settings to measure on ``terrain``: as given, or the shipped one of its scene."""
    return list(settings) if settings else [SHIPPED_BY_SCENE[TERRAINS[terrain]["scene"]]]


def steps_for(batch: int, steps: int | None) -> int:
    """Env steps per timed call: as given, or enough for about ENV_STEPS_PER_CALL env steps."""
    return steps if steps else max(2, min(20, ENV_STEPS_PER_CALL // batch))


def run_matrix(args: argparse.Namespace, info: dict[str, Any], out: Callable[[list], None]) -> list[dict]:
    """Measure every (backend, terrain, setting, batch) until the time budget runs out; write after each row."""
    rows = benchmarks.speed.report.load_rows(args.out_dir / f"{args.stem}.json") if args.append else []
    start = time.perf_counter()
    for terrain in args.terrains:
        for setting in settings_for(terrain, args.settings):
            baseline = cpu_baseline(bench_env(terrain, setting, "jax"), args.baseline_seconds)
            for backend, observation, batch in itertools.product(args.backends, args.observations, args.batches):
                if time.perf_counter() - start > args.budget_s:
                    print(
                        f"skipped {backend}/{terrain}/{setting}/{observation}/{batch}: past --budget-s {args.budget_s}",
                        flush=True,
                    )
                    continue
                rows = benchmarks.speed.report.upsert(
                    rows, _row(args, info, terrain, setting, backend, batch, baseline, observation)
                )
                out(rows)
    return rows


def _row(
    args: argparse.Namespace,
    info: dict[str, Any],
    terrain: str,
    setting: str,
    backend: str,
    batch: int,
    baseline: dict[str, float],
    observation: str = "original",
) -> dict[str, Any]:
    """One measured row (printed as it is done)."""
    env = bench_env(terrain, setting, backend, batch, observation, args.episode_steps)
    wrapper, note = batch_wrapper(env, args.regenerate_every)
    measured = measure(env, wrapper, batch, steps_for(batch, args.steps), args.repeats, ceiling=args.ceiling)
    row = {
        "terrain": terrain,
        "settings": setting,
        "observation": observation,
        "observation_size": env.observation_size,
        "episode_steps": env.config.termination.max_episode_steps,
        "regenerate_every": args.regenerate_every,
        "physics_backend": env.physics_backend,
        "overrides": SETTINGS[setting],
        "full_step": wrapper is not None,
        "full_step_note": note,
        **measured,
        **baseline,
        **row_provenance(info),
    }
    fmt = benchmarks.speed.report.fmt
    print(
        f"{backend:4s} {terrain:11s} {setting} {observation} batch {batch:6d}: env {row['env_steps_per_s']:12,.0f}/s  "
        f"ceiling {fmt(row['physics_ceiling_env_steps_per_s'])}/s  compile "
        f"{row['compile_s_env']:.1f}+{fmt(row['compile_s_ceiling'], 1)} s  "
        f"NaN/M {row['nan_terminations_per_million_env_steps']}  obs non-finite {row['obs_non_finite_seen']}",
        flush=True,
    )
    return row


def main(argv: Sequence[str] | None = None) -> None:
    args = parse_args(argv)
    if args.compile_cache:
        jax.config.update("jax_compilation_cache_dir", str(args.compile_cache))
    info = run_info()
    tag = "_".join(t for t in (args.tag, "quick" if args.quick else "") if t)
    args.stem = f"throughput_{benchmarks.speed.report.slug(info['device'])}" + (
        f"_{benchmarks.speed.report.slug(tag)}" if tag else ""
    )
    meta = {
        **info,
        "steps_per_call": args.steps or f"{ENV_STEPS_PER_CALL} / batch in [2, 20]",
        "repeats": args.repeats,
        "settings": {t: {s: SETTINGS[s] for s in settings_for(t, args.settings)} for t in args.terrains},
        "backends": list(args.backends),
        "observations": {o: OBSERVATIONS[o]() for o in args.observations},
        "terrains": {t: TERRAINS[t] for t in args.terrains},
    }
    rows = run_matrix(args, info, lambda rows: benchmarks.speed.report.write_all(args.out_dir, args.stem, rows, meta))
    paths = benchmarks.speed.report.write_all(args.out_dir, args.stem, rows, meta)
    print(benchmarks.speed.report.markdown(rows, meta))
    print("wrote " + ", ".join(str(p) for p in paths))


if __name__ == "__main__":
    main()
