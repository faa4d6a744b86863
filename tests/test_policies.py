"""Shipped policies (policies/<task>/): each beats a zero policy on its task; ``train.evaluate --policy``."""

from __future__ import annotations

import json

import numpy as np
import pytest

from hsa_mjx import resources
from hsa_mjx.deploy import policy_file
from hsa_mjx.sim.host_physics import HostPhysics
from train import evaluate
from train.episodes import policy_sources, rollout

SHIPPED = list(policy_file.shipped())
EPISODES, STEPS = 4, 250  # per policy: the corridor policy, slowest between its walls, closes the least
MARGIN_M = 0.02
# A terrain policy with goals on reachable ground (rough) is played on two of its levels (flat and the
# top) with 4 goal sites a tile: its 10-level ladder's distance fields take 190 s to build under the
# suite's unoptimised XLA (25 s optimised), these 9 s.
REACHABLE_SMALL = ("env.terrain.levels=2", "env.terrain.reachability.goal_sites=4")


def _small_env(name: str) -> tuple[str, ...]:
    terrain = policy_file.load_policy(policy_file.shipped()[name]).meta["config"]["env"].get("terrain") or {}
    return REACHABLE_SMALL if (terrain.get("reachability") or {}).get("enabled") else ()


def goal_progress(traces: dict) -> np.ndarray:
    """Metres each episode closed on its current goal, summed over its steps (the steps where a spiral's
    goal moves on to the next checkpoint are left out, so progress along the track counts)."""
    distance = np.concatenate([traces["start_distance"][:, None], traces["distance"]], axis=1)
    goal_index = np.concatenate([traces["checkpoint"][:, :1], traces["checkpoint"]], axis=1)
    closed = distance[:, :-1] - distance[:, 1:]
    same_goal = goal_index[:, 1:] == goal_index[:, :-1]
    return np.sum(np.where(same_goal & traces["alive"].astype(bool), closed, 0.0), axis=1)


def test_policies_folder_documents_every_shipped_policy():
    assert {"corridor", "flat"} <= set(SHIPPED)
    readme = (resources.data_dir("policies") / "README.md").read_text()
    for name in SHIPPED:
        assert f"policies/{name}" in readme, name


@pytest.mark.slow
@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_policy_beats_a_zero_policy(name):
    """The policy and a zero policy (the same network with zero weights) from the same starts and
    goals, in one compiled rollout: on average, and in all episodes but at most one (a policy that
    reaches 95 % of its goals may meet a start it fails), the trained one closes more distance.
    The physics runs in C MuJoCo (the original's engine; the policies trained on MJX)."""
    import jax
    import jax.numpy as jnp

    config, env, _, policy = policy_sources.load_shipped_policy(policy_file.shipped()[name], overrides=_small_env(name))
    trained = jax.tree.map(jnp.asarray, policy.params)
    zero = {
        **trained,
        "kernels": tuple(jnp.zeros_like(k) for k in trained["kernels"]),
        "biases": tuple(jnp.zeros_like(b) for b in trained["biases"]),
    }
    params = jax.tree.map(lambda a, b: jnp.stack([a] * EPISODES + [b] * EPISODES), trained, zero)
    keys = jax.random.split(jax.random.PRNGKey(0), EPISODES)
    goal_range = jnp.asarray(policy_sources.default_goal_range(config), jnp.float32)
    c_mujoco = HostPhysics(env.robot.mj_model, env.index, env.motors)  # the substeps in C MuJoCo: fast on a CPU
    traces = jax.device_get(
        rollout.rollout(
            env,
            policy_sources.shipped_policy_apply(policy),
            jnp.concatenate([keys, keys]),
            goal_range,
            STEPS,
            params=params,
            simulate=c_mujoco,
        )
    )
    traces = {k: np.asarray(v) for k, v in traces.items()}
    assert np.all(traces["action"][EPISODES:] == 0.0) and np.any(traces["action"][:EPISODES] != 0.0)
    np.testing.assert_allclose(traces["goal"][:EPISODES, 0], traces["goal"][EPISODES:, 0])  # same goals
    progress = goal_progress(traces)
    best_zero = progress[EPISODES:].max()
    assert progress[:EPISODES].mean() > best_zero + MARGIN_M, progress
    assert np.sum(progress[:EPISODES] > best_zero + MARGIN_M) >= EPISODES - 1, progress


def test_goal_progress_leaves_out_goal_switches():
    traces = {
        "start_distance": np.array([2.0]),
        "distance": np.array([[1.9, 1.8, 3.0, 2.9, 2.9]]),
        "checkpoint": np.array([[0, 0, 1, 1, 1]]),
        "alive": np.array([[1, 1, 1, 1, 0]]),
    }
    np.testing.assert_allclose(goal_progress(traces), [0.3])  # 0.2 to checkpoint 0, then 0.1 to checkpoint 1


def test_evaluate_policy_refuses_bad_input(tiny_run_dir, tmp_path, capsys):
    assert evaluate.main(["--policy", "nope"]) == 2
    err = capsys.readouterr().err
    assert "no policy 'nope'" in err and "'corridor'" in err  # lists the shipped ones
    assert evaluate.main(["--policy", "corridor", "--stochastic"]) == 2
    assert evaluate.main([]) == 2 and evaluate.main([str(tiny_run_dir), "--policy", "corridor"]) == 2
    assert evaluate.main(["--policy", "corridor", "--episodes", "0"]) == 2
    assert evaluate.main(["--policy", "rough", "--tiles", "0"]) == 2
    err = capsys.readouterr().err
    assert "--stochastic needs a RUN_DIR" in err and "either a RUN_DIR or --policy" in err and "--episodes" in err
    assert "--tiles must be between 1 and 256" in err
    assert evaluate.main(["--policy", "spiral", "--goal-range", "4", "4.5"]) == 2  # checkpoints: not radial goals
    assert "env.goal.mode=radial" in capsys.readouterr().err
    assert evaluate.main(["--policy", "flat", "--goal-range", "4.5", "4"]) == 2
    assert "0 < MIN <= MAX" in capsys.readouterr().err
    for key in ("ppo.learning_rate=1", "env.observation.heading=false"):  # only the env, not the policy's input
        assert evaluate.main([str(tiny_run_dir), "--set", key]) == 2
        assert f"evaluate --set '{key.split('=')[0]}'" in capsys.readouterr().err
    assert evaluate.main(["--policy", "corridor", "--set", "env.goal.far=1"]) == 2
    assert "unknown config key(s) ['far'] in section 'goal'" in capsys.readouterr().err
    broken = tmp_path / "broken"
    broken.mkdir()
    (broken / policy_file.META_FILE).write_text(json.dumps({"format": policy_file.FORMAT, "format_version": 99}))
    assert evaluate.main(["--policy", str(broken)]) == 2
    assert "format version 99" in capsys.readouterr().err


def test_evaluate_policy_runs_an_exported_policy(tiny_run_dir, tmp_path, capsys):
    from train import export

    assert export.main([str(tiny_run_dir), "--format", "npz", "--out", str(tmp_path / "tiny")]) == 0
    out = tmp_path / "eval"
    goal = ["--set", "env.goal.mode=fixed", "--set", "env.goal.position=[2.5,0.0]"]  # not the run's radial goals
    assert (
        evaluate.main(
            [
                "--policy",
                str(tmp_path / "tiny"),
                "--episodes",
                "2",
                "--steps",
                "12",
                "--backend",
                "c",
                "--out",
                str(out),
                *goal,
            ]
        )
        == 0
    )
    assert f"wrote 4 files to {out}" in capsys.readouterr().out
    result = json.loads((out / "eval.json").read_text())
    assert result["policy_dir"] == "tiny" and result["policy"] == "deterministic"  # no absolute machine path
    assert result["episodes"] == 2 and result["max_steps"] == 12 and result["step"] >= 80
    assert result["physics"] == "c_mujoco"  # the substeps ran in C MuJoCo
    assert result["source"]["run"] == tiny_run_dir.name and result["mean_final_distance"] > 0
    overrides = {"env.goal.mode": "fixed", "env.goal.position": [2.5, 0.0]}
    assert result["env_overrides"] == overrides and abs(result["mean_start_distance"] - 2.5) < 0.1
    for name in ("actions.png", "joints.png", "constraint.png", "trajectories.png"):
        assert (out / name).stat().st_size > 5_000


def test_gif_frames_are_capped(env, tmp_path):
    from PIL import Image

    from train.episodes import diagnostics

    steps = 12
    qpos = np.tile(env.robot.mj_model.qpos0, (1, steps, 1))
    qpos[0, :, env.index.joint_qpos] += np.linspace(0.0, 3.0, steps)[None, :]  # distinct frames: GIF merges repeats
    traces = {"alive": np.ones((1, steps)), "qpos": qpos, "goal": np.zeros((1, steps, 2))}
    for cap, frames in ((diagnostics.GIF_FRAMES, 6), (4, 4)):  # every 2nd step; every 3rd for 4 frames
        path = diagnostics.render_gif(traces, env, tmp_path / f"{cap}.gif", max_frames=cap)
        with Image.open(path) as gif:
            assert gif.n_frames == frames and gif.size == (480, 360)
