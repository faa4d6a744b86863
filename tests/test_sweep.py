"""The sweep tool: a sweep file is checked before anything runs, every (arm, seed) becomes one training and one
evaluation command, and the report pools each arm's seeds with intervals (on made-up run folders: no training)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml

from benchmarks.sweeps import report as sweep_report
from benchmarks.sweeps import run as sweep
from train import config as train_config

SWEEP = {
    "name": "demo",
    "question": "does b beat a?",
    "config": "configs/train_flat.yaml",
    "env_steps": 1_310_720,
    "seeds": [0, 1],
    "arms": {"a": [], "b": ["ppo.value_targets=per_iteration"]},
    "evaluate": {"episodes": 100, "goal_range": [1.5, 4.5]},
}


@pytest.mark.parametrize("path", sorted(Path("benchmarks/sweeps").glob("*.yaml")), ids=lambda p: p.stem)
def test_every_shipped_sweep_file_loads(path):
    """Each sweep file in the repository passes the checks its run makes first (keys, arms' configs)."""
    loaded = sweep.load(path)
    assert loaded.arms and loaded.env_steps > 0 and loaded.name == path.stem


def _write(tmp_path: Path, **changes) -> Path:
    path = tmp_path / "sweep.yaml"
    path.write_text(yaml.safe_dump({**SWEEP, **changes}))
    return path


@pytest.mark.parametrize(
    "changes, match",
    [
        ({"arm": {}}, "unknown key"),
        ({"evaluate": {"episodes": 4, "tiles": 8}}, "evaluate: unknown key"),
        ({"arms": {"a": ["ppo.value_targets=per_epoch"]}}, "arm 'a' does not build"),
        ({"seeds": [0, 0]}, "distinct seeds"),
        ({"arms": {"a": {"config": "configs/train_flat.yaml", "sets": []}}}, "arm 'a': unknown key"),
    ],
)
def test_a_bad_sweep_file_is_refused_before_anything_runs(tmp_path, changes, match):
    with pytest.raises(ValueError, match=match):
        sweep.load(_write(tmp_path, **changes))
    with pytest.raises(FileNotFoundError):
        sweep.load(tmp_path / "missing.yaml")


def test_every_arm_and_seed_is_one_run_at_equal_steps_then_one_evaluation(tmp_path):
    spec = sweep.load(_write(tmp_path, evaluate={"episodes": 8, "terrain": {"levels": "1", "tiles": 8}}))
    jobs = sweep.plan(spec, tmp_path / "out")
    assert [(j.seed, j.arm) for j in jobs] == [(0, "a"), (0, "b"), (1, "a"), (1, "b")]  # seeds outermost
    for job in jobs:
        assert f"run.num_timesteps={spec.env_steps}" in job.train and f"run.seed={job.seed}" in job.train
        config = train_config.load(spec.config, spec.overrides(job.arm, job.seed))
        assert config.ppo.value_targets == ("per_iteration" if job.arm == "b" else "per_minibatch")
        ev = job.evaluate
        assert ev[ev.index("--terrain-seed") + 1] == "1000" and ev[ev.index("--tiles") + 1] == "8"
        assert str(job.run_dir) in ev and "--stochastic" not in ev  # the mean action
    assert [(j.arm, j.seed) for j in sweep.select(jobs, "b:1, a:0, b:1")] == [("b", 1), ("a", 0)]  # --only, as named
    with pytest.raises(ValueError, match="no run c:0 in this sweep; valid: a:0, b:0, a:1, b:1"):
        sweep.select(jobs, "a:0,c:0")
    # an arm with a config of its own trains from it, with its overrides
    own = {"config": "configs/train_flat_st3215.yaml", "set": ["ppo.value_targets=per_iteration"]}
    spec = sweep.load(_write(tmp_path, arms={"a": [], "st3215": own}))
    job = sweep.plan(spec, tmp_path / "out")[1]
    assert job.train[job.train.index("--config") + 1] == own["config"] and spec.config_of("a") == SWEEP["config"]
    assert train_config.load(own["config"], spec.overrides("st3215", 0)).env.robot == "st3215"


def _fake_run(run_dir: Path, success: float, v_loss: float, episodes: int = 100) -> None:
    """A run folder as python -m train and train.evaluate leave it, with made-up figures."""
    run_dir.mkdir(parents=True)
    config = train_config.to_dict(train_config.load("configs/train_flat.yaml"))
    (run_dir / "config.yaml").write_text(yaml.safe_dump(config))
    rows = [
        {
            "step": 655_360 * (i + 1),
            "loss/v_loss": v_loss / (i + 1),
            "episode/success_rate": 0.95,
            "curriculum/max_distance": 4.5,
            "training/walltime": 10.0 * (i + 1),
        }
        for i in range(3)
    ]
    (run_dir / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    (run_dir / "summary.json").write_text(json.dumps({"env_steps": 1_966_080, "wall_s": 30.0, "interrupted": False}))
    (run_dir / "sweep_eval").mkdir()
    (run_dir / "sweep_eval" / "eval.json").write_text(json.dumps({"episodes": episodes, "success_rate": success}))


def test_the_report_pools_seeds_with_intervals_and_compares_to_the_first_arm(tmp_path):
    spec = sweep.load(_write(tmp_path))
    out = tmp_path / "out"
    jobs = sweep.plan(spec, out)
    figures = {("a", 0): 0.50, ("a", 1): 0.52, ("b", 0): 0.90, ("b", 1): 0.92}
    for job in jobs:
        _fake_run(job.run_dir, figures[(job.arm, job.seed)], v_loss=3e8 if job.arm == "a" else 0.2)
    report = sweep_report.write(spec, jobs, out)
    a, b = report["arms"]["a"], report["arms"]["b"]
    assert (a["successes"], a["episodes"]) == (102, 200) and (b["successes"], b["episodes"]) == (182, 200)
    assert a["ci95"][0] < 0.51 < a["ci95"][1] and b["ci95"][1] < 1.0
    assert b["vs_first"]["verdict"] == "better" and b["vs_first"]["ci95"][0] > 0
    run = next(r for r in report["runs"] if r["arm"] == "b")
    assert run["learning"]["first_v_loss"] == pytest.approx(0.2)
    assert run["learning"]["time_to_target"]["reached"]["env_steps"] == 655_360
    for name in ("sweep.json", "sweep.md", "sweep.png", "arm_a.png", "arm_b.png"):
        assert (out / name).stat().st_size > 0
    assert "cut by re-draws" not in (out / "sweep.md").read_text()  # no terrain re-draws: no such column
    # a difference inside the seeds' spread is not read as a win
    for job in jobs:
        (job.run_dir / "sweep_eval" / "eval.json").write_text(
            json.dumps(
                {
                    "episodes": 1000,
                    "success_rate": {("a", 0): 0.5, ("a", 1): 0.6, ("b", 0): 0.58, ("b", 1): 0.6}[(job.arm, job.seed)],
                }
            )
        )
    assert "not separated" in sweep_report.write(spec, jobs, out)["arms"]["b"]["vs_first"]["verdict"]


def test_on_terrain_the_report_pools_failure_modes_per_type_and_counts_episodes_cut_by_redraws(tmp_path):
    spec = sweep.load(_write(tmp_path))
    jobs = sweep.plan(spec, tmp_path / "out")
    for job in jobs:
        _fake_run(job.run_dir, 0.5, v_loss=1.0)
        stuck = 0.5 if job.seed == 0 else 0.25  # one type each: poles reached 50 %, the rest stuck or lost
        rows = [
            {"type": "flat", "episodes": 10, "success_rate": 1.0, "modes": {"reached": 1.0}},
            {
                "type": "poles",
                "episodes": 30,
                "success_rate": 0.5,
                "modes": {"reached": 0.5, "stuck": stuck, "lost": 0.5 - stuck},
            },
        ]
        (job.run_dir / "sweep_eval" / "terrain_eval.json").write_text(json.dumps({"rows": rows}))
        metrics = [
            {"step": 655_360, "training/walltime": 10.0, "episodes": 30.0, "terrain/redraw_truncations": 10.0},
            {"step": 1_966_080, "training/walltime": 30.0, "episodes": 60.0},
        ]
        (job.run_dir / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in metrics))
    report = sweep_report.write(spec, jobs, tmp_path / "out", devices=["0", "0"])
    a = report["arms"]["a"]
    assert a["per_type"] == pytest.approx({"flat": 1.0, "poles": 0.5})
    assert a["modes"]["stuck"] == pytest.approx((15 + 7.5) / 80) and a["modes"]["reached"] == pytest.approx(50 / 80)
    assert report["runs"][0]["learning"]["redraw_truncated_share"] == pytest.approx(10 / 100)
    assert report["runs"][0]["evaluation"]["per_type_modes"]["poles"]["stuck"] == pytest.approx(0.5)
    text = (tmp_path / "out" / "sweep.md").read_text()
    assert "| a | 62.5% | 28.1% | 9.4% | 0.0% | 0.0% |" in text and "| poles | 50.0% | 50.0% |" in text
    assert "| a seed 0 | 62.5% (47%-76%) | - | - | not reached | 10.0% |" in text
    assert "2 runs at once on 1 GPU(s) (`--devices 0,0`)" in text  # their seconds are not one run's alone


def test_runs_share_the_devices_and_a_finished_run_is_not_trained_again(tmp_path):
    """The runner takes the next job as a device frees; a run whose summary says it is done only evaluates."""
    spec = sweep.load(_write(tmp_path))
    jobs = sweep.plan(spec, tmp_path / "out")[:2]
    done = json.dumps({"env_steps": spec.env_steps, "interrupted": False})
    for job in jobs:
        job.train = ["-c", f"import pathlib; pathlib.Path({str(job.run_dir / 'summary.json')!r}).write_text({done!r})"]
        job.evaluate = ["-c", f"import pathlib; pathlib.Path({str(job.run_dir / 'sweep_eval')!r}).mkdir()"]
    sweep.Runner(["0", "1"], deadline=None).run(jobs, spec.env_steps)
    assert all(sweep.trained(j, spec.env_steps) and (j.run_dir / "sweep_eval").is_dir() for j in jobs)
    jobs[0].train = ["-c", "raise SystemExit(1)"]  # would fail if run again
    (jobs[0].run_dir / "sweep_eval").rmdir()
    sweep.Runner([None], deadline=None).run(jobs[:1], spec.env_steps)
    assert (jobs[0].run_dir / "sweep_eval").is_dir()


def test_a_run_trained_further_is_evaluated_again(tmp_path):
    """Raising a sweep's env steps continues its runs; their evaluations of the earlier checkpoint are dropped."""
    spec = sweep.load(_write(tmp_path))
    job = sweep.plan(spec, tmp_path / "out")[0]
    _fake_run(job.run_dir, 0.5, v_loss=1.0)
    evaluation = job.run_dir / "sweep_eval" / "eval.json"
    evaluation.write_text(json.dumps({"episodes": 100, "success_rate": 0.5, "step": 1_966_080}))
    assert sweep_report.evaluation(job.run_dir)["successes"] == 50
    more = 2 * spec.env_steps
    done = json.dumps({"env_steps": more, "interrupted": False})
    job.train = ["-c", f"import pathlib; pathlib.Path({str(job.run_dir / 'summary.json')!r}).write_text({done!r})"]
    assert sweep_report.evaluation(job.run_dir) is not None  # not trained further yet
    job.evaluate = ["-c", "import sys; sys.exit(3)"]  # the evaluation fails: nothing stale stays behind
    sweep.Runner([None], deadline=None).run([job], more)
    assert sweep.trained(job, more) and not (job.run_dir / "sweep_eval").exists()
    evaluation.parent.mkdir()
    evaluation.write_text(json.dumps({"episodes": 100, "success_rate": 0.5, "step": 1_966_080}))
    assert sweep_report.evaluation(job.run_dir) is None  # an earlier checkpoint's figure is not reported


GRID = {"name": "stress", "episodes": 50, "reference": ["flat"]}


@pytest.mark.parametrize(
    "grid, error, match",
    [
        ({"name": "hardest"}, ValueError, "grids: "),
        ({"name": "stress", "cells": 3}, ValueError, "evaluate.grid: unknown key"),
        ({"name": "stress", "reference": ["no_such_policy"]}, FileNotFoundError, "no_such_policy"),
    ],
)
def test_a_bad_grid_evaluation_is_refused_before_anything_runs(tmp_path, grid, error, match):
    with pytest.raises(error, match=match):
        sweep.load(_write(tmp_path, evaluate={"episodes": 8, "grid": grid}))


def _fake_grid(path: Path, rates: list[float], episodes: int = 50) -> None:
    """A robustness result as benchmarks.robustness.score writes it: per cell, its label and counts."""
    path.parent.mkdir(parents=True, exist_ok=True)
    cells = [
        {"label": f"cell {i}", "successes": round(r * episodes), "episodes": episodes, "success_rate": r}
        for i, r in enumerate(rates)
    ]
    played = {"grid": "stress", "physics_backend": "warp", "episodes_per_cell": episodes, "where": []}
    path.write_text(json.dumps({**played, "cells": cells}))


def test_the_grid_evaluation_exports_each_run_and_compares_the_pooled_arms_to_each_reference(tmp_path):
    spec = sweep.load(_write(tmp_path, evaluate={"episodes": 8, "backend": "warp", "grid": GRID}))
    out = tmp_path / "out"
    jobs, refs = sweep.plan(spec, out), sweep.references(spec, out)
    export, grid = jobs[0].grid
    assert export[:2] == ["-m", "train.export"] and str(jobs[0].run_dir) in export
    assert grid[grid.index("--episodes") + 1] == "50" and grid[grid.index("--seed") + 1] == "1000"
    assert grid[2] == export[export.index("--out") + 1] and grid[grid.index("--backend") + 1] == "warp"
    assert [(r.arm, r.train, r.evaluate) for r in refs] == [("reference flat", [], [])]
    assert refs[0].grid[0][2] == "flat"
    rates = {("a", 0): [1.0, 0.2], ("a", 1): [1.0, 0.3], ("b", 0): [0.6, 0.9], ("b", 1): [0.7, 0.9]}
    for job in jobs:
        _fake_run(job.run_dir, 0.9, v_loss=1.0)
        _fake_grid(job.grid_result, rates[(job.arm, job.seed)])
    _fake_grid(refs[0].grid_result, [1.0, 0.3])
    report = sweep_report.write(spec, jobs, out, references=refs)["grid"]
    a, b = report["arms"]["a"], report["arms"]["b"]
    assert [c["successes"] for c in b["cells"]] == [65, 90] and b["cells"][1]["per_seed"] == [0.9, 0.9]
    assert b["min_success_cell"] == "cell 0" and b["mean_success_rate"] == pytest.approx(0.775)
    worse, better = b["versus"]["flat"]
    assert worse["ci95"][1] < 0 < better["ci95"][0]  # b loses cell 0 and wins cell 1 against flat
    assert a["versus"]["flat"][1]["ci95"][0] < 0 < a["versus"]["flat"][1]["ci95"][1]  # a: not separated
    assert report["references"]["flat"]["cells_upper_bound_below_90"] == 1
    text = (out / "sweep.md").read_text()
    assert "| cell 1 | 30% " in text and "Played on warp: the stress grid, 50 episodes a cell." in text


def test_a_reference_is_played_once_and_never_trained(tmp_path):
    spec = sweep.load(_write(tmp_path, evaluate={"episodes": 8, "grid": GRID}))
    ref = sweep.references(spec, tmp_path / "out")[0]
    ref.grid = [
        [
            "-c",
            f"import pathlib; p = pathlib.Path({str(ref.grid_result)!r}); "
            "p.parent.mkdir(parents=True); p.write_text('{}')",
        ]
    ]
    sweep.Runner([None], deadline=None).run([ref], spec.env_steps)
    assert ref.grid_result.is_file() and not (ref.run_dir / "sweep_eval").exists()
    ref.grid = [["-c", "raise SystemExit(1)"]]  # would fail if played again
    sweep.Runner([None], deadline=None).run([ref], spec.env_steps)


def test_equal_wall_clock_runs_are_evaluated_at_every_checkpoint_and_the_time_to_target_read_from_them(tmp_path):
    """``budget_s`` stops each run on its training clock (a run so stopped is done); with
    ``evaluate.every_checkpoint`` each checkpoint is evaluated once (in one batch; the newest's is the
    run's final evaluation) and the time to the target is the first evaluated checkpoint at the target,
    with its training seconds."""
    from train.run import checkpoint

    spec = sweep.load(_write(tmp_path, budget_s=120, evaluate={"episodes": 100, "every_checkpoint": True}))
    job = sweep.plan(spec, tmp_path / "out")[0]
    assert train_config.load(spec.config, spec.overrides("a", 0)).run.max_training_s == 120
    job.run_dir.mkdir(parents=True)
    stopped = json.dumps({"env_steps": 3000, "interrupted": False, "stopped_by": "max_training_s"})
    job.train = ["-c", f"import pathlib; pathlib.Path({str(job.run_dir / 'summary.json')!r}).write_text({stopped!r})"]
    for i, seconds in enumerate((40.0, 80.0, 120.0)):  # three checkpoints at a steady clock
        path = checkpoint.checkpoint_dir(job.run_dir) / f"step_{(i + 1) * 1000:012d}"
        path.mkdir(parents=True)
        meta = {"format": checkpoint.FORMAT_VERSION, "config": {}, "step": (i + 1) * 1000}
        (path / checkpoint.META_FILE).write_text(json.dumps({**meta, "training_walltime_s": seconds}))
    script = (  # train.evaluate's stand-in: success 0.5, 0.95, 0.97 by checkpoint, into --out (several: its folders)
        "import json, pathlib, sys; a = sys.argv; out = pathlib.Path(a[a.index('--out') + 1]);"
        "ckpts = a[a.index('--checkpoint') + 1 :] if '--checkpoint' in a else [];"
        "outs = [out / pathlib.Path(c).name for c in ckpts] if len(ckpts) > 1 else [out];"
        "steps = [int(c[-12:]) for c in ckpts] or [3000];"
        "rates = {1000: 0.5, 2000: 0.95, 3000: 0.97};"
        "[o.mkdir(parents=True) for o in outs];"
        "[(o / 'eval.json').write_text(json.dumps({'episodes': 100, 'success_rate': rates[s], 'step': s, "
        "'played': 'final' if not ckpts else 'checkpoint'})) for o, s in zip(outs, steps)]"
    )
    job.evaluate = ["-c", script, "--out", str(job.run_dir / "sweep_eval")]
    sweep.Runner([None], deadline=None).run([job], spec.env_steps)
    assert sweep.trained(job, spec.env_steps)  # stopped by its budget short of the env steps: done
    report = sweep_report.write(spec, [job], tmp_path / "out")
    run = report["runs"][0]
    assert [p["training_walltime_s"] for p in run["checkpoints"]] == [40.0, 80.0, 120.0]
    assert run["evaluated_time_to_target"] == {"training_s": 80.0, "env_steps": 2000, "success_rate": 0.95}
    text = (tmp_path / "out" / "sweep.md").read_text()
    assert "80 s, 2,000 env steps" in text and "resumed from its newest checkpoint" not in text  # one call
    final = json.loads((job.run_dir / "sweep_eval" / "eval.json").read_text())
    assert final["played"] == "checkpoint" and final["step"] == 3000  # the newest's, not played again
    assert run["evaluation"]["success_rate"] == 0.97
    job.evaluate = ["-c", "raise SystemExit(1)", "--out", "x"]  # evaluated checkpoints are not evaluated again
    sweep.Runner([None], deadline=None).run([job], spec.env_steps)
    assert len(sweep_report.write(spec, [job], tmp_path / "out")["runs"][0]["checkpoints"]) == 3
    resumed = {"calls": 2, "startup": {"first_update_since_launch_s": 30.0, "cold_caches": False}}
    (job.run_dir / "summary.json").write_text(json.dumps({**json.loads(stopped), **resumed}))
    sweep_report.write(spec, [job], tmp_path / "out")
    text = (tmp_path / "out" / "sweep.md").read_text()
    assert "30 s, warm caches, the last of 2 calls" in text and "resumed from its newest checkpoint" in text


def test_runs_sharing_a_gpu_share_its_memory(monkeypatch):
    monkeypatch.delenv("XLA_PYTHON_CLIENT_MEM_FRACTION", raising=False)
    runner = sweep.Runner(["0", "0", "0", "1"], deadline=None)
    assert runner.environment("0")["XLA_PYTHON_CLIENT_MEM_FRACTION"] == "0.250"
    assert runner.environment("0")["CUDA_VISIBLE_DEVICES"] == "0"
    assert "XLA_PYTHON_CLIENT_MEM_FRACTION" not in runner.environment("1")  # alone on its GPU: XLA's default
    monkeypatch.setenv("XLA_PYTHON_CLIENT_MEM_FRACTION", "0.5")  # the user's choice wins
    assert runner.environment("0")["XLA_PYTHON_CLIENT_MEM_FRACTION"] == "0.5"
