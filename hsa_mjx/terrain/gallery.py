"""Render every terrain generator to one PNG: a height map and a 3-D view per type.

    python -m hsa_mjx.terrain.gallery                 # writes docs/terrains.png
    python -m hsa_mjx.terrain.gallery --out t.png --seed 3

Each terrain is shown as an env gets it: generated on the heightfield of ``assets/scene_terrain.xml``,
spawn zone applied as in the shipped configs (off for the corridor and spiral tasks), lifted and
clipped into the heightfield's range. Axes are world x and y; the robot spawns at the origin,
facing +x.
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import jax
import mujoco
import numpy as np
from matplotlib.figure import Figure

from hsa_mjx.resources import scene_path
from hsa_mjx.terrain.grid import Grid
from hsa_mjx.terrain.params import TERRAIN_TYPES, FlatSpawnConfig, TerrainConfig
from hsa_mjx.terrain.sampler import TerrainSampler

OUTPUT = Path("docs") / "terrains.png"  # relative to where it runs: the checkout root redraws the README figure
NO_SPAWN_ZONE = ("corridor", "spiral")  # their task configs disable it
COLUMNS = 3  # terrain types per figure row (each takes a map and a 3-D panel)
CMAP = "viridis"


def terrain_heights(terrain_type: str, grid: Grid, seed: int) -> np.ndarray:
    """World heights (nrow, ncol) of one terrain as an env sees it (after lifting into [0, z_scale])."""
    spawn = FlatSpawnConfig(enabled=terrain_type not in NO_SPAWN_ZONE)
    config = dataclasses.replace(TerrainConfig(), types=(terrain_type,), proportions=(1.0,), flat_spawn=spawn)
    data, _ = TerrainSampler(config, grid).sample(jax.random.PRNGKey(seed))
    return np.asarray(data).reshape(grid.nrow, grid.ncol) * grid.z_scale


def _draw(fig: Figure, spec, terrain_type: str, grid: Grid, heights: np.ndarray) -> None:
    """One type: height map (left) and 3-D surface (right), sharing the colour scale."""
    extent = (-grid.half_x, grid.half_x, -grid.half_y, grid.half_y)
    top = max(float(heights.max()), 1e-3)
    ax_map = fig.add_subplot(spec[0])
    image = ax_map.imshow(heights, origin="lower", extent=extent, cmap=CMAP, vmin=0.0, vmax=top)
    ax_map.plot([-0.2, 0.2], [0.0, 0.0], "r-", lw=2)  # the robot at the spawn (block A to block B)
    ax_map.set_title(f"{terrain_type}  (0 to {heights.max():.2f} m)", fontsize=10)
    ax_map.set_xlabel("x (m)", fontsize=8)
    ax_map.set_ylabel("y (m)", fontsize=8)
    ax_map.tick_params(labelsize=7)
    fig.colorbar(image, ax=ax_map, fraction=0.046, pad=0.02).ax.tick_params(labelsize=7)
    ax_3d = fig.add_subplot(spec[1], projection="3d")
    x, y = grid.mesh()
    ax_3d.plot_surface(x, y, heights, cmap=CMAP, vmin=0.0, vmax=top, linewidth=0, antialiased=False)
    ax_3d.set_zlim(0.0, max(top, 0.5))
    ax_3d.set_box_aspect((1.0, 1.0, 0.4), zoom=1.15)
    ax_3d.view_init(elev=35, azim=-60)
    ax_3d.tick_params(labelsize=6)


def render_gallery(out: Path, seed: int = 0) -> Path:
    """Draw all eleven generators into ``out`` (PNG) and return the path."""
    model = mujoco.MjModel.from_xml_path(str(scene_path("terrain")))
    grid = Grid.from_model(model)
    rows = -(-len(TERRAIN_TYPES) // COLUMNS)
    fig = Figure(figsize=(6.6 * COLUMNS, 3.0 * rows))
    outer = fig.add_gridspec(rows, COLUMNS, hspace=0.35, wspace=0.15)
    for i, terrain_type in enumerate(TERRAIN_TYPES):
        spec = outer[i // COLUMNS, i % COLUMNS].subgridspec(1, 2, width_ratios=(1.0, 1.4), wspace=0.0)
        _draw(fig, spec, terrain_type, grid, terrain_heights(terrain_type, grid, seed))
    fig.suptitle("The eleven terrain generators (world axes; red: the robot at its spawn)", fontsize=13)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=80, bbox_inches="tight")
    return out


def main() -> None:
    """Command line: write the gallery PNG."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, default=OUTPUT, help="PNG to write (default docs/terrains.png)")
    parser.add_argument("--seed", type=int, default=0, help="PRNG seed of the random types")
    args = parser.parse_args()
    print(f"wrote {render_gallery(args.out, args.seed)}")


if __name__ == "__main__":
    main()
