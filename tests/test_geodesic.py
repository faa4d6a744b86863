"""Progress along the path: distance fields of goal sites, read by the env's geodesic progress."""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import hsa_mjx
from hsa_mjx.task import goals
from hsa_mjx.terrain import geodesic, reachability
from hsa_mjx.terrain import traversability as tv
from hsa_mjx.terrain.sampler import TerrainSampler

RES = 0.1


def _free_with_wall() -> np.ndarray:
    """A 10 x 10 m map (0.1 m cells) with a wall along x = 1 m from y = -1 m up to the top edge."""
    pts = tv.map_points(hsa_mjx.terrain.Grid(), RES)
    wall = (np.abs(pts[..., 0] - 1.0) < 0.5 * RES) & (pts[..., 1] >= -1.0)
    return ~wall


def test_the_distance_around_a_wall_matches_the_path_length_within_one_cell():
    free = jnp.asarray(_free_with_wall())
    site = tv.cell_of(jnp.array([2.0, 0.0]), hsa_mjx.terrain.Grid(), RES)
    field = np.asarray(geodesic.site_field(free, site, RES))
    start = tuple(np.asarray(tv.cell_of(jnp.zeros(2), hsa_mjx.terrain.Grid(), RES)))
    # The shortest way from the origin passes the wall's end, one cell below y = -1 (x = 1, y = -1.1).
    known = 2.0 * math.hypot(1.0, 1.1)
    assert abs(field[start] - known) <= RES
    assert field[start] > 2.0 + 0.5  # far longer than the straight line through the wall
    # Every cell has a finite distance, the wall's own cells too (continued from their free neighbours).
    assert np.isfinite(field).all() and field[~np.asarray(free)].min() > 0


def test_extend_keeps_finite_cells_and_fills_the_rest_from_them():
    d = jnp.full((5, 5), jnp.inf).at[2, 2].set(1.0)
    out = np.asarray(geodesic.extend(d, RES))
    assert (
        out[2, 2] == 1.0
        and np.isclose(out[2, 4], 1.0 + 2 * RES)
        and np.isclose(out[0, 0], 1.0 + 2 * math.sqrt(2) * RES)
    )


def test_sites_spread_evenly_over_the_goal_range_and_the_field_reads_exactly_at_its_nodes():
    free = jnp.ones((101, 101), bool)
    origin = tv.cell_of(jnp.zeros(2), hsa_mjx.terrain.Grid(), RES)
    spawn = tv.path_distances(free, origin, RES)
    cells = geodesic.pick_sites(jax.random.PRNGKey(0), spawn, (1.5, 4.5), 6)
    d = np.asarray(spawn)[np.asarray(cells)[:, 0], np.asarray(cells)[:, 1]]
    bins = 1.5 + 0.5 * np.arange(7)
    assert ((d >= bins[:-1]) & (d <= bins[1:])).all()  # site k in the k-th bin
    field = jnp.arange(16.0).reshape(4, 4)
    assert float(geodesic.field_distance(field, (0.0, 0.0), 0.2, jnp.array([0.4, 0.2]))) == 6.0
    assert float(geodesic.field_distance(field, (0.0, 0.0), 0.2, jnp.array([0.5, 0.2]))) == pytest.approx(6.5)
    np.testing.assert_allclose(
        geodesic.path_direction(field, (0.0, 0.0), 0.2, jnp.array([0.3, 0.3])), [-1, -4] / np.hypot(1, 4), rtol=1e-5
    )


@pytest.mark.parametrize(
    "changes, message",
    [
        ({"reward__progress": "geodesic"}, "terrain.reachability.enabled"),
        ({"reward__progress": "path"}, "reward.progress"),
        (
            {
                "reward__progress": "geodesic",
                "scene": "terrain",
                "terrain__reachability__enabled": True,
                "terrain__reachability__goal_sites": 4,
            },
            "goal.mode 'radial' or 'spiral'",
        ),
        (
            {"scene": "terrain", "terrain__types": ["corridor"], "terrain__corridor__bend_amplitude": 0.3},
            "bend_amplitude",
        ),
    ],
)
def test_geodesic_settings_that_cannot_work_are_refused(changes, message):
    with pytest.raises(ValueError, match=message):
        hsa_mjx.build_config("flat", **changes)


def test_spiral_progress_runs_along_the_track():
    """The spiral's sites are its checkpoints: from checkpoint k - 1 the way to k follows the track, no
    shorter than the straight line and longer where the track curls (the straight line crosses a wall)."""
    config = hsa_mjx.build_config("spiral", reward__progress="geodesic", terrain__reachability__enabled=True)
    grid = hsa_mjx.terrain.Grid()
    data = TerrainSampler(config.terrain, grid).type_data(0, jax.random.PRNGKey(0))
    limits = dataclasses.replace(tv.ROBOT, resolution=config.terrain.reachability.resolution)
    points = goals.spiral_checkpoints(config.goal, config.terrain.spiral)
    spawn = reachability.spawn_field(data, grid, limits)
    spec = geodesic.SiteSpec(grid, limits, (1.5, 4.5), len(points), 2)
    sites = geodesic.build(spec, np.asarray(data)[None], np.asarray(spawn)[None], jax.random.PRNGKey(0), points)
    along = np.array(
        [
            float(
                geodesic.field_distance(
                    jnp.asarray(sites.fields[0, k]), sites.origin, sites.spacing, jnp.asarray(points[k - 1])
                )
            )
            for k in range(1, len(points))
        ]
    )
    straight = np.linalg.norm(points[1:] - points[:-1], axis=1)
    assert (along >= straight - 0.15).all() and (along > 1.05 * straight).any()
