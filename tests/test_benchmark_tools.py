"""Pure helpers of the benchmark scripts (no MJX)."""

from benchmarks import curriculum_compare as cc


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
