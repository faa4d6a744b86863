"""Traversability on hand-made tiles: a wall, a gap narrower than the robot, slopes, and path distances."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from benchmarks.terrain.fields import neighbours_at_once
from hsa_mjx.terrain import traversability as tv
from hsa_mjx.terrain.grid import Grid, to_hfield_data

RES = 0.05
ROBOT = tv.Limits(max_step=0.05, max_slope=0.3, half_width=0.14, resolution=RES)
N = 101  # a 5 m square at 5 cm


def _wall(rows: slice, col: int, height: float = 0.25) -> np.ndarray:
    h = np.zeros((N, N), np.float32)
    h[rows, col] = height
    return h


def test_a_wall_blocks_its_cells_and_the_robots_half_width_around_it():
    free = np.asarray(tv.free_cells(jnp.asarray(_wall(slice(0, 80), 50)), ROBOT))
    clearance = int(ROBOT.half_width / RES)  # 2 whole cells: the robot's centre stays 0.14 m off
    assert not free[:80, 50 - 1 - clearance : 50 + 2 + clearance].any()
    assert free[:80, : 50 - 2 - clearance].all() and free[:80, 50 + 3 + clearance :].all()
    assert free[90:].all()  # past the wall's end


@pytest.mark.parametrize("gap_m, passes", [(0.20, False), (0.60, True)])
def test_a_gap_narrower_than_the_robot_closes(gap_m, passes):
    h = _wall(slice(None), 50)
    gap = int(round(gap_m / RES))
    h[40 : 40 + gap, 50] = 0.0
    free = tv.free_cells(jnp.asarray(h), ROBOT)
    distances = np.asarray(tv.path_distances(free, (45, 90), RES))
    assert np.isfinite(distances[45, 10]) == passes


def test_a_slope_above_the_limit_is_blocked_and_one_below_is_not():
    ramp = np.broadcast_to(np.arange(N, dtype=np.float32) * RES, (N, N))
    steep = tv.blocked(jnp.asarray(0.5 * ramp), ROBOT)  # rise 0.5 per metre, 2.5 cm a cell
    gentle = tv.blocked(jnp.asarray(0.2 * ramp), ROBOT)
    assert np.asarray(steep).all() and not np.asarray(gentle).any()


def test_the_path_distance_around_a_wall_is_the_shortest_path():
    limits = tv.Limits(max_step=0.05, max_slope=10.0, half_width=0.01, resolution=RES)  # no growth
    free = tv.free_cells(jnp.asarray(_wall(slice(0, 80), 50)), limits)  # cols 49-51 blocked to row 79, (80, 50)
    distances = np.asarray(jax.jit(tv.path_distances, static_argnums=2)(free, (10, 60), RES))
    octile = 9 * np.sqrt(2) + 61  # (10, 40) -> (80, 49): 70 rows, 9 columns
    known = (2 * octile + 2 * np.sqrt(2)) * RES  # down one side, under the wall's end, up the other
    assert abs(distances[10, 40] - known) <= RES
    assert distances[10, 60] == 0 and distances[10, 70] == pytest.approx(10 * RES)  # straight: no detour
    closed = tv.free_cells(jnp.asarray(_wall(slice(None), 50)), limits)
    assert np.isinf(np.asarray(tv.path_distances(closed, (10, 60), RES))[10, 40])  # behind a closed wall


def test_the_map_samples_a_tiles_surface_and_finds_its_cells():
    grid = Grid(nrow=50, ncol=50)
    heights = jnp.zeros((50, 50)).at[:, 25:].set(0.3)  # a 0.3 m step across the tile
    surface = np.asarray(tv.surface_map(to_hfield_data(heights, grid), grid, 0.1))
    assert surface.shape == (101, 101) and surface.min() == 0 and surface.max() == pytest.approx(0.3)
    assert tuple(np.asarray(tv.cell_of(jnp.array([0.0, -5.0]), grid, 0.1))) == (0, 50)
    with pytest.raises(ValueError, match="max_step' must be > 0"):
        tv.Limits(max_step=0.0, max_slope=0.3, half_width=0.14)


def test_the_sweeps_reach_the_plain_relaxations_fixed_point_bit_for_bit():
    """``relax``'s sweeps against every cell relaxed from its 8 neighbours at once, to convergence, on a
    maze of random blocked cells (the distance field) and on continuing it into the blocked cells."""
    free = jnp.asarray(np.random.default_rng(0).random((41, 41)) > 0.3).at[20, 20].set(True)
    start = jnp.where(free, jnp.full(free.shape, jnp.inf).at[20, 20].set(0.0), jnp.inf)
    field = tv.path_distances(free, (20, 20), RES)
    np.testing.assert_array_equal(np.asarray(field), np.asarray(neighbours_at_once(start, free, RES)))
    assert np.isfinite(field).sum() > 0.5 * free.sum()  # the maze leaves most free cells connected
    holes = ~jnp.isfinite(field)
    continued = np.asarray(tv.relax(field, holes, RES))
    np.testing.assert_array_equal(continued, np.asarray(neighbours_at_once(field, holes, RES)))
    assert np.isfinite(continued).all()
