"""Geodesic distance fields: a terrain task's goal-site fields built by sweeps and by the plain relaxation.

    python -m benchmarks.terrain.fields                                  # configs/train_rough.yaml's pool
    python -m benchmarks.terrain.fields --config configs/train_spiral.yaml --repeats 5

Every tile of the config's pool gets ``terrain.reachability.goal_sites`` sites on random free cells;
each site's field is its path distance over the free cells, then continued into the blocked ones (as
``hsa_mjx.terrain.geodesic.site_field``), all in one jitted, vmapped call. It is timed with
``traversability.relax`` (Gauss-Seidel sweeps) and with every cell relaxed from its 8 neighbours at
once (the reference), on the default JAX device: the first call (compile and run) and the fastest of
``--repeats`` more. Prints both and whether the two fields are equal bit for bit (exit 1 where not).
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

from hsa_mjx.sim.model import load_scene
from hsa_mjx.terrain import traversability as tv
from train import config as train_config

Relax = Callable[[jax.Array, jax.Array, float], jax.Array]


def neighbours_at_once(distances: jax.Array, update: jax.Array, resolution: float) -> jax.Array:
    """The reference relaxation: every ``update`` cell from its 8 neighbours at once, to convergence."""
    costs = [resolution * float(np.hypot(dr, dc)) for dr, dc in tv.NEIGHBOURS]

    def step(state: tuple[jax.Array, jax.Array]) -> tuple[jax.Array, jax.Array]:
        d, _ = state
        best = d
        for (dr, dc), cost in zip(tv.NEIGHBOURS, costs):
            best = jnp.minimum(best, tv.shifted(d, dr, dc, jnp.inf) + cost)
        best = jnp.where(update, best, d)
        return best, jnp.any(best < d)

    return jax.lax.while_loop(lambda s: s[1], step, (distances, jnp.asarray(True)))[0]


def fields_fn(relax: Relax, resolution: float) -> Callable[[jax.Array, jax.Array], jax.Array]:
    """Jitted: (free maps (tiles, n, n), site cells (tiles, sites, 2)) -> fields (tiles, sites, n, n)."""

    def one(free: jax.Array, site: jax.Array) -> jax.Array:
        free = free.at[site[0], site[1]].set(True)
        start = jnp.full(free.shape, jnp.inf, jnp.float32).at[site[0], site[1]].set(0.0)
        d = relax(jnp.where(free, start, jnp.inf), free, resolution)
        return relax(d, ~jnp.isfinite(d), resolution)

    return jax.jit(jax.vmap(jax.vmap(one, (None, 0))))


def inputs(config_path: str, seed: int) -> tuple[jax.Array, jax.Array, float]:
    """The config's pool as free maps, random free site cells per tile and the map resolution."""
    env = train_config.from_dict(train_config.read_yaml(config_path)).env
    _, pool = load_scene(env)
    if pool is None:
        raise ValueError(f"{config_path}: scene {env.scene!r} has no terrain pool; give a terrain config")
    resolution = env.terrain.reachability.resolution
    limits = dataclasses.replace(tv.ROBOT, resolution=resolution)
    grid = pool.layout.tile
    free = jax.vmap(lambda data: tv.free_cells(tv.surface_map(data, grid, resolution), limits))(jnp.asarray(pool.tiles))
    free = np.asarray(free)
    count, rng = max(env.terrain.reachability.goal_sites, 1), np.random.default_rng(seed)
    sites = np.stack([cells[rng.integers(len(cells), size=count)] for cells in map(np.argwhere, free)])
    return jnp.asarray(free), jnp.asarray(sites, jnp.int32), resolution


def timed(fn: Callable, args: tuple, repeats: int) -> tuple[np.ndarray, float, float]:
    """(output, first call s, fastest of ``repeats`` further calls s)."""
    start = time.perf_counter()
    out = jax.block_until_ready(fn(*args))
    first, best = time.perf_counter() - start, np.inf
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(fn(*args))
        best = min(best, time.perf_counter() - start)
    return np.asarray(out), first, best


def main(argv: list[str] | None = None) -> int:
    """Command line: time both relaxations, print, exit 1 when their fields differ."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--config", default="configs/train_rough.yaml", help="a training config with terrain")
    parser.add_argument("--repeats", type=int, default=3, help="timed calls after the first")
    parser.add_argument("--seed", type=int, default=0, help="draws the site cells")
    args = parser.parse_args(argv)
    free, sites, resolution = inputs(args.config, args.seed)
    print(
        f"{args.config}: {sites.shape[0]} tiles x {sites.shape[1]} sites, {free.shape[1]} x {free.shape[2]} cells, "
        f"{jax.devices()[0].device_kind}"
    )
    out = {}
    for name, relax in (("sweeps", tv.relax), ("neighbours at once", neighbours_at_once)):
        out[name], first, best = timed(fields_fn(relax, resolution), (free, sites), args.repeats)
        print(f"{name:>20}: first call {first:.2f} s, then {best * 1e3:.1f} ms")
    same = np.array_equal(*out.values(), equal_nan=True)
    print("fields equal bit for bit" if same else "FIELDS DIFFER")
    return 0 if same else 1


if __name__ == "__main__":
    raise SystemExit(main())
