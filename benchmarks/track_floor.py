"""How wide the spiral track's flat floor is, ours against the original's edge rule.

    python -m benchmarks.track_floor                          # widths 0.8 0.9 0.95 1.0
    python -m benchmarks.track_floor --widths 0.8 0.95 --out floor.json

The original carved the track by zeroing every heightfield vertex within ``track_width / 2`` of
the line and leaving every other vertex at the wall height. Our generator puts the wall's half
height at ``track_width / 2`` (a ramp one vertex spacing wide centred there), so on the same
0.2 m grid our floor is one spacing narrower. This measures both on the scene's heightfield,
exactly as MuJoCo triangulates it: at ``samples`` points along the line it walks across the
track (along the line's normal, in ``step`` increments) and reports the width of the stretch
around the line that stays below ``tolerance``. The original rule is applied to our track line
and start disc, so only the edge rule differs.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
from pathlib import Path

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from hsa_mjx.model import scene_path
from hsa_mjx.terrain.generators import spiral, spiral_extension, spiral_track_distance
from hsa_mjx.terrain.grid import Grid, surface_height, to_hfield_data
from hsa_mjx.terrain.params import SpiralParams

ORIGINAL_WALL = 0.5  # m, the original's spiral wall height (ORIGINAL_FACTS 12)
HALF_SPAN = 0.7  # m, how far across the track each probe looks on either side of the line


def scene_grid() -> Grid:
    """The heightfield grid of ``assets/scene_terrain.xml``."""
    return Grid.from_model(mujoco.MjModel.from_xml_path(str(scene_path("terrain"))))


def ours(params: SpiralParams, grid: Grid) -> jax.Array:
    """Heightfield data of our spiral generator (half-height edge at ``track_width / 2``)."""
    x, y = (jnp.asarray(v, jnp.float32) for v in grid.mesh())
    return to_hfield_data(spiral(jax.random.PRNGKey(0), params, grid, x, y), grid)


def original_rule(params: SpiralParams, grid: Grid) -> jax.Array:
    """Heightfield data of the original's rule on our line: vertices within ``track_width / 2`` at 0."""
    x, y = (jnp.asarray(v, jnp.float32) for v in grid.mesh())
    carved = (spiral_track_distance(params, x, y, spiral_extension(params)) <= 0.5 * params.track_width) | (
        jnp.hypot(x, y) <= params.start_radius)
    return to_hfield_data(jnp.where(carved, 0.0, ORIGINAL_WALL), grid)


def line_points(params: SpiralParams, samples: int, margin: float = 0.2) -> tuple[np.ndarray, np.ndarray]:
    """Points on the track line and unit normals there, (samples, 2) each, ``margin`` rad from both ends."""
    u = np.linspace(margin, 2.0 * math.pi * params.turns - margin, samples)
    rate = (params.end_radius - params.start_radius) / (2.0 * math.pi * params.turns)
    r, angle = params.start_radius + rate * u, math.pi - u
    radial = np.stack([np.cos(angle), np.sin(angle)], -1)
    along = rate * radial + r[:, None] * np.stack([np.sin(angle), -np.cos(angle)], -1)  # d/du
    normal = np.stack([-along[:, 1], along[:, 0]], -1) / np.linalg.norm(along, axis=-1, keepdims=True)
    return r[:, None] * radial, normal


def floor_widths(data: jax.Array, grid: Grid, params: SpiralParams, samples: int = 400,
                 tolerance: float = 0.01, step: float = 0.005) -> np.ndarray:
    """Width (m) of the floor below ``tolerance`` around the line at each sample (0 where the line is above)."""
    centre, normal = line_points(params, samples)
    offsets = np.arange(-round(HALF_SPAN / step), round(HALF_SPAN / step) + 1) * step
    points = centre[:, None, :] + offsets[None, :, None] * normal[:, None, :]
    flat = np.asarray(surface_height(data, grid, jnp.asarray(points, jnp.float32))) < tolerance
    mid = len(offsets) // 2
    left = np.argmin(flat[:, mid::-1], axis=1)  # first raised probe walking from the line, either way
    right = np.argmin(flat[:, mid:], axis=1)
    left = np.where(flat[:, mid::-1].all(axis=1), mid + 1, left)
    right = np.where(flat[:, mid:].all(axis=1), mid + 1, right)
    return np.where(flat[:, mid], (left + right - 2) * step, 0.0)


def summary(widths: np.ndarray, narrow: float) -> dict:
    """Minimum, 10th percentile, median and mean width, and the share of the line narrower than ``narrow``."""
    return {"min": float(widths.min()), "p10": float(np.percentile(widths, 10)),
            "median": float(np.median(widths)), "mean": float(widths.mean()),
            "narrow_share": float(np.mean(widths < narrow))}


def compare(track_widths: list[float], narrow: float = 0.4, tolerance: float = 0.01,
            grid: Grid | None = None) -> list[dict]:
    """One row per rule and width: the original's rule at 0.8 m, then ours at each of ``track_widths``."""
    grid = grid or scene_grid()
    rows = []
    for rule, make, widths in (("original", original_rule, [0.8]), ("ours", ours, track_widths)):
        for width in widths:
            params = dataclasses.replace(SpiralParams(), track_width=width)
            floor = floor_widths(make(params, grid), grid, params, tolerance=tolerance)
            rows.append({"rule": rule, "track_width": width, **summary(floor, narrow)})
    return rows


def main() -> None:
    """Command line: print the table (and write it as JSON with --out)."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--widths", type=float, nargs="+", default=[0.8, 0.9, 0.95, 1.0])
    parser.add_argument("--narrow", type=float, default=0.4, help="report the share narrower than this (m)")
    parser.add_argument("--tolerance", type=float, default=0.01, help="floor: below this height (m)")
    parser.add_argument("--out", type=Path, help="JSON file to write")
    args = parser.parse_args()
    rows = compare(args.widths, args.narrow, args.tolerance)
    print(f"flat floor (< {args.tolerance} m) across the spiral track, metres; narrow: < {args.narrow} m")
    print("| rule | track_width | min | p10 | median | mean | narrow share |\n|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['rule']} | {r['track_width']} | {r['min']:.2f} | {r['p10']:.2f} | {r['median']:.2f} "
              f"| {r['mean']:.2f} | {r['narrow_share']:.2f} |")
    if args.out:
        args.out.write_text(json.dumps(rows, indent=1) + "\n")


if __name__ == "__main__":
    main()
