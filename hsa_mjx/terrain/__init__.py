"""Terrain: the original's eleven heightfield generators as pure JAX functions, and per-env sampling.

Public API:
    TERRAIN_TYPES                          the eleven type names
    generate(type, key, params, grid, d)   world heights (nrow, ncol) of one terrain at difficulty d in [0, 1]
    TerrainSampler(config, grid).sample    one env's heightfield data and type id from a key
    Grid                                   the heightfield's static geometry (``Grid.from_model``)
    to_hfield_data, surface_height         heights -> MuJoCo data in [0, 1]; exact surface lookup
    TerrainConfig and the *Params classes  the ``terrain:`` config section
    traversability                         free cells of a tile for the robot (its measured limits: ROBOT),
                                           path distances over them
    reachability                           the ground reachable from the spawn per tile; goals drawn on it

Layout convention (MuJoCo's): heights[row, col] is the vertex at world x = xs[col], y = ys[row].
See ``docs/terrain.md``.
"""

from hsa_mjx.terrain.generators import GENERATORS
from hsa_mjx.terrain.grid import Grid, surface_height, to_hfield_data
from hsa_mjx.terrain.params import (
    TERRAIN_TYPES,
    CorridorParams,
    CratersParams,
    FlatSpawnConfig,
    FlatWithInclineParams,
    FlatWithRampParams,
    InclineParams,
    PerlinParams,
    PolesParams,
    SpiralParams,
    StairsParams,
    TerrainConfig,
    WavyParams,
    check_type,
    validate_terrain,
)
from hsa_mjx.terrain.sampler import TerrainSampler, apply_flat_spawn, generate, spawn_plane

__all__ = [
    "TERRAIN_TYPES",
    "GENERATORS",
    "Grid",
    "generate",
    "TerrainSampler",
    "apply_flat_spawn",
    "spawn_plane",
    "surface_height",
    "to_hfield_data",
    "TerrainConfig",
    "FlatSpawnConfig",
    "WavyParams",
    "PerlinParams",
    "StairsParams",
    "InclineParams",
    "CratersParams",
    "PolesParams",
    "FlatWithInclineParams",
    "FlatWithRampParams",
    "CorridorParams",
    "SpiralParams",
    "check_type",
    "validate_terrain",
]
