"""Goals on reachable ground: tiles without enough of it are re-drawn or refused when the atlas is built,
and radial goals are drawn only on cells the robot reaches, at their path distance from the spawn."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import hsa_mjx
from hsa_mjx.terrain import reachability
from hsa_mjx.terrain import traversability as tv
from hsa_mjx.terrain.atlas import AtlasLayout, TerrainPool
from hsa_mjx.terrain.grid import Grid, to_hfield_data
from hsa_mjx.terrain.params import TERRAIN_TYPES, ReachabilityConfig, TerrainConfig

GRID = Grid(nrow=50, ncol=50)
REACH = ReachabilityConfig(enabled=True, goal_range=(1.5, 4.5))


def _ring_wall(radius: float = 1.0) -> np.ndarray:
    """A 0.5 m wall all round the spawn: nothing beyond ``radius`` can be reached."""
    xs = np.linspace(-GRID.half_x, GRID.half_x, GRID.ncol)
    r = np.hypot(*np.meshgrid(xs, xs))
    return np.asarray(to_hfield_data(jnp.asarray(np.where(np.abs(r - radius) < 0.2, 0.5, 0.0)), GRID))


def _pool(terrain_type: str, tiles: np.ndarray, **changes) -> TerrainPool:
    config = dataclasses.replace(
        TerrainConfig(), types=(terrain_type,), tiles_per_type=len(tiles), reachability=REACH, **changes
    )
    layout = AtlasLayout.from_config(config, GRID)
    return TerrainPool(config, layout, tiles, np.full(len(tiles), TERRAIN_TYPES.index(terrain_type)))


def test_a_random_tile_walled_off_from_its_goals_is_redrawn_and_a_fixed_one_refused():
    walled = np.stack([_ring_wall(), _ring_wall()])
    limits = dataclasses.replace(tv.ROBOT, resolution=REACH.resolution)
    assert reachability.goal_area(reachability.spawn_fields(walled, GRID, limits), REACH.goal_range, 0.1).max() == 0
    pool = _pool("poles", walled.copy())
    assert not np.allclose(pool.tiles, walled)  # both re-drawn from the generator
    assert (reachability.goal_area(pool.reach, REACH.goal_range, REACH.resolution) >= REACH.min_area).all()
    with pytest.raises(ValueError, match=r"reachability.min_area.*\['flat level 0'\]"):
        _pool("flat", walled[:1].copy())


def test_goals_are_drawn_only_on_reachable_ground_at_their_path_distance():
    env = hsa_mjx.make_env(
        "flat",
        scene="terrain",
        terrain__types=["poles"],
        terrain__tiles_per_type=4,
        terrain__poles__num=150,  # twice the default's poles: many goals of the ring are closed off
        terrain__reachability__enabled=True,
        goal__mode="radial",
        goal__radial_range=[1.5, 4.5],
    )
    pool, res = env.world.pool, env.config.terrain.reachability.resolution
    assert pool.reach.shape == (4, 101, 101)
    ring = reachability.cell_centres(GRID, res)
    euclid = np.hypot(ring[..., 0], ring[..., 1])
    closed = ((euclid >= 1.5) & (euclid <= 4.5) & np.isinf(pool.reach)).mean(axis=(1, 2))
    assert closed.min() > 0.05  # each tile has unreachable cells at goal distances to avoid
    states = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(0), 128))
    goal, tile = np.asarray(states.pipeline_state.task.goal_xy), np.asarray(states.pipeline_state.task.tile)
    cell = np.asarray(tv.cell_of(jnp.asarray(goal), GRID, res))
    path = pool.reach[tile, cell[:, 0], cell[:, 1]]
    assert np.isfinite(path).all() and (path >= 1.5).all() and (path <= 4.5).all()
    assert len(set(tile.tolist())) == 4 and np.hypot(*goal.T).min() < 4.5  # every tile, goals spread


@pytest.mark.parametrize(
    "change, message",
    [
        ({"goal_range": (3.0, 2.0)}, "reachability.goal_range"),
        ({"resolution": 0.0}, "reachability.resolution"),
        ({"min_area": -1.0}, "reachability.min_area"),
    ],
)
def test_bad_reachability_settings_are_refused(change, message):
    with pytest.raises(ValueError, match=message):
        hsa_mjx.build_config("flat", **{f"terrain__reachability__{k}": v for k, v in change.items()})


def test_the_measured_limits_put_the_map_on_the_measured_side_of_a_step():
    """``benchmarks.terrain.capability``: the robots got past a 5 cm step and not past a 7.5 cm one; the map with
    ``traversability.ROBOT`` says the same; the limit is the hardest value passed."""
    from benchmarks.terrain import capability

    step = capability.PROBES["step"]
    assert capability.predicted_pass(step, 0.05) and not capability.predicted_pass(step, 0.075)
    rows = [{"height": h, "mean_progress_m": m} for h, m in ((0.0, 1.8), (0.05, 1.8), (0.075, 1.3), (0.1, 1.6))]
    assert capability.limit(step, rows) == 0.1 and capability.limit(step, rows[2:3]) is None
    gap = capability.PROBES["gap"]  # narrower is harder
    widths = [{"corridor_width": w, "mean_progress_m": m} for w, m in ((0.82, 0.6), (0.62, 1.5), (0.52, 0.2))]
    assert capability.limit(gap, widths) == 0.62


def test_the_ladder_audit_reads_each_level_on_the_robots_map():
    """``benchmarks.terrain.ladders``: level 0 is open ground, the dispatcher's corridor at full wall height closes
    (its 0.2 m floor is narrower than the blocks), and the parameter is given in physical units."""
    from benchmarks.terrain import ladders

    config = dataclasses.replace(
        TerrainConfig(), types=("corridor", "stairs"), proportions=(0.5, 0.5), levels=2, tiles_per_type=1
    )
    rows = {(r["type"], r["level"]): r for r in ladders.ladder_rows(config, (1.5, 4.5))}
    assert rows[("corridor", 0)]["reachable_share"] == 1.0 and rows[("corridor", 1)]["reachable_share"] == 0.0
    assert rows[("stairs", 1)]["parameter"] == "step_height 0.04 m" and rows[("stairs", 1)]["reachable_share"] == 1.0
    assert rows[("corridor", 1)]["median_detour"] is None and 1.0 <= rows[("stairs", 0)]["median_detour"] < 1.1


def test_the_ladder_audit_counts_time_at_the_measured_speed(tmp_path):
    """``benchmarks.terrain.ladders --speeds``: a level is in time when its farthest goals, along the ground, take
    no longer than an episode at the speed measured there (interpolated between evaluated difficulties)."""
    import json

    from benchmarks.terrain import ladders

    cells = [("poles", 0.0, 0.2), ("poles", 0.5, 0.1), ("poles", 1.0, None), ("flat", 0.0, 0.2)]
    path = tmp_path / "terrain_eval.json"
    path.write_text(json.dumps({"rows": [{"type": t, "difficulty": d, "success_speed_m_s": v} for t, d, v in cells]}))
    speeds = ladders.read_speeds(path)
    assert ladders.speed_at(speeds["poles"], 0.25) == pytest.approx(0.15)
    assert ladders.speed_at(speeds["poles"], 1.0) is None  # no goal reached there: not measured
    rows = [
        {"type": "poles", "difficulty": 0.25, "median_detour": 1.2},  # 4.5 m x 1.2 / 0.15 m/s = 36 s
        {"type": "poles", "difficulty": 0.5, "median_detour": 2.0},  # 90 s: longer than the episode
        {"type": "poles", "difficulty": 1.0, "median_detour": 1.1},
        {"type": "flat", "difficulty": 0.0, "median_detour": None},  # no reachable goal: no time
    ]
    timed = ladders.add_time(rows, speeds, goal_max=4.5, episode_s=80.0)
    assert [r["in_time"] for r in timed] == [True, False, None, None]
    assert timed[0]["far_goal_s"] == pytest.approx(36.0)
    path.write_text(json.dumps({"rows": [{"type": "flat", "difficulty": 0.0}]}))  # an older evaluation
    with pytest.raises(ValueError, match="success_speed_m_s"):
        ladders.read_speeds(path)
