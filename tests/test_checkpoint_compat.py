"""Files of earlier versions still work: a checkpoint (tests/data/run_format_1) evaluates as it did
then and resumes with both curricula where they stopped; the shipped policies evaluate as the cited
results recorded."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

DATA = Path(__file__).resolve().parent / "data"
COMPARED = (
    "step",
    "goal_range",
    "episodes",
    "success_rate",
    "mean_final_distance",
    "mean_speed_m_per_s",
    "mean_start_distance",
    "mean_progress_m",
    "mean_episode_steps",
    "not_finished",
)


@pytest.fixture(scope="module")
def old_run(tmp_path_factory) -> Path:
    """A writable copy of the saved run."""
    run = tmp_path_factory.mktemp("compat") / "run"
    shutil.copytree(DATA / "run_format_1", run)
    return run


def _terrain_levels(run: Path, step: int) -> dict:
    """The terrain levels a checkpoint holds, (envs,) arrays."""
    from train.run import checkpoint

    path = checkpoint.checkpoint_dir(run) / f"step_{step:012d}"
    envs = checkpoint.read_meta(path)["terrain_envs"]
    template = {"terrain_levels": {k: np.zeros((envs,), np.int32) for k in ("row", "level")}}
    return checkpoint.load(path, template)["terrain_levels"]


def test_old_checkpoint_evaluates_the_same(old_run):
    from train.evaluate import main as evaluate

    assert evaluate([str(old_run), "--episodes", "2", "--steps", "12", "--backend", "c"]) == 0
    now = json.loads((old_run / "eval" / "eval.json").read_text())
    then = json.loads((DATA / "expected_eval_run_format_1.json").read_text())
    for key in COMPARED:
        assert now[key] == pytest.approx(then[key], rel=1e-5, abs=1e-6), key


def test_old_checkpoint_resumes_both_curricula(old_run):
    from train import config as train_config
    from train.run.logger import read_jsonl
    from train.trainer import train

    saved = read_jsonl(old_run / "metrics.jsonl")[-1]
    assert saved["step"] == 80 and saved["curriculum/episode_count"] > 0
    config = train_config.load(old_run / "config.yaml", ["run.num_timesteps=120"])
    assert train(config, old_run, resume=True, quiet=True)["env_steps"] == 120
    resumed = read_jsonl(old_run / "metrics.jsonl")[-1]
    # 40 env steps are 10 per env after the resume's fresh episodes of 15 steps: none ends, so both
    # curricula must hold exactly what the checkpoint saved (a fresh start would show 0 episodes)
    assert resumed["step"] == 120
    for key in ("curriculum/episode_count", "curriculum/max_distance", "curriculum/success_rate"):
        assert resumed[key] == pytest.approx(saved[key]), key
    before, after = _terrain_levels(old_run, 80), _terrain_levels(old_run, 120)
    for key in ("row", "level"):
        np.testing.assert_array_equal(after[key], before[key])
    assert resumed["terrain/mean_level"] == pytest.approx(float(np.mean(before["level"])))


# The shipped policies' default CPU evaluations as the results the docs cite recorded them.
RECORDED = {
    "flat": "benchmarks/results/training/flat_warp/eval_policy_cpu.json",
    "corridor": "benchmarks/results/training/corridor_scan/eval_policy_cpu.json",
}
# relative tolerance of progress and episode length: the corridor gait rubs the walls, which turns the
# suite's float rounding into more drift over 1,000 steps (measured: 0.545 vs 0.619 m of progress)
TOLERANCE = {"flat": 0.05, "corridor": 0.2}


@pytest.mark.parametrize("name", sorted(RECORDED))
def test_shipped_policy_evaluates_as_recorded(name, tmp_path):
    """``python -m train.evaluate --policy NAME`` (C MuJoCo on this CPU) reproduces the cited result."""
    from train.evaluate import main as evaluate

    assert evaluate(["--policy", name, "--out", str(tmp_path)]) == 0
    now = json.loads((tmp_path / "eval.json").read_text())
    then = json.loads((DATA.parent.parent / RECORDED[name]).read_text())
    assert [now[k] for k in ("episodes", "max_steps", "physics", "goal_range")] == [
        then[k] for k in ("episodes", "max_steps", "physics", "goal_range")
    ]
    assert now["mean_start_distance"] == pytest.approx(then["mean_start_distance"], rel=1e-5)  # the same goals
    # the suite's XLA flags (no LLVM optimisation) round the policy's float32 differently, and over
    # 500-1,000 steps the gait drifts a little (measured: progress 0.996 vs 0.987 m, 481 vs 484 steps);
    # a policy loaded wrong does not walk at all
    assert abs(now["success_rate"] - then["success_rate"]) <= 0.25  # at most one episode of four
    for key in ("mean_progress_m", "mean_episode_steps"):
        assert now[key] == pytest.approx(then[key], rel=TOLERANCE[name]), (key, now[key], then[key])


def test_the_evaluation_api_takes_a_spec_and_the_command_is_its_wrapper(tmp_path):
    """``evaluate(EvalSpec(...))`` gives the command's ``eval.json``; a bad spec is a ValueError before any compile."""
    from train.episodes.play import EvalSpec, evaluate
    from train.evaluate import main as command
    from train.evaluate import parse_args, spec_from_args

    spec = EvalSpec(policy="flat", episodes=2, steps=20, goal_range=(1.5, 1.6), out=str(tmp_path / "api"))
    result = evaluate(spec)
    assert command(["--policy", "flat", "--episodes", "2", "--steps", "20", "--goal-range", "1.5", "1.6",
                    "--out", str(tmp_path / "cli")]) == 0  # fmt: skip
    written = json.loads((tmp_path / "cli" / "eval.json").read_text())
    assert json.loads((tmp_path / "api" / "eval.json").read_text())["episodes"] == result["episodes"] == 2
    for key in ("success_rate", "mean_progress_m", "mean_start_distance", "goal_range", "max_steps"):
        assert written[key] == result[key], key
    with pytest.raises(ValueError, match="give either a RUN_DIR or --policy"):
        evaluate(EvalSpec())
    with pytest.raises(FileNotFoundError):
        evaluate(EvalSpec(policy=str(tmp_path / "nothing_here")))
    # the spec is typed: the command turns its flags into a mapping and tuples; CLI strings are refused
    flags = ["--policy", "flat", "--set", "env.goal.radial_range=[4.0,4.5]", "--levels", "0,1"]
    flags += ["--terrain-types", "a, b"]
    typed = spec_from_args(parse_args(flags))
    assert typed.overrides == {"env.goal.radial_range": [4.0, 4.5]} and typed.override_items() == (
        "env.goal.radial_range=[4.0, 4.5]",
    )
    assert (typed.levels, typed.terrain_types) == ((0.0, 1.0), ("a", "b"))
    bad_specs = (({"overrides": "env.seed=1"}, "overrides must map"), ({"levels": "0,1"}, "levels must be"))
    bad_specs += (({"video_cell": ("stairs", 1.0)}, "add --video and --terrain-types"),)
    bad_specs += (({"stuck_window_s": 0.0}, "--stuck-window-s"),)
    for bad, match in bad_specs:
        with pytest.raises(ValueError, match=match):
            evaluate(EvalSpec(policy="flat", **bad))
