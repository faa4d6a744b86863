"""benchmarks.scaling.time_to_target: the first log meeting the target, resumed calls' clocks added up, bad
folders refused."""

import json

import pytest
import yaml

import benchmarks.scaling.time_to_target

CONFIG = {
    "env": {"physics": {"backend": "warp"}},
    "run": {"num_envs": 64, "num_devices": 2},
    "ppo": {"batch_size": 8, "num_minibatches": 4, "unroll_length": 20},
    "goal_curriculum": {"enabled": True, "target_range": [1.5, 4.5]},
}


def _run(tmp_path, rows, config=CONFIG):
    """A run folder holding ``config`` and the log ``rows``."""
    (tmp_path / "config.yaml").write_text(yaml.safe_dump(config))
    (tmp_path / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    return tmp_path


def _row(step, wall, goal, success, launch=None):
    row = {"step": step, "training/walltime": wall, "curriculum/max_distance": goal, "episode/success_rate": success}
    return row if launch is None else {**row, "training/since_launch": launch}


def test_the_first_log_at_full_range_and_success_counts_across_a_resume(tmp_path):
    rows = [
        _row(640, 10.0, 1.8, 0.95, launch=14.0),  # 4 s of start-up before the loop
        _row(1280, 20.0, 4.5, 0.85, launch=24.0),  # range not full, then success too low
        _row(1920, 5.0, 4.5, 0.92, launch=8.0),  # a resumed call: its clocks restart
        _row(2560, 9.0, 4.5, 0.97, launch=12.0),
    ]
    result = benchmarks.scaling.time_to_target.time_to_target(
        *benchmarks.scaling.time_to_target.read_run(_run(tmp_path, rows)), success=0.9
    )
    assert result["iteration_env_steps"] == 640
    assert result["first_log_s"] == 10.0
    assert result["reached"]["wall_s"] == 25.0 and result["reached"]["env_steps"] == 1920
    assert result["reached"]["since_launch_s"] == 32.0 and result["last"]["since_launch_s"] == 36.0
    assert result["reached"]["ppo_iterations"] == 3
    assert result["last"]["wall_s"] == 29.0 and result["last"]["success_rate"] == 0.97
    assert "| 10.0 | 25.0 | 32.0 | 1,920 | 3 |" in benchmarks.scaling.time_to_target.markdown({"run": result})


def test_a_target_never_met_is_none_with_the_last_log(tmp_path):
    rows = [_row(640, 10.0, 1.8, 0.95), _row(1280, 20.0, 2.1, 0.99)]
    result = benchmarks.scaling.time_to_target.time_to_target(
        *benchmarks.scaling.time_to_target.read_run(_run(tmp_path, rows)), success=0.9
    )
    assert result["reached"] is None and result["last"]["goal_max_m"] == 2.1
    assert result["last"]["since_launch_s"] is None  # logged before the key existed
    assert "not reached" in benchmarks.scaling.time_to_target.markdown({"run": result})
    assert result["physics_backend"] == "warp"
    (tmp_path / "summary.json").write_text(json.dumps({"physics_backend": "jax"}))  # what "auto" resolved to
    assert (
        benchmarks.scaling.time_to_target.time_to_target(
            *benchmarks.scaling.time_to_target.read_run(tmp_path), success=0.9
        )["physics_backend"]
        == "jax"
    )
    no_curriculum = {**CONFIG, "goal_curriculum": {"enabled": False}}  # then the success alone counts
    result = benchmarks.scaling.time_to_target.time_to_target(
        *benchmarks.scaling.time_to_target.read_run(_run(tmp_path, rows, no_curriculum)), success=0.9
    )
    assert result["reached"]["env_steps"] == 640


def test_a_step_count_target_reads_the_first_log_at_it_whatever_the_logged_success(tmp_path):
    rows = [_row(640, 10.0, 1.8, 0.0, launch=14.0), _row(1280, 20.0, 2.1, 0.2, launch=24.0), _row(1920, 30.0, 2.4, 0.3)]
    result = benchmarks.scaling.time_to_target.time_to_target(
        *benchmarks.scaling.time_to_target.read_run(_run(tmp_path, rows)), success=0.9, at_env_steps=1000
    )
    assert result["target"] == {"env_steps": 1000}
    assert result["reached"]["env_steps"] == 1280 and result["reached"]["since_launch_s"] == 24.0
    startup = {"first_update_since_launch_s": 21.5, "cold_caches": True}
    (tmp_path / "summary.json").write_text(json.dumps({"startup": startup}))
    out = tmp_path / "out"
    args = [str(tmp_path), "--at-env-steps", "5000", "--out-dir", str(out)]
    assert benchmarks.scaling.time_to_target.main(args) == 0  # never reached: reported
    assert json.loads((out / "time_to_target_runs.json").read_text())[tmp_path.name]["startup"] == startup
    assert f"| {tmp_path.name} | 64 | 2 | 21.5 | yes |" in (out / "time_to_target_runs.md").read_text()
    with pytest.raises(SystemExit):
        benchmarks.scaling.time_to_target.main([str(tmp_path), "--at-env-steps", "0"])


def test_bad_folders_are_refused(tmp_path, capsys):
    with pytest.raises(FileNotFoundError, match="metrics.jsonl"):
        benchmarks.scaling.time_to_target.read_run(tmp_path)
    assert (
        benchmarks.scaling.time_to_target.main([str(tmp_path)]) == 2
        and "not a training run folder" in capsys.readouterr().out
    )
    with pytest.raises(ValueError, match="no log rows"):
        benchmarks.scaling.time_to_target.read_run(_run(tmp_path, []))


def test_the_evaluated_target_is_the_first_evaluated_checkpoint_at_the_success_with_its_clocks(tmp_path):
    """Read from the run's evaluated checkpoints (the sweep's every_checkpoint), not the logged success; a TD3
    run's iteration is one step of every env."""
    td3 = {**CONFIG, "run": {**CONFIG["run"], "learner": "td3"}}
    run = _run(tmp_path, [_row(640, 10.0, 4.5, 0.99), _row(1280, 20.0, 4.5, 0.99)], td3)
    for step, clock, rate in ((640, 10.0, 0.6), (1280, 20.0, 0.93)):
        folder = run / "sweep_checkpoints" / f"step_{step:012d}"
        folder.mkdir(parents=True)
        (folder / "eval.json").write_text(json.dumps({"episodes": 100, "success_rate": rate}))
        (folder / "clock.json").write_text(json.dumps({"step": step, "training_walltime_s": clock}))
    startup = {"first_update_since_launch_s": 30.0, "first_update_s": 12.0, "cold_caches": True}
    (run / "summary.json").write_text(json.dumps({"startup": startup}))
    out = tmp_path / "out"
    assert benchmarks.scaling.time_to_target.main([str(run), "--out-dir", str(out)]) == 0
    row = json.loads((out / "time_to_target_runs.json").read_text())[run.name]
    assert row["learner"] == "td3" and row["iteration_env_steps"] == 64 and row["reached"]["env_steps"] == 640
    assert row["evaluated"]["checkpoints_evaluated"] == 2
    assert row["evaluated"]["reached"] == {
        "training_s": 20.0,
        "env_steps": 1280,
        "success_rate": 0.93,
        "since_launch_s": 38.0,
    }
    assert "| 20, 38.0, 1,280 |" in (out / "time_to_target_runs.md").read_text()


def test_runs_of_the_same_folder_name_keep_a_row_each():
    names = benchmarks.scaling.time_to_target.run_names(["out/runs/ppo/seed0", "out/runs/td3/seed0", "x/seed1"])
    assert names == ["ppo/seed0", "td3/seed0", "x/seed1"]
    assert benchmarks.scaling.time_to_target.run_names(["a/run"]) == ["run"]
    with pytest.raises(ValueError, match="twice"):
        benchmarks.scaling.time_to_target.run_names(["a/run", "a/run"])
