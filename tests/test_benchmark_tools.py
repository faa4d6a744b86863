"""Pure helpers of the benchmark scripts (no MJX)."""

import pytest

from benchmarks import curriculum_compare as cc
from benchmarks import track_floor
from hsa_mjx import config as cfg
from hsa_mjx.terrain.grid import Grid


def _record(step: int, max_distance: float, sps: float, episodes: float) -> dict:
    return {"step": step, "env_steps": 1000.0, "training/env_steps_per_s": sps,
            "curriculum/max_distance": max_distance, "curriculum/episode_count": episodes}


def test_training_seconds_add_each_log_over_its_own_rate():
    records = [_record(1000, 1.8, 100.0, 0), _record(2000, 1.8, 0.0, 5), _record(3000, 1.95, 500.0, 9)]
    assert cc.training_seconds(records) == [10.0, 10.0, 12.0]  # a log without a rate adds nothing


def test_widenings_report_step_episodes_seconds_and_new_maximum():
    records = [_record(1000, 1.8, 100.0, 0), _record(2000, 1.8, 100.0, 5), _record(3000, 1.95, 250.0, 9)]
    assert cc.widenings(records) == [(1000, 0, 10.0, 1.8), (3000, 9, 24.0, 1.95)]


def test_corridor_gaits_table_has_one_row_per_layout_and_one_cell_per_gait():
    from benchmarks.corridor_gaits import GAITS, markdown
    rows = [{"layout": layout, "gait": gait, "dx_m": 0.1 * i, "dy_m": -0.01}
            for layout in ("corridor_preset", "plane") for i, gait in enumerate(GAITS)]
    lines = markdown(rows).splitlines()
    assert len(lines) == 4 and lines[2].startswith("| corridor_preset |") and lines[3].count("|") == len(GAITS) + 2
    assert "+0.300, -0.010" in lines[3]


def _layout():
    import numpy as np
    from benchmarks.gaits import GaitLayout
    # slots 0-3 "A" cylinders (two on each block), 4-7 "C" cylinders
    return GaitLayout(on_block_a=np.array([1, 0, 1, 0, 0, 1, 0, 1], np.float32), unit=np.array([1, 2, 3, 4] * 2),
                      contracting=np.array([1, 1, 1, 1, 0, 0, 0, 0], np.float32))


def test_gait_sweep_actions_reproduce_a_reachable_target_wave_and_saturate_otherwise():
    import numpy as np
    from benchmarks.gait_sweep import gait_actions, gait_targets
    times = np.arange(201) * 0.02
    slow = gait_targets("sine", 1.5, 4.0, "A", "opposite", _layout(), times)
    assert np.all(slow[0] == 0) and np.abs(slow).max() > 1.0
    np.testing.assert_allclose(slow[:, 5], -slow[:, 0], atol=1e-12)  # same block and phase, C turns against A
    actions = gait_actions(slow, 0.1785, 6.28)
    assert actions.shape == (200, 8) and np.abs(actions).max() <= 1.0
    np.testing.assert_allclose(np.cumsum(0.1785 * actions, axis=0), slow[1:], atol=1e-5)  # followed exactly
    square = gait_actions(gait_targets("square", 6.28, 4.0, "B", "same", _layout(), times), 0.1785, 6.28)
    assert set(np.unique(np.round(square[:30], 6))) <= {-1.0, 1.0}  # full speed towards +-6.28
    lead_b = gait_targets("sine", 2.0, 4.0, "B", "same", _layout(), times)
    assert lead_b[25, 0] < lead_b[25, 1]  # block A's servo (slot 0) lags block B's (slot 1) by a quarter period


def test_track_progress_splits_calls_where_the_batch_restarts():
    from benchmarks.track_progress import calls, table
    distances = [1.75, 1.70, 1.60, 1.749, 1.5, 1.3]
    records = [{"step": 1000 * (i + 1), "step/distance_to_goal": d, "step/reward": 0.01 * i} for i, d in enumerate(distances)]
    assert [len(c) for c in calls(records)] == [3, 3]
    lines = table([("run", records)]).splitlines()
    assert lines[2] == "| run | 1 | 1,000 -> 3,000 | 1.750 -> 1.600 | 0.000 -> 0.000 | +0.000 -> +0.020 |"
    assert lines[3].startswith("| run | 2 | 4,000 -> 6,000 | 1.749 -> 1.300 |")


def test_track_progress_does_not_split_where_checkpoints_are_collected():
    from benchmarks.track_progress import calls
    # a collected checkpoint moves the goal on: the distance rises with the checkpoint index (one call);
    # a restart drops the index back (a new call)
    rows = [(0.60, 0.0), (0.50, 0.1), (0.55, 0.4), (0.65, 0.9), (0.80, 0.0), (0.70, 0.0)]
    records = [{"step": i, "step/distance_to_goal": d, "step/checkpoint_index": c, "step/reward": 0.0}
               for i, (d, c) in enumerate(rows)]
    assert [len(c) for c in calls(records)] == [4, 2]
    # a restart can also bring the distance down (the start is nearer its checkpoint than where the
    # batch stood): the falling index alone marks it; a few failed episodes' small fall does not
    rows = [(0.70, 0.80), (0.66, 0.86), (0.63, 0.0), (0.57, 0.0), (0.56, 0.10), (0.55, 0.09)]
    records = [{"step": i, "step/distance_to_goal": d, "step/checkpoint_index": c, "step/reward": 0.0}
               for i, (d, c) in enumerate(rows)]
    assert [len(c) for c in calls(records)] == [2, 4]


def test_turn_gaits_sides_come_from_the_model_and_each_side_plays_its_own_lead():
    import numpy as np
    from benchmarks import fidelity, gaits
    from benchmarks.turn_gaits import SIDES, left_side, mixed_targets, variants
    model = fidelity.load_mj_model(fidelity.fidelity_config())
    left, layout = left_side(model), gaits.gait_layout(model)
    assert left.sum() == 4  # units 1 and 4 sit at +y (left of block_a -> block_b), units 2 and 3 at -y
    np.testing.assert_array_equal(left, np.isin(layout.unit, [1, 4]).astype(np.float32))
    times, base = np.arange(101) * 0.02, ("sine", 2.0, 4.0, "same")
    one_side = mixed_targets(base, "A", "-", left, layout, times)
    assert np.all(one_side[:, left == 0] == 0) and np.abs(one_side[:, left > 0]).max() > 1.0
    crossed = mixed_targets(base, "A", "B", left, layout, times)
    straight_a, straight_b = (mixed_targets(base, lead, lead, left, layout, times) for lead in "AB")
    np.testing.assert_array_equal(crossed[:, left > 0], straight_a[:, left > 0])
    np.testing.assert_array_equal(crossed[:, left == 0], straight_b[:, left == 0])
    table = variants(layout, left, 50, 0.02, 0.1785, 6.28)
    assert len(table) == 1 + 2 * len(SIDES) and len(set(SIDES)) == len(SIDES)
    assert all(a.shape == (50, 8) and np.abs(a).max() <= 1.0 for a in table.values())


def test_track_floor_widths_approach_the_track_width_on_a_fine_grid_and_show_the_coarse_grid_gap():
    fine = Grid(nrow=251, ncol=251)  # 0.04 m spacing
    rows = {(r["rule"], r["track_width"]): r for r in track_floor.compare([0.8, 1.2], grid=fine)}
    for key in [("original", 0.8), ("ours", 0.8), ("ours", 1.2)]:
        assert key[1] - 2.5 * fine.spacing_x <= rows[key]["median"] <= key[1], rows[key]
    assert rows[("ours", 1.2)]["median"] - rows[("ours", 0.8)]["median"] == pytest.approx(0.4, abs=fine.spacing_x)
    # on the scene's 0.2 m grid a half-height edge at 0.4 m leaves a narrower floor than the original's rule
    preset_width = cfg.get_preset("spiral").terrain.spiral.track_width
    coarse = {(r["rule"], r["track_width"]): r for r in track_floor.compare([0.8, preset_width])}
    original = coarse[("original", 0.8)]["median"]
    assert coarse[("ours", 0.8)]["median"] < original - 0.5 * track_floor.scene_grid().spacing_x
    # which is why the spiral preset widens its track: the floor the original had
    assert coarse[("ours", preset_width)]["median"] == pytest.approx(original, abs=0.05)
