"""End to end on CPU: a tiny PPO run with the curriculum, checkpoints, resume, refusal, evaluation."""

from __future__ import annotations

import dataclasses
import json
import shutil

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import TINY_RUN as TINY

from train import config as train_config
from train.run import checkpoint


def tiny(**run) -> train_config.TrainConfig:
    data = json.loads(json.dumps(TINY))
    data["run"].update(run)
    return train_config.from_dict(data)


@pytest.fixture(scope="module")
def run_dir(tiny_run_dir):
    return tiny_run_dir  # trained once per session (tests/conftest.py)


def records(path):
    from train.run.logger import read_jsonl

    return read_jsonl(path / "metrics.jsonl")


def test_run_leaves_checkpoints_logs_and_plots(run_dir):
    assert [p.name for p in checkpoint.list_checkpoints(run_dir)] == ["step_000000000040", "step_000000000080"]
    assert (run_dir / "config.yaml").is_file() and (run_dir / "learning_curve.png").stat().st_size > 10_000
    assert (run_dir / "ppo_diagnostics.png").stat().st_size > 10_000
    assert list((run_dir / "tensorboard").iterdir())
    recs = records(run_dir)
    assert [r["step"] for r in recs] == [40, 80]
    last = recs[-1]
    for key in (
        "loss/total_loss",
        "loss/policy_loss",
        "loss/v_loss",
        "loss/kl_mean",
        "loss/clip_fraction",
        "loss/explained_variance",
        "loss/grad_norm",
        "loss/learning_rate",
        "curriculum/max_distance",
        "curriculum/success_rate",
        "training/env_steps_per_s",
        "nonfinite/states",
    ):
        assert np.isfinite(last[key]), key
    assert last["training/since_launch"] > last["training/walltime"] > 0  # the process started before the loop
    startup = json.loads((run_dir / "summary.json").read_text())["startup"]
    before = startup["imports_s"] + startup["build_s"] + startup["init_s"] + startup["reset_s"]
    assert 0.0 < before < startup["first_update_since_launch_s"] <= recs[0]["training/since_launch"]
    assert 0.0 <= startup["compile_s"] <= startup["first_update_s"] and isinstance(startup["cold_caches"], bool)
    xla = startup["xla"]  # each program JAX compiled, by name: the training epoch's among the largest
    assert xla["programs"] >= 2 and 0.0 < max(xla["largest"].values()) <= xla["compile_s"]
    assert xla["trace_s"] > 0.0 and startup["warp_prebuild_s"] is None  # no Warp build ahead on a CPU
    assert startup["epoch_compile_s"] > 0.0 and "warp_warm_up_s" not in startup  # compiled ahead; no Warp here
    with_episodes = [r for r in recs if r["episodes"] > 0]
    assert with_episodes and "episode/reward/forward" in with_episodes[0]
    assert "termination/goal_reached" in with_episodes[0]


def test_curriculum_updates_inside_training(run_dir):
    last = records(run_dir)[-1]
    assert last["curriculum/episode_count"] == 4  # 80 env steps = 20 per env: one 15-step episode each
    assert last["curriculum/max_distance"] > 1.8 + 1e-6  # widened from the initial range


def test_resume_continues_step_and_curriculum(run_dir):
    from train.trainer import train

    before = records(run_dir)[-1]
    meta = checkpoint.read_meta(checkpoint.latest(run_dir))
    clock = meta["training_walltime_s"]
    summary = train(tiny(num_timesteps=160), run_dir, resume=True, quiet=True)  # envs restart on resume
    assert summary["env_steps"] == 160
    assert (meta["calls"], summary["calls"]) == (1, 2)  # training calls: the fresh one, then this resume
    assert summary["checkpoint"] == "checkpoints/step_000000000160"  # within the run dir, no absolute path
    after = records(run_dir)[-1]
    assert after["step"] == 160
    assert after["curriculum/episode_count"] > before["curriculum/episode_count"]
    assert after["curriculum/max_distance"] >= before["curriculum/max_distance"]
    assert checkpoint.read_meta(checkpoint.latest(run_dir))["training_walltime_s"] > clock > 0.0  # the clock goes on


def test_a_checkpoint_is_due_by_env_steps_or_by_the_runs_clock_where_set():
    from train.trainer import checkpoint_due, next_checkpoint_s

    steps = tiny().run  # a checkpoint every 40 env steps
    clock = dataclasses.replace(steps, checkpoint_every_s=30.0)
    off = next_checkpoint_s(0.0, steps)
    assert checkpoint_due(40, 0.0, off, steps) and not checkpoint_due(39, 1e6, off, steps)  # the clock off by default
    assert next_checkpoint_s(0.0, clock) == 30.0 and next_checkpoint_s(31.5, clock) == 60.0
    assert next_checkpoint_s(1164.4, clock) == 1170.0  # a resumed call keeps the run's schedule
    assert checkpoint_due(1, 30.0, 30.0, clock) and not checkpoint_due(39, 29.9, 30.0, clock)
    with pytest.raises(ValueError, match="checkpoint_every_s"):
        train_config.from_dict({"run": {"checkpoint_every_s": -1.0}})


def test_a_restored_learner_state_has_the_types_of_a_fresh_one(run_dir):
    """Shapes, dtypes and weak types alike: a resumed run's epoch is the fresh run's program (the
    persistent compilation cache serves it; a weakly typed leaf would make it another program)."""
    import jax

    from train.devices import strategies
    from train.learners.ppo.networks import init_training_state
    from train.run import saved

    config = tiny()
    learner = strategies.build(config, jax.devices()[:1]).learner
    fresh = init_training_state(config, learner.networks, jax.random.PRNGKey(0), learner.network_input_size)
    restored = saved.restore_training_state(checkpoint.latest(run_dir), fresh, config)
    assert jax.tree.map(jax.typeof, restored) == jax.tree.map(jax.typeof, fresh)
    assert not [x for x in jax.tree.leaves(fresh) if jax.typeof(x).weak_type]


def test_resume_refuses_other_config_and_overwrite(run_dir):
    from train.trainer import train

    other = train_config.from_dict(
        train_config.apply_overrides(json.loads(json.dumps(TINY)), ["env.reward.forward=1.0"])
    )
    with pytest.raises(ValueError, match="env.reward.forward"):
        train(other, run_dir, resume=True, quiet=True)
    with pytest.raises(ValueError, match="--resume"):
        train(tiny(), run_dir, quiet=True)


def _crashed_copy(run_dir, tmp_path):
    """A copy of the run as a kill -9 after its newest checkpoint leaves it: log records past the
    checkpoint and a cut-off last line. Returns (copy, the checkpoint's step)."""
    copy = tmp_path / "crashed"
    shutil.copytree(run_dir, copy)
    step = int(checkpoint.read_meta(checkpoint.latest(copy))["step"])
    with (copy / "metrics.jsonl").open("a") as fh:
        for later in (step + 40, step + 80):
            fh.write(json.dumps({"step": later, "time": 0.0, "episodes": 0.0}) + "\n")
        fh.write('{"step": ')
    return copy, step


def test_resume_after_a_crash_logs_every_step_once_in_order(run_dir, tmp_path):
    from train.trainer import train

    copy, step = _crashed_copy(run_dir, tmp_path)
    summary = train(tiny(num_timesteps=step + 80), copy, resume=True, quiet=True)
    assert summary["env_steps"] == step + 80
    steps = [r["step"] for r in records(copy)]
    assert steps == sorted(set(steps)) and steps[-2:] == [step + 40, step + 80], steps  # strictly increasing
    assert records(copy)[-1]["episodes"] > 0 or "loss/total_loss" in records(copy)[-1]  # the new run's records
    with pytest.raises(ValueError, match=r"already holds a run.*--resume.*--overwrite"):
        train(tiny(), copy, quiet=True)  # a second start without --resume


def test_resume_falls_back_to_the_newest_readable_checkpoint(run_dir, tmp_path, capsys):
    from train.trainer import train

    copy, step = _crashed_copy(run_dir, tmp_path)
    (checkpoint.latest(copy) / checkpoint.STATE_FILE).write_bytes(b"\x00 not msgpack")
    previous = checkpoint.list_checkpoints(copy)[-2]
    start = int(checkpoint.read_meta(previous)["step"])
    summary = train(tiny(num_timesteps=step + 40), copy, resume=True, quiet=True)
    out = capsys.readouterr().out
    assert (
        "skipping unreadable checkpoint" in out
        and f"resuming from the newest readable checkpoint, {previous.name}" in out
    )
    assert summary["env_steps"] == step + 40
    steps = [r["step"] for r in records(copy)]
    assert steps == sorted(set(steps)) and steps[-1] == step + 40 and start in steps


def test_a_run_dir_without_checkpoints_is_refused_or_overwritten(tmp_path):
    from train.run.folder import prepare_run_dir

    early = tmp_path / "early"  # killed before its first checkpoint: logs only
    early.mkdir()
    (early / "metrics.jsonl").write_text(json.dumps({"step": 40}) + "\n")
    (early / "notes.txt").write_text("mine")
    with pytest.raises(ValueError, match="already holds a run \\(metrics.jsonl\\)"):
        prepare_run_dir(early, {"run": {}}, resume=False)
    with pytest.raises(FileNotFoundError, match="no readable checkpoint"):
        prepare_run_dir(early, {"run": {}}, resume=True)
    assert prepare_run_dir(early, {"run": {"seed": 3}}, resume=False, overwrite=True) is None
    assert not (early / "metrics.jsonl").exists() and (early / "notes.txt").read_text() == "mine"
    assert "seed: 3" in (early / "config.yaml").read_text()


def test_only_process_zero_judges_a_fresh_run_dir_and_a_refusal_stops_every_process(tmp_path, monkeypatch):
    from train import trainer
    from train.devices import distributed

    started = tmp_path / "started"  # process 0 has already written its config.yaml when process 1 looks
    started.mkdir()
    (started / "config.yaml").write_text("run: {}\n")
    monkeypatch.setattr(distributed, "is_main", lambda: False)
    assert trainer.prepare_run_dir(started, {"run": {}}, resume=False) is None
    assert (started / "config.yaml").read_text() == "run: {}\n"  # process 1 writes nothing
    monkeypatch.setattr(distributed, "any_process", lambda flag: True)  # process 0 refused
    with pytest.raises(ValueError, match="another process refused to start the run"):
        trainer.prepare_run_dir(started, {"run": {}}, resume=False)


def test_cli_errors_before_compile(run_dir, capsys):
    from train.cli import main

    assert main(["--config", "configs/nope.yaml"]) == 2
    assert main(["--config", "configs/train_quickstart_cpu.yaml", "--set", "ppo.nope=1"]) == 2
    assert main(["--resume"]) == 2
    assert main(["--resume", "--overwrite", "--run-dir", str(run_dir)]) == 2
    err = capsys.readouterr().err
    assert "give one" in err
    assert "not found" in err and "unknown config key" in err and "--run-dir" in err


def test_evaluate_writes_summary_and_plots(run_dir):
    from train.evaluate import main

    assert main([str(run_dir), "--episodes", "2", "--steps", "12"]) == 0  # auto: C MuJoCo substeps on this CPU
    result = json.loads((run_dir / "eval" / "eval.json").read_text())
    assert result["physics"] == "c_mujoco"
    assert result["episodes"] == 2 and 0.0 <= result["success_rate"] <= 1.0
    assert result["mean_final_distance"] > 0
    assert result["policy"] == "deterministic" and result["max_steps"] == 12
    ends = sum(v for k, v in result.items() if k.startswith("termination/"))
    assert 0.0 <= result["not_finished"] <= 1.0 and ends + result["not_finished"] >= 1.0 - 1e-6  # every episode
    for name in ("actions.png", "joints.png", "constraint.png", "trajectories.png"):
        assert (run_dir / "eval" / name).stat().st_size > 5_000
    # trained on MJX's JAX implementation (the CPU's, recorded with the checkpoint), sampled on MJX's, asked
    # for by name (a shipped policy on the Warp backend: tests/test_backend.py)
    assert checkpoint.read_meta(checkpoint.latest(run_dir))["physics_backend"] == "jax"
    # an earlier checkpoint by its step (a plateau check compares two), a step it never saved refused
    first = int(checkpoint.list_checkpoints(run_dir)[0].name.split("_")[-1])
    assert main([str(run_dir), "--episodes", "2", "--steps", "12", "--checkpoint", str(first)]) == 0
    assert json.loads((run_dir / "eval" / "eval.json").read_text())["step"] == first
    assert main([str(run_dir), "--episodes", "2", "--steps", "12", "--checkpoint", str(first + 1)]) == 2
    assert main([str(run_dir), "--episodes", "2", "--steps", "12", "--stochastic", "--backend", "jax"]) == 0
    sampled = json.loads((run_dir / "eval" / "eval.json").read_text())
    assert sampled["policy"] == "stochastic" and sampled["episodes"] == 2 and sampled["mean_episode_steps"] > 0
    assert sampled["physics"] == "mjx_jax"  # --backend, the config's physics.backend names, picks the physics
    assert main([str(run_dir / "missing")]) == 2


def test_several_checkpoints_are_evaluated_in_one_batch_as_each_alone(run_dir, tmp_path):
    """``--checkpoint A B``: one rollout, each checkpoint's eval.json in its own folder, the same figures as
    its own evaluation on the same goals; what a batch cannot hold is refused before anything loads."""
    from train.evaluate import main

    saved = checkpoint.list_checkpoints(run_dir)
    steps = [str(int(p.name.split("_")[-1])) for p in saved]
    common = ["--episodes", "3", "--steps", "12", "--backend", "jax", "--seed", "5"]
    assert main([str(run_dir), *common, "--out", str(tmp_path), "--checkpoint", *steps]) == 0
    for step, path in zip(steps, saved):
        batched = json.loads((tmp_path / path.name / "eval.json").read_text())
        assert main([str(run_dir), *common, "--out", str(tmp_path / "alone"), "--checkpoint", str(path)]) == 0
        alone = json.loads((tmp_path / "alone" / "eval.json").read_text())
        assert batched["step"] == alone["step"] == int(step) and batched["episodes"] == 3
        assert batched["checkpoint"] == alone["checkpoint"] and batched["success_rate"] == alone["success_rate"]
        assert batched["mean_start_distance"] == pytest.approx(alone["mean_start_distance"], abs=1e-6)  # same goals
        # the same policy: XLA's batch of 6 rounds differently from a batch of 3 (measured 3e-4 m in 12 steps)
        assert batched["mean_final_distance"] == pytest.approx(alone["mean_final_distance"], abs=2e-3)
    assert main([str(run_dir), *common, "--checkpoint", *steps]) == 2  # no --out for the folders
    assert main([str(run_dir), *common, "--out", str(tmp_path), "--stochastic", "--checkpoint", *steps]) == 2


def test_several_checkpoints_on_terrain_are_one_batch_as_each_alone(run_dir, tmp_path):
    """On terrain too: one rollout on the same cells, tiles and goals, each checkpoint in its own block
    (the order given changes nothing), each one's terrain_eval.json as its own evaluation writes it (the
    policy's forward is the flat batch's, checked against single evaluations above)."""
    from train.evaluate import main

    saved = checkpoint.list_checkpoints(run_dir)
    common = ["--episodes", "2", "--steps", "12", "--backend", "jax", "--terrain-types", "flat", "--levels", "1"]
    for order, out in ((saved, tmp_path), (saved[::-1], tmp_path / "reversed")):
        assert main([str(run_dir), *common, "--out", str(out), "--checkpoint", *(str(p) for p in order)]) == 0
    rows = {p.name: json.loads((tmp_path / p.name / "terrain_eval.json").read_text())["rows"][0] for p in saved}
    for path in saved:
        again = json.loads((tmp_path / "reversed" / path.name / "terrain_eval.json").read_text())["rows"][0]
        assert again == rows[path.name]  # each block plays its own checkpoint, wherever it stands
    first, last = rows[saved[0].name], rows[saved[-1].name]
    assert first["mean_final_distance"] != last["mean_final_distance"]  # two policies
    header = json.loads((tmp_path / saved[-1].name / "terrain_eval.json").read_text())
    assert header["step"] == int(saved[-1].name[-12:]) and header["episodes_per_cell"] == last["episodes"] == 2
    assert header["checkpoint"].endswith(saved[-1].name) and header["policy"] == "deterministic"


def test_auto_reset_draws_fresh_goals_from_curriculum():
    """The batch env resets finished envs with the parameters the curricula give; it holds no curriculum."""
    import dataclasses

    from hsa_mjx.batch.auto_reset import AutoResetEnv, BatchState
    from hsa_mjx.curricula import goal_curriculum
    from hsa_mjx.curricula.state import CurriculumRules
    from hsa_mjx.task.env import HSAEnv

    config = tiny()
    env = HSAEnv(
        train_config.from_dict(
            train_config.apply_overrides(json.loads(json.dumps(TINY)), ["env.termination.max_episode_steps=3"])
        ).env
    )
    batch, rules = AutoResetEnv(env), CurriculumRules(env.config, config.goal_curriculum)
    # no curriculum state in the batch: the envs, episode sums, totals and (with regeneration) terrain tiles
    assert [f.name for f in dataclasses.fields(BatchState)] == ["env", "episode", "totals", "terrain"]
    keys = jax.random.split(jax.random.PRNGKey(0), 2)
    curricula = rules.init(keys)
    state = jax.jit(batch.reset)(keys, rules.params(curricula))
    step = jax.jit(batch.step)
    goals = []
    for _ in range(7):
        state = step(state, jnp.zeros((2, 8)), rules.params(curricula))
        goals.append(np.asarray(state.env.pipeline_state.task.goal_xy))
    goals = np.stack(goals)  # (7, 2 envs, 2)
    distinct = {tuple(np.round(g, 5)) for g in goals[:, 0]}
    assert len(distinct) >= 3  # three episodes of env 0, three different goals
    lo, hi = np.asarray(goal_curriculum.goal_range(curricula.goal, config.goal_curriculum, rules.start))
    radius = np.linalg.norm(goals, axis=-1)
    assert np.all(radius >= lo - 1e-5) and np.all(radius <= hi + 1e-5)
    assert float(state.totals["episodes"]) == 4  # 2 envs x 2 finished episodes
    from hsa_mjx.batch.auto_reset import summarize

    logged = summarize({k: float(v) for k, v in jax.device_get(state.totals).items()})
    assert logged["env_steps"] == 14  # 7 steps x 2 envs
    distances = np.asarray(state.env.metrics["distance_to_goal"])
    assert 1.0 < logged["step/distance_to_goal"] < 5.0 and np.all(distances > 0)  # a mean over every env step
    assert "terrain/redraw_truncated_share" not in logged  # no re-draws
    cut = summarize({**{k: float(v) for k, v in jax.device_get(state.totals).items()}, "redraw_truncations": 1.0})
    assert cut["terrain/redraw_truncated_share"] == 1.0 / 5.0  # one of the five episodes that ended was cut


def test_init_from_starts_with_the_source_networks(run_dir, tmp_path):
    from train.trainer import train

    config = tiny(num_timesteps=40, init_from=str(run_dir))  # the tiny run's programs: no new compile
    summary = train(config, tmp_path / "ft", quiet=True)
    assert summary["env_steps"] == 40  # a fresh step count
    source_ts = load_payload(checkpoint.latest(run_dir))
    tuned_ts = load_payload(checkpoint.latest(tmp_path / "ft"))
    # 40 env steps are one PPO iteration: 2 Adam steps, each moving a weight by about the learning rate
    # (a fresh initialisation would differ by tenths)
    moved = max(
        float(np.max(np.abs(np.asarray(a) - np.asarray(b))))
        for a, b in zip(jax.tree.leaves(source_ts["params"]), jax.tree.leaves(tuned_ts["params"]))
    )
    assert moved < 5 * 2 * config.ppo.learning_rate
    assert _count(tuned_ts["normalizer"]["count"]) > _count(source_ts["normalizer"]["count"])  # stats carried on


def _count(value) -> int:
    """A normaliser count as msgpack stores it: a number, or a uint64 split into hi and lo words."""
    return (int(value["hi"]) << 32) | int(value["lo"]) if isinstance(value, dict) else int(value)


def load_payload(path):
    from flax import serialization

    return serialization.msgpack_restore((path / checkpoint.STATE_FILE).read_bytes())["training_state"]


def test_init_from_refuses_other_networks_before_compile(run_dir, tmp_path, capsys):
    from train.cli import main
    from train.run.warm_start import read_init_from

    heading = train_config.from_dict(
        train_config.apply_overrides(
            json.loads(json.dumps(TINY)), ["env.observation.heading=true", f"run.init_from={run_dir}"]
        )
    )
    with pytest.raises(ValueError, match="observation size"):
        read_init_from(heading)
    wider = train_config.from_dict(
        train_config.apply_overrides(
            json.loads(json.dumps(TINY)), ["ppo.policy_hidden_sizes=[16]", f"run.init_from={run_dir}"]
        )
    )
    with pytest.raises(ValueError, match="policy_hidden_sizes"):
        read_init_from(wider)
    other_task = train_config.from_dict(
        train_config.apply_overrides(
            json.loads(json.dumps(TINY)),
            ["env.reward.forward=1.0", "ppo.learning_rate=0.0", f"run.init_from={run_dir}"],
        )
    )
    assert read_init_from(other_task)["step"] >= 80  # another env and optimiser: the same networks fit
    assert (
        main(
            [
                "--config",
                "configs/train_quickstart_cpu.yaml",
                "--run-dir",
                str(tmp_path / "x"),
                "--init-from",
                str(tmp_path / "missing"),
            ]
        )
        == 2
    )
    assert "run.init_from" in capsys.readouterr().err and not (tmp_path / "x").exists()
