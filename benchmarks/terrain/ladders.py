"""How hard each terrain level is for this robot: the ladders of a training config measured on its map.

    python -m benchmarks.terrain.ladders [--config configs/train_rough.yaml] [--goal-range 1.5 4.5]
        [--out benchmarks/results/ladders] [--picture docs/ladders.png]

Builds the config's terrain pool as training draws it (every type, level and tile; no re-draws) and
maps each tile with the robot's measured limits (``traversability.ROBOT``, ``python -m
benchmarks.terrain.capability``). Per type and level it reports the parameter the difficulty scales in physical
units, the share of the goal ring (cells at a straight-line distance inside ``--goal-range``) the robot
can reach from its spawn, the median detour (path over straight-line distance) to the reachable ones,
and the steepest slope over the robot's length on the reachable ground. A level whose goals cannot be
reached grades nothing; a ladder whose levels all read alike grades little. Writes
``ladders_<config>.{json,md}``.

``--speeds TERRAIN_EVAL.json`` (a ``python -m train.evaluate ... --terrain-types`` result) also counts
time: the robot's measured speed on each type and level (how fast the goals it reached were reached,
interpolated between the evaluated difficulties), the time the farthest goals need at it (the ring's
outer radius times the median detour) and whether that fits in the config's episode. A level whose
goals need more than the episode's time is not feasible, however reachable its ground.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.run_info import run_info, write_result
from hsa_mjx.terrain import reachability
from hsa_mjx.terrain import traversability as tv
from hsa_mjx.terrain.atlas import AtlasLayout, TerrainPool
from hsa_mjx.terrain.generators import DIFFICULTY_PARAMETER, stage_fraction
from hsa_mjx.terrain.grid import Grid
from hsa_mjx.terrain.params import TERRAIN_TYPES, TerrainConfig


def parameter_at(config: TerrainConfig, terrain_type: str, difficulty: float) -> str:
    """What the level means in physical units ("-" for flat): the values the difficulty sets."""
    p, d = config.params(terrain_type), difficulty
    if terrain_type == "corridor":
        return _corridor_at(p, d)
    if terrain_type == "poles" and p.grade == "count":
        count = math.ceil(d * p.num - 1e-6)
        return f"{count} poles {p.height[0]:.2g}-{p.height[1]:.2g} m high, >= {p.min_spacing:.2g} m apart"
    if terrain_type == "flat_with_ramp":
        length = p.length * 2.0 * (Grid().half_x if p.direction.endswith("x") else Grid().half_y)
        return f"height {d * p.height:.3g} m ({math.degrees(math.atan(d * p.height / length)):.1f} deg)"
    if terrain_type == "wavy":
        return f"amplitude {d * p.amplitude:.3g} m ({math.degrees(math.atan(d * p.amplitude * p.scale)):.1f} deg)"
    name = DIFFICULTY_PARAMETER[terrain_type].split()[0].rstrip(",")
    if p is None or not hasattr(p, name):
        return "-"
    value = getattr(p, name)
    unit = "deg" if name == "angle" else "m"
    if isinstance(value, tuple):
        return f"{name} {d * value[0]:.3g}-{d * value[1]:.3g} {unit}"
    return f"{name} {d * value:.3g} {unit}"


def _corridor_at(p: Any, d: float) -> str:
    """Wall height, floor width and bend of a corridor at difficulty ``d`` (the generator's stages)."""
    height = p.wall_height * min(1.0, d / p.wall_until)
    width = p.corridor_width
    if p.start_width > 0:
        width = p.start_width + (p.corridor_width - p.start_width) * float(
            stage_fraction(d, p.wall_until, p.width_until)
        )
    bend = p.bend_amplitude * float(stage_fraction(d, p.width_until, 1.0)) if p.bend_amplitude > 0 else 0.0
    return f"walls {height:.3g} m, floor {width:.3g} m" + (f", bend +-{bend:.2g} m" if bend else "")


def tile_measures(pool: TerrainPool, goal_range: tuple[float, float]) -> list[dict[str, float]]:
    """Per tile: reachable share of the goal ring, median detour and steepest reachable slope."""
    limits, grid = tv.ROBOT, pool.layout.tile
    fields = reachability.spawn_fields(pool.tiles, grid, limits)
    centres = reachability.cell_centres(grid, limits.resolution)
    straight = np.hypot(centres[..., 0], centres[..., 1])
    ring = (straight >= goal_range[0]) & (straight <= goal_range[1])
    out = []
    for data, field in zip(pool.tiles, fields):
        reached = ring & np.isfinite(field)
        slope = np.asarray(tv.span_slope(tv.surface_map(data, grid, limits.resolution), limits))[np.isfinite(field)]
        out.append(
            {
                "reachable_share": float(reached.sum() / ring.sum()),
                "median_detour": float(np.median(field[reached] / straight[reached])) if reached.any() else None,
                "steepest_reachable_slope_deg": float(np.degrees(np.arctan(slope.max()))) if slope.size else None,
            }
        )
    return out


def ladder_rows(config: TerrainConfig, goal_range: tuple[float, float]) -> list[dict[str, Any]]:
    """One row per (type, level): the parameter, and the tile measures (mean share, worst tile, detour)."""
    config = dataclasses.replace(config, reachability=dataclasses.replace(config.reachability, enabled=False))
    layout = AtlasLayout.from_config(config, Grid())
    pool = TerrainPool(config, layout)
    measures = tile_measures(pool, goal_range)
    rows = []
    for name in layout.types:
        for level, difficulty in enumerate(layout.difficulties):
            mine = [
                m
                for m, kind, lv in zip(measures, pool.tile_type, pool.tile_level)
                if TERRAIN_TYPES[kind] == name and lv == level
            ]
            shares = [m["reachable_share"] for m in mine]
            detours = [m["median_detour"] for m in mine if m["median_detour"] is not None]
            slopes = [m["steepest_reachable_slope_deg"] for m in mine if m["steepest_reachable_slope_deg"] is not None]
            rows.append(
                {
                    "type": name,
                    "level": level,
                    "difficulty": round(difficulty, 4),
                    "parameter": parameter_at(config, name, difficulty),
                    "tiles": len(mine),
                    "reachable_share": round(float(np.mean(shares)), 3),
                    "worst_tile_share": round(float(np.min(shares)), 3),
                    "median_detour": round(float(np.median(detours)), 3) if detours else None,
                    "steepest_reachable_slope_deg": round(float(np.max(slopes)), 1) if slopes else None,
                }
            )
    return rows


def read_speeds(path: Path) -> dict[str, list[tuple[float, float | None]]]:
    """Per type, (difficulty, speed of the reached goals in m/s, or None) from a terrain evaluation."""
    if not path.is_file():
        raise FileNotFoundError(f"--speeds: no such file {path}")
    rows = json.loads(path.read_text()).get("rows") or []
    if not rows or any("success_speed_m_s" not in r for r in rows):
        raise ValueError(f"--speeds: {path} holds no per-cell success_speed_m_s (evaluate with today's train.evaluate)")
    speeds: dict[str, list[tuple[float, float | None]]] = {}
    for r in sorted(rows, key=lambda r: r["difficulty"]):
        speeds.setdefault(r["type"], []).append((float(r["difficulty"]), r["success_speed_m_s"]))
    return speeds


def speed_at(measured: list[tuple[float, float | None]], difficulty: float) -> float | None:
    """The speed at ``difficulty``, linear between the evaluated difficulties; None outside them or where the
    nearest evaluated cell reached no goal (its speed was not measured)."""
    nearest = min(measured, key=lambda m: abs(m[0] - difficulty))
    known = [(d, v) for d, v in measured if v is not None]
    if nearest[1] is None or not known or not known[0][0] <= difficulty <= known[-1][0]:
        return None
    return float(np.interp(difficulty, [d for d, _ in known], [v for _, v in known]))


def add_time(rows: list[dict[str, Any]], speeds: dict, goal_max: float, episode_s: float) -> list[dict[str, Any]]:
    """``rows`` with each level's measured speed, the farthest goals' time at it and whether it fits."""
    out = []
    for r in rows:
        speed = speed_at(speeds[r["type"]], r["difficulty"]) if r["type"] in speeds else None
        far = None if speed is None or r["median_detour"] is None else goal_max * r["median_detour"] / speed
        out.append({**r, "speed_m_s": speed, "far_goal_s": far, "in_time": None if far is None else far <= episode_s})
    return out


def markdown(result: dict[str, Any]) -> str:
    """The rows as one table per type."""
    timed = "speeds" in result
    lines = [
        f"# Terrain ladders of `{result['config']}` on the robot's map",
        "",
        f"{result['date']}; command `{result['command']}`; goal ring {result['goal_range']} m (straight line); "
        f"limits {result['limits']}."
        + (f" Speeds measured in `{result['speeds']}`; episodes of {result['episode_s']:g} s." if timed else ""),
        "",
        "| type | level | parameter | reachable share of the goal ring | worst tile | median detour | "
        "steepest reachable slope deg |" + (" speed m/s | farthest goals s | in time |" if timed else ""),
        "| --- " * (10 if timed else 7) + "|",
    ]
    for r in result["rows"]:
        detour = "-" if r["median_detour"] is None else f"{r['median_detour']:.2f}"
        slope = "-" if r["steepest_reachable_slope_deg"] is None else f"{r['steepest_reachable_slope_deg']:.1f}"
        line = (
            f"| {r['type']} | {r['level']} | {r['parameter']} | {r['reachable_share']:.0%} | "
            f"{r['worst_tile_share']:.0%} | {detour} | {slope} |"
        )
        if timed:
            fits = {None: "not measured", True: "yes", False: "**no**"}[r["in_time"]]
            speed = "-" if r["speed_m_s"] is None else f"{r['speed_m_s']:.3f}"
            far = "-" if r["far_goal_s"] is None else f"{r['far_goal_s']:.0f}"
            line += f" {speed} | {far} | {fits} |"
        lines.append(line)
    return "\n".join(lines) + "\n"


def draw_levels(config: TerrainConfig, out: Path, levels: Sequence[int] = (0, 5, 9)) -> Path:
    """A PNG of one tile of each type at ``levels`` (height maps, a colour scale per type; the red bar is the
    robot at its spawn), as the pool holds them."""
    from matplotlib.figure import Figure

    config = dataclasses.replace(config, reachability=dataclasses.replace(config.reachability, enabled=False))
    layout = AtlasLayout.from_config(config, Grid())
    pool, grid = TerrainPool(config, layout), layout.tile
    extent = (-grid.half_x, grid.half_x, -grid.half_y, grid.half_y)
    levels = [lv for lv in levels if lv < layout.levels]
    fig = Figure(figsize=(2.6 * len(levels), 2.5 * len(layout.types)))
    for row, name in enumerate(layout.types):
        tiles = [i for i, (t, lv) in enumerate(zip(pool.tile_type, pool.tile_level)) if TERRAIN_TYPES[t] == name]
        heights = {lv: pool.tiles[min(i for i in tiles if pool.tile_level[i] == lv)] * grid.z_scale for lv in levels}
        top = max(max(float(h.max()) for h in heights.values()), 1e-3)
        for col, lv in enumerate(levels):
            ax = fig.add_subplot(len(layout.types), len(levels), row * len(levels) + col + 1)
            ax.imshow(heights[lv].reshape(grid.nrow, grid.ncol), origin="lower", extent=extent, vmin=0.0, vmax=top)
            ax.plot([-0.2, 0.2], [0.0, 0.0], "r-", lw=2)
            ax.set_title(f"{name} level {lv}\n{parameter_at(config, name, layout.difficulties[lv])}", fontsize=6)
            ax.set_xticks([])
            ax.set_yticks([])
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=90, bbox_inches="tight")
    return out


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--config", type=Path, default=Path("configs/train_rough.yaml"), help="a training or env config")
    p.add_argument("--goal-range", type=float, nargs=2, default=(1.5, 4.5), metavar=("MIN", "MAX"))
    p.add_argument("--out", type=Path, default=Path("benchmarks/results/ladders"))
    p.add_argument("--picture", type=Path, help="also draw a tile of each type at levels 0, 5 and 9 into this PNG")
    p.add_argument("--speeds", type=Path, help="a terrain evaluation (terrain_eval.json): count time as well")
    args = p.parse_args(argv)
    if not 0.0 <= args.goal_range[0] < args.goal_range[1]:
        p.error(f"--goal-range MIN MAX must satisfy 0 <= MIN < MAX, got {args.goal_range}")
    if not args.config.is_file():
        p.error(f"--config: no such file {args.config}")
    from train import config as train_config

    env = train_config.load(str(args.config), []).env
    if env.scene != "terrain":
        p.error(f"--config: {args.config} has no terrain (scene {env.scene!r})")
    goal_range = (float(args.goal_range[0]), float(args.goal_range[1]))
    try:
        speeds = read_speeds(args.speeds) if args.speeds else None
    except (FileNotFoundError, ValueError) as err:
        p.error(str(err))
    rows = ladder_rows(env.terrain, goal_range)
    timing = {}
    if speeds is not None:
        episode_s = env.termination.max_episode_steps * env.dt
        rows = add_time(rows, speeds, goal_range[1], episode_s)
        timing = {"speeds": str(args.speeds), "episode_s": episode_s}
    result = {
        **run_info(),
        "config": str(args.config),
        "goal_range": list(goal_range),
        "limits": dataclasses.asdict(tv.ROBOT),
        **timing,
        "rows": rows,
    }
    write_result(args.out / f"ladders_{args.config.stem}", result, markdown(result))
    if args.picture:
        print(f"wrote {draw_levels(env.terrain, args.picture)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
