"""The physics backend choice, and MJX's Warp implementation against its JAX implementation on a CPU.

MuJoCo Warp runs on a CPU (slowly): a few envs for a few steps suffice to check that one env code
path runs on both implementations, gives the same trajectories within a stated bound, and keeps
every env on its own terrain tile.
"""

from __future__ import annotations

import json
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import hsa_mjx
from hsa_mjx.batch.auto_reset import AutoResetEnv
from hsa_mjx.sim import backend

ENVS, REST, STEPS = 3, 8, 20  # envs, zero-action steps at rest, then gait steps
# Terrain tiles: flat, stairs and craters; solver settings of the shipped heightfield configs.
SETTINGS = {
    "physics.integrator": "implicitfast",
    "physics.iterations": 8,
    "physics.ls_iterations": 8,
    "terrain.types": ["flat", "stairs", "craters"],
    "terrain.tiles_per_type": 2,
    "scene": "terrain",
}
# Same gait from the same reset on both implementations, 20 env steps (400 substeps, float32 both):
# measured max |dqpos| 0.012 rad (hinges), block positions within 1.1 mm; the bounds leave room for
# the order of Warp's atomics (not run-to-run deterministic on a GPU).
QPOS_TOL, BLOCK_TOL = 0.1, 1e-2  # rad, m
# Foot contact forces (what the contact-cost reward reads), summed over the four feet: at rest both
# carry the robot's weight (58.9 N) within REST_FORCE_TOL; over the gait, impacts make single steps
# differ by up to ~35 N between the implementations (a touchdown a substep apart), so the gait is
# compared by its mean: measured 59.3 (JAX) vs 54.3 N (Warp) on these tiles, 60.5 vs 62.5 N on the plane.
WEIGHT_N, REST_FORCE_TOL, GAIT_FORCE_TOL = 58.9, 1.0, 8.0


def _gait(steps: int, envs: int) -> jax.Array:
    """A crawl-like action sequence: each unit's pair in antiphase, one period per 25 steps."""
    t = np.arange(steps)[:, None, None] * 2 * np.pi / 25
    phase = np.arange(8)[None, None, :] * np.pi / 4
    return jnp.asarray(np.broadcast_to(np.sin(t + phase), (steps, envs, 8)), jnp.float32)


def _rollout(name: str) -> dict[str, np.ndarray]:
    """Reset ENVS envs with fixed keys on backend ``name`` and play the gait; what the tests compare."""
    env = hsa_mjx.make_env("mixed", num_envs=ENVS, **{**SETTINGS, "physics.backend": name})
    state = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(3), ENVS))
    step = jax.jit(jax.vmap(env.step))
    forces = []
    for action in jnp.concatenate([jnp.zeros((REST, ENVS, 8)), _gait(STEPS, ENVS)]):
        state = step(state, action)
        forces.append(
            np.asarray(jax.vmap(lambda d: d.sensordata[env.index.foot_sensors].sum(-2))(state.pipeline_state.physics))
        )
    physics, task = state.pipeline_state.physics, state.pipeline_state.task
    blocks = np.asarray(physics.xpos[:, env.index.block_body])
    ground = np.asarray(jax.vmap(env.world.ground)(task.tile, physics.xpos[:, env.index.block_body, :2]))
    return {
        "backend": env.physics_backend,
        "qpos": np.asarray(physics.qpos),
        "blocks": blocks,
        "height": blocks[..., 2] - ground,
        "tile": np.asarray(task.tile),
        "type": np.asarray(task.terrain_id),
        "force": np.linalg.norm(np.asarray(forces), axis=-1).sum(-1),
        "done": np.asarray(state.done),
        "floor": np.asarray(physics.mocap_pos[:, env.index.terrain_mocap]),
    }


@pytest.fixture(scope="module")
def rollouts():
    return {name: _rollout(name) for name in ("jax", "warp")}


def test_auto_picks_jax_on_a_cpu_and_refuses_unknown_backends():
    assert backend.resolve("auto") == "jax" and backend.resolve("c") == "c"
    assert backend.for_one_env("auto") == "c" and backend.for_one_env("jax") == "jax"  # one env on a CPU: C MuJoCo
    with pytest.raises(
        ValueError, match=r"'physics.backend' = 'cuda' is not valid; choose one of \['auto', 'jax', 'warp', 'c'\]"
    ):
        backend.resolve("cuda")
    with pytest.raises(ValueError, match=r"physics.backend.*'cuda'.*\['auto', 'jax', 'warp', 'c'\]"):
        hsa_mjx.build_config("flat", physics__backend="cuda")


def test_warp_without_warp_lang_says_how_to_install(monkeypatch):
    monkeypatch.setattr(backend, "warp_installed", lambda: False)
    with pytest.raises(ValueError, match=r"warp-lang.*pip install -e \"\.\[warp\]\""):
        hsa_mjx.make_env("flat", physics__backend="warp")


def test_importing_the_package_and_its_entry_points_without_warp_prints_nothing():
    """No "Failed to import warp" lines where warp-lang is missing (hidden here) and Brax imports MJX
    (with warp-lang installed: tests/test_quiet_import.py)."""
    modules = (
        "hsa_mjx.task.types, hsa_mjx.task.env, hsa_mjx.batch.auto_reset, hsa_mjx.adapters.gymnasium, "
        "hsa_mjx.adapters.gymnasium_vector, train.cli, train.trainer, train.episodes.play, "
        "train.export"
    )
    script = f"import sys; sys.modules['warp'] = None\nimport {modules}"
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True)
    assert out.stdout == "" and "Failed to import" not in out.stderr, out.stdout + out.stderr


def test_one_code_path_runs_on_both_backends(rollouts):
    assert rollouts["jax"]["backend"] == "jax" and rollouts["warp"]["backend"] == "warp"
    for run in rollouts.values():
        assert np.all(np.isfinite(run["qpos"])) and not run["done"].any()


def test_warp_and_jax_give_the_same_trajectory_within_the_bound(rollouts):
    jax_run, warp_run = rollouts["jax"], rollouts["warp"]
    np.testing.assert_array_equal(jax_run["tile"], warp_run["tile"])  # same keys, same terrain draws
    assert np.abs(jax_run["qpos"] - warp_run["qpos"]).max() < QPOS_TOL
    assert np.abs(jax_run["blocks"] - warp_run["blocks"]).max() < BLOCK_TOL
    moved = np.linalg.norm(jax_run["blocks"][:, :, :2].mean(1) - warp_run["blocks"][:, :, :2].mean(1), axis=-1)
    assert moved.max() < BLOCK_TOL


def test_contact_forces_agree_between_backends(rollouts):
    """The contact-cost reward reads these sensors: the same load on the feet at rest and over the gait."""
    jax_force, warp_force = rollouts["jax"]["force"], rollouts["warp"]["force"]  # (steps, envs), summed over feet
    for force in (jax_force, warp_force):
        np.testing.assert_allclose(force[REST - 1], WEIGHT_N, atol=2 * REST_FORCE_TOL)
    assert np.abs(jax_force[REST - 1] - warp_force[REST - 1]).max() < REST_FORCE_TOL
    assert np.abs(jax_force[REST:].mean(0) - warp_force[REST:].mean(0)).max() < GAIT_FORCE_TOL


def test_every_robot_stands_on_its_own_tile_on_both_backends(rollouts):
    for run in rollouts.values():
        assert len(set(run["tile"].tolist())) >= 2  # a mixed batch
        assert np.all(np.abs(run["height"] - 0.14) < 0.02), run["height"]  # resting on its own ground
        for tile, floor in zip(run["tile"], run["floor"]):  # the floor moved under each env's own tile
            assert np.allclose(floor, run["floor"][run["tile"] == tile][0])
        assert len({tuple(np.round(f, 3)) for f in run["floor"]}) == len(set(run["tile"].tolist()))


def test_warp_batch_resets_finished_envs_and_refuses_a_larger_batch():
    env = hsa_mjx.make_env(
        "flat",
        num_envs=2,
        physics__backend="warp",
        termination__max_episode_steps=3,
        physics__integrator="implicitfast",  # the flat task's settings: Warp's kernels of the shipped-policy test
        physics__iterations=4,
        physics__ls_iterations=8,
    )
    batch = AutoResetEnv(env)
    state = jax.jit(batch.reset)(jax.random.split(jax.random.PRNGKey(0), 2))
    step = jax.jit(batch.step)
    for _ in range(4):
        state = step(state, jnp.zeros((2, 8)))
    assert np.asarray(state.totals["episodes"]) == 2  # both truncated at step 3 and were reset...
    assert np.all(np.asarray(state.env.pipeline_state.task.step_count) == 1)  # ...then stepped once more
    with pytest.raises(ValueError, match="num_envs=3"):
        batch.reset(jax.random.split(jax.random.PRNGKey(0), 3))


def test_a_shipped_policy_evaluates_on_the_warp_backend(tmp_path):
    """``--backend warp`` runs a policy trained on any backend on MuJoCo Warp (checkpoints and policy files
    hold no backend); on a CPU ``auto`` would pick C MuJoCo."""
    from train.evaluate import main

    out = tmp_path / "eval"
    args = ["--policy", "flat", "--episodes", "2", "--steps", "12", "--backend", "warp", "--out", str(out)]
    assert main(args) == 0
    result = json.loads((out / "eval.json").read_text())
    assert result["physics"] == "mjx_warp" and result["episodes"] == 2 and result["mean_episode_steps"] > 0


def test_warp_kernel_modules_are_prebuilt_once_per_device(monkeypatch):
    """The modules named for building ahead exist in the installed MuJoCo Warp (a renamed one would only
    lose the head start), and a device's modules are built once: two light ones here, on the CPU."""
    import importlib.util
    import types
    import warnings

    from hsa_mjx.sim import warp_kernels

    for module in warp_kernels.MODULES:
        assert importlib.util.find_spec(f"{warp_kernels.PACKAGE}.{module}") is not None, module
    monkeypatch.setattr(warp_kernels, "MODULES", ("support", "constraint"))
    monkeypatch.setattr(warp_kernels, "_built", set())
    cpu = jax.devices("cpu")[0]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert warp_kernels.prebuild(cpu, workers=2) > 0.0
    assert warp_kernels.prebuild(cpu) is None
    assert warp_kernels.warp_device(types.SimpleNamespace(platform="gpu", local_hardware_id=1)) == "cuda:1"


def test_warp_warm_up_steps_one_world_of_the_training_data():
    """The warm-up that builds MuJoCo Warp's per-model kernels ahead steps one env's data as a batch of one
    (Warp's shared buffers left unbatched, as a vmapped reset leaves them): it runs without a warning."""
    import warnings

    from hsa_mjx.sim import warp_kernels

    env = hsa_mjx.make_env("mixed", num_envs=ENVS, **{**SETTINGS, "physics.backend": "warp"})
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert warp_kernels.warm_up(env.robot.mjx_model, env._data0) > 0.0


def test_recorded_warp_launches_run_nothing_and_name_the_module_each_would_load():
    """A dry run's launches record (module, block size, device) and leave their outputs alone; an empty
    launch records nothing; a captured loop's body and both branches of a captured ``if`` run once each;
    on leaving, Warp's own launch is back."""
    warp = pytest.importorskip("warp")
    from hsa_mjx.sim import warp_kernels

    @warp.kernel(module="unique")
    def ones(out: warp.array(dtype=float)):
        out[warp.tid()] = 1.0

    out, calls, launch = warp.zeros(4, dtype=float, device="cpu"), [], warp.launch
    with warp_kernels.recording_launches() as launches:
        warp.launch(ones, dim=4, inputs=[out], device="cpu")
        warp.launch(ones, dim=0, inputs=[out], device="cpu")
        warp.launch_tiled(ones, dim=[2], inputs=[out], device="cpu", block_dim=64)
        warp.capture_while(None, while_body=lambda tag: calls.append(tag), tag="loop")
        warp.capture_if(None, on_true=lambda: calls.append("yes"), on_false=lambda: calls.append("no"))
    assert [(module, block, str(device)) for module, block, device in launches.values()] == [(ones.module, 1, "cpu")]
    assert calls == ["loop", "yes", "no"] and out.numpy().tolist() == [0.0] * 4 and warp.launch is launch


def test_the_warp_kernel_helper_builds_the_env_in_its_own_process_and_a_failure_is_a_warning():
    """The helper a Warp training start launches builds the env from its config and steps it once in a
    process of its own (on the CPU here), reporting its seconds; a helper that fails is a warning naming
    its exit and last output, never an error."""
    from hsa_mjx.adapters.original_args import build_config
    from hsa_mjx.config import to_dict
    from hsa_mjx.task import warp_builder

    config = to_dict(build_config("mixed", **{**SETTINGS, "physics.backend": "warp"}))
    good, bad = warp_builder.spawn(config, ENVS), warp_builder.spawn({"no_such_key": 1}, ENVS)
    report = good.wait()
    assert report["warm_up_s"] > 0.0 and report["done_s"] >= report["warm_up_s"] and report["waited_s"] >= 0.0
    assert report["modules"] >= 20  # a dry run of the step named its kernel modules (the flat task: 44 on a CPU)
    with pytest.warns(UserWarning, match="exit 1.*no_such_key"):
        assert bad.wait() is None


def test_the_warp_kernel_helper_is_done_at_its_report_not_at_its_exit():
    """The training start goes on once the helper's report line comes, while the helper still tears down;
    a JSON line that is no report does not end the wait."""
    import time

    from hsa_mjx.task import warp_builder

    script = (
        "import json, time; print(json.dumps({'other': 1}), flush=True); time.sleep(1); "
        "print(json.dumps({'warm_up_s': 2.0, 'finished_at': time.time()}), flush=True); time.sleep(60)"
    )
    process = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)
    started = time.perf_counter()
    try:
        report = warp_builder.watch(process, time.time()).wait()
        assert report["warm_up_s"] == 2.0 and 1.0 <= time.perf_counter() - started < 30.0
        assert process.poll() is None  # still running: its exit was not waited for
    finally:
        process.kill()


def test_the_warp_kernel_helper_runs_on_the_training_gpu_and_only_for_warp_on_a_gpu(monkeypatch):
    """The helper sees the training device by its CUDA ordinal, mapped through a CUDA_VISIBLE_DEVICES the
    trainer was given; nothing is launched for the JAX backend or a CPU."""
    import types

    from hsa_mjx.task import warp_builder

    gpu = types.SimpleNamespace(platform="gpu", local_hardware_id=1)
    monkeypatch.delenv("CUDA_VISIBLE_DEVICES", raising=False)
    assert warp_builder._visible_devices(gpu) == "1"
    monkeypatch.setenv("CUDA_VISIBLE_DEVICES", "4,6")
    assert warp_builder._visible_devices(gpu) == "6" and warp_builder._visible_devices(None) is None
    assert warp_builder.start({}, 1, "jax", gpu) is None
    assert warp_builder.start({}, 1, "warp", jax.devices("cpu")[0]) is None
