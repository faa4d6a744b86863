"""Trainer pieces without MJX: config checks, checkpoints, the JAX compatibility shim."""

from __future__ import annotations

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from hsa_mjx.task.observation import observation_size
from train import config as train_config
from train.devices import compat
from train.episodes import policy_sources, rollout
from train.learners.ppo.policy import NETWORK_KEYS
from train.run import checkpoint


def test_default_and_shipped_configs_validate():
    assert train_config.from_dict({}).run.num_envs == 1024
    for name in ("train_quickstart_cpu", "train_flat"):
        config = train_config.load(f"configs/{name}.yaml")
        assert config.goal_curriculum.enabled and config.env.goal.mode == "radial"
        assert train_config.from_dict(train_config.to_dict(config)) == config  # round trip
    flat = train_config.to_dict(train_config.load("configs/train_flat.yaml"))
    assert flat["env"]["observation"]["heading"]
    plain = train_config.to_dict(
        train_config.from_dict({**flat, "env": {**flat["env"], "observation": {"heading": False}}})
    )
    assert checkpoint.incompatibilities(plain, flat) == ["env.observation.heading"]  # resume refuses
    for name, goal_mode in (("train_corridor", "random"), ("train_spiral", "spiral")):
        config = train_config.validate(train_config.load(f"configs/{name}.yaml"))
        assert config.env.scene == "terrain" and config.env.goal.mode == goal_mode
        assert not config.goal_curriculum.enabled  # the curriculum needs radial goals
        assert (config.env.physics.integrator, config.env.physics.iterations) == ("implicitfast", 8)
        assert not config.env.terrain.per_env  # one shared track (exact: test_terrain_env)
    corridor = train_config.to_dict(train_config.load("configs/train_corridor.yaml"))
    rough = train_config.load("configs/train_rough.yaml")  # perception: the scan, a privileged critic, top re-draws
    assert rough.env.observation.height_scan.enabled and rough.env.observation.height_scan.noise > 0
    assert rough.ppo.privileged_critic and rough.terrain_curriculum.top_redraw
    assert not corridor["env"]["observation"].pop("height_scan")["enabled"]
    assert not any(corridor["env"]["observation"].pop("noise").values())
    assert corridor["env"]["observation"] == {
        "heading": True,
        "servo_targets": True,
        "clock_period_s": 4.0,
        "path_direction": False,
        "hinge_angles": "raw",
        "history_steps": 0,
        "velocity": "simulated",
    }
    assert corridor["env"]["control"]["servo_target_limit"] == 6.28  # the original's corridor (Loose) range
    # the corridor with perception continues the rough policy: its inputs and servo range, radial goals
    scan = train_config.validate(train_config.load("configs/train_corridor_scan.yaml"))
    assert scan.run.init_from == "rough" and scan.ppo.privileged_critic and not scan.goal_curriculum.enabled
    assert observation_size(scan.env.observation) == observation_size(rough.env.observation) == 91
    assert scan.env.control.servo_target_limit == 3141.5 and scan.env.goal.mode == "radial"
    assert (
        scan.env.terrain.types == ("corridor",)
        and scan.env.physics == train_config.load("configs/train_corridor.yaml").env.physics
    )
    # the spiral starts from a flat run's networks: the flat task's servo range and 28 observation slots
    spiral = train_config.to_dict(train_config.load("configs/train_spiral.yaml"))
    assert spiral["env"]["control"]["servo_target_limit"] == flat["env"]["control"]["servo_target_limit"] == 3141.5
    assert spiral["env"]["observation"] == {**flat["env"]["observation"], "hinge_angles": "wrapped"}
    assert observation_size(train_config.load("configs/train_spiral.yaml").env.observation) == 28
    assert all(spiral["ppo"][k] == flat["ppo"][k] for k in NETWORK_KEYS)
    assert (spiral["env"]["goal"]["num_checkpoints"], spiral["env"]["goal"]["track_starts"]) == (20, 19)
    assert all(spiral["ppo"][k] == corridor["ppo"][k] for k in spiral["ppo"])  # the track tasks' PPO settings
    # evaluation defaults to the goals each was trained on
    assert policy_sources.default_goal_range(train_config.load("configs/train_flat.yaml")) == (1.5, 4.5)
    turn = train_config.from_dict({"env": {"goal": {"radial_range": [0.8, 1.2]}}, "curriculum": {"enabled": False}})
    assert policy_sources.default_goal_range(turn) == (0.8, 1.2)


def test_training_configs_use_the_guarded_physics():
    """Training physics = the fidelity guard's shipped setting for the scene (benchmarks/fidelity/guard.py)."""
    from benchmarks.fidelity.guard import SETTINGS, SHIPPED_BY_SCENE

    for name in ("train_flat", "train_quickstart_cpu", "train_corridor", "train_corridor_scan", "train_spiral"):
        physics = train_config.load(f"configs/{name}.yaml").env.physics
        shipped = SETTINGS[SHIPPED_BY_SCENE["terrain" if "corridor" in name or "spiral" in name else "flat"]]
        assert {k: getattr(physics, k.split(".")[1]) for k in shipped} == shipped, name


@pytest.mark.parametrize(
    "data, match",
    [
        ({"trainer": {}}, "unknown config section"),
        ({"ppo": {"learning_rat": 1e-3}}, r"unknown config key.*learning_rate"),
        ({"ppo": {"activation": "gelu"}}, "activation"),
        ({"ppo": {"distribution_type": "beta"}}, r"ppo.distribution_type.*'tanh_normal', 'normal'"),
        ({"ppo": {"noise_std_type": "exp"}}, r"ppo.noise_std_type.*'scalar', 'log'"),
        ({"run": {"num_envs": "many"}}, "run.num_envs"),
        ({"run": {"num_envs": 3}}, "multiple of run.num_envs"),
        ({"env": {"goal": {"mode": "random"}}}, "goal.mode 'radial'"),
        ({"env": {"preset": "nope"}}, "unknown preset"),
        ({"curriculum": {"window_size": 0}}, "window_size"),
        ({"randomization_curriculum": {"enabled": True}}, "randomization_curriculum.enabled needs ranges to widen"),
        ({"randomization_curriculum": {"start": 1.5}}, r"randomization_curriculum.start must be in \[0, 1\]"),
        ({"ppo": {"observation_clip": -1}}, r"ppo.observation_clip.*>= 0"),
        ({"run": {"init_normalizer_count": -5}}, r"run.init_normalizer_count.*>= 0"),
        ({"ppo": {"learning_rate": -0.001}}, r"ppo.learning_rate' = -0.001 is out of range.*\[0.0, inf\)"),
        ({"ppo": {"discounting": 1.5}}, r"ppo.discounting' = 1.5 .*\(0.0, 1.0\]"),
        ({"ppo": {"clipping_epsilon": -0.2}}, r"ppo.clipping_epsilon' = -0.2"),
        ({"ppo": {"gae_lambda": 7}}, r"ppo.gae_lambda' = 7.0 .*\[0.0, 1.0\]"),
        ({"ppo": {"entropy_cost": float("nan")}}, r"ppo.entropy_cost' = nan"),
        ({"run": {"seed": -5}}, r"run.seed' = -5 .*\[0, 4294967295\]"),
    ],
)
def test_bad_config_is_named(data, match):
    with pytest.raises(ValueError, match=match):
        train_config.from_dict(data)


def test_device_split_checked():
    config = train_config.from_dict({"run": {"num_envs": 1024}, "ppo": {"batch_size": 256}})
    with pytest.raises(ValueError, match="divisible by the 3 devices"):
        train_config.validate_devices(config, 3)
    assert train_config.validate_devices(config, 2) is config
    one = train_config.from_dict({"run": {"collection": "one_device"}})
    with pytest.raises(ValueError, match="one_device runs on one device, but 2"):
        train_config.validate_devices(one, 2)


def test_set_overrides():
    given = {"ppo": {"learning_rate": 1.0}, "env": {"reward": {"forward": 6.0}}}
    data = train_config.apply_overrides(given, ["ppo.learning_rate=2e-4", "env.reward.forward=3", "run.seed=7"])
    assert given == {"ppo": {"learning_rate": 1.0}, "env": {"reward": {"forward": 6.0}}}  # the caller's data kept
    config = train_config.from_dict(data)
    assert config.ppo.learning_rate == pytest.approx(2e-4)
    assert config.env.reward.forward == 3.0 and config.run.seed == 7
    with pytest.raises(ValueError, match="section.key=value"):
        train_config.apply_overrides({}, ["ppo.learning_rate"])
    with pytest.raises(ValueError, match="must start with one of"):
        train_config.apply_overrides({}, ["learning_rate=1"])
    with pytest.raises(ValueError, match="unknown config key"):
        train_config.from_dict(train_config.apply_overrides({}, ["run.epochs=3"]))


def test_missing_config_file():
    with pytest.raises(FileNotFoundError, match="training config not found"):
        train_config.load("configs/does_not_exist.yaml")


def _payload(scale: float = 1.0):
    return {
        "w": jnp.arange(6.0).reshape(2, 3) * scale,
        "inner": {"n": jnp.asarray(3, jnp.int32)},
        "rng": jax.random.PRNGKey(5),
    }


def test_checkpoint_round_trip_prune_and_no_temp_left(tmp_path):
    for step in (10, 20, 30, 40):
        checkpoint.save(tmp_path, step, _payload(step), {"env": {"a": 1}}, keep=2)
    names = [p.name for p in checkpoint.list_checkpoints(tmp_path)]
    assert names == ["step_000000000030", "step_000000000040"]
    assert not [p for p in checkpoint.checkpoint_dir(tmp_path).iterdir() if p.name.startswith(".tmp")]
    latest = checkpoint.latest(tmp_path)
    restored = checkpoint.load(latest, _payload())
    np.testing.assert_allclose(restored["w"], np.arange(6.0).reshape(2, 3) * 40)
    assert int(restored["inner"]["n"]) == 3
    assert checkpoint.read_meta(latest)["step"] == 40
    # a hard stop (second Ctrl-C) names the checkpoint --resume continues from, or says there is none
    from train.cli import interrupted_message

    assert interrupted_message(tmp_path).endswith("continues from " + str(latest))
    assert "before any checkpoint" in interrupted_message(tmp_path / "nothing")


def test_stop_flag_takes_a_forwarded_duplicate_as_one_request_and_a_later_one_as_hard_stop():
    import os
    import signal

    from train.trainer import StopFlag

    with StopFlag(repeat_s=60.0) as stop:
        os.kill(os.getpid(), signal.SIGTERM)
        os.kill(os.getpid(), signal.SIGTERM)  # e.g. pkill reaching both `timeout` and its child
        assert stop.raised
    with StopFlag(repeat_s=0.0) as stop:
        os.kill(os.getpid(), signal.SIGINT)
        with pytest.raises(KeyboardInterrupt):
            os.kill(os.getpid(), signal.SIGINT)
    assert signal.getsignal(signal.SIGTERM) != stop.handle  # handlers restored


def test_corrupt_and_missing_checkpoints_are_named(tmp_path):
    with pytest.raises(FileNotFoundError, match="no checkpoint found"):
        checkpoint.latest(tmp_path)
    path = checkpoint.save(tmp_path, 1, _payload(), {"env": {}})
    (path / checkpoint.STATE_FILE).write_bytes(b"\x00garbage\xff" * 10)
    with pytest.raises(ValueError, match="corrupt"):
        checkpoint.load(path, _payload())
    (path / checkpoint.META_FILE).write_text("{not json")
    with pytest.raises(ValueError, match="corrupt"):
        checkpoint.read_meta(path)


def test_checkpoint_of_other_shape_refused(tmp_path):
    path = checkpoint.save(tmp_path, 1, _payload(), {"env": {}})
    other = dict(_payload(), w=jnp.zeros((3, 3)))
    with pytest.raises(ValueError, match="does not match"):
        checkpoint.load(path, other)


def test_incompatibilities():
    saved = json.loads(json.dumps(train_config.to_dict(train_config.from_dict({}))))
    same = train_config.to_dict(train_config.from_dict({"run": {"num_timesteps": 5}, "ppo": {"learning_rate": 1e-5}}))
    assert checkpoint.incompatibilities(saved, json.loads(json.dumps(same))) == []
    other = train_config.to_dict(
        train_config.from_dict({"env": {"reward": {"forward": 1.0}}, "ppo": {"policy_hidden_sizes": [8]}})
    )
    assert checkpoint.incompatibilities(saved, json.loads(json.dumps(other))) == [
        "env.reward.forward",
        "ppo.policy_hidden_sizes",
    ]


def test_compat_shim_replicates_onto_devices(monkeypatch):
    monkeypatch.delattr(jax, "device_put_replicated", raising=False)
    assert compat.install() is True
    devices = jax.local_devices()
    out = jax.device_put_replicated({"a": jnp.ones((2, 3)), "b": jnp.asarray(4)}, devices)
    assert out["a"].shape == (len(devices), 2, 3) and out["b"].shape == (len(devices),)
    assert set(out["a"].devices()) == set(devices)
    assert compat.install() is False  # already present: nothing replaced
    summed = jax.pmap(lambda t: t["a"].sum() + t["b"])(out)
    np.testing.assert_allclose(summed, [10.0] * len(devices))


def test_incompatibilities_keys_added_later_match_their_default():
    """A checkpoint written before a config key existed resumes when that key keeps its default."""
    defaults = json.loads(json.dumps(train_config.to_dict(train_config.from_dict({}))))
    saved = json.loads(json.dumps(defaults))
    del saved["env"]["termination"]["qacc_every_substep"]
    assert checkpoint.incompatibilities(saved, defaults, defaults) == []
    changed = train_config.to_dict(train_config.from_dict({"env": {"termination": {"qacc_every_substep": True}}}))
    assert checkpoint.incompatibilities(saved, json.loads(json.dumps(changed)), defaults) == [
        "env.termination.qacc_every_substep"
    ]
    assert checkpoint.incompatibilities(saved, defaults) == ["env.termination.qacc_every_substep"]
    without_section = json.loads(json.dumps(defaults))
    del without_section["env"]["observation"]  # written before the observation section existed
    assert checkpoint.incompatibilities(without_section, defaults, defaults) == []
    heading = json.loads(
        json.dumps(train_config.to_dict(train_config.from_dict({"env": {"observation": {"heading": True}}})))
    )
    assert checkpoint.incompatibilities(without_section, heading, defaults) == ["env.observation"]
    older = json.loads(json.dumps(defaults))
    del older["ppo"]["distribution_type"], older["ppo"]["noise_std_type"]  # written before these keys
    assert checkpoint.incompatibilities(older, defaults, defaults) == []
    normal = json.loads(
        json.dumps(train_config.to_dict(train_config.from_dict({"ppo": {"distribution_type": "normal"}})))
    )
    assert checkpoint.incompatibilities(older, normal, defaults) == ["ppo.distribution_type"]


def test_unsquashed_policy_with_log_std_samples_beyond_one():
    """distribution_type normal + noise_std_type log: SB3-like exploration (the env clips to [-1, 1])."""
    from brax.training.agents.ppo import networks as ppo_networks

    from train.learners.ppo.networks import init_training_state, make_networks

    config = train_config.from_dict(
        {
            "ppo": {
                "distribution_type": "normal",
                "noise_std_type": "log",
                "init_noise_std": 3.0,
                "policy_hidden_sizes": [8],
                "value_hidden_sizes": [8],
            }
        }
    )
    networks = make_networks(config, 5, 2)
    ts = init_training_state(config, networks, jax.random.PRNGKey(0), 5)
    policy = ppo_networks.make_inference_fn(networks)((ts.normalizer, ts.params.policy), deterministic=False)
    keys = jax.random.split(jax.random.PRNGKey(1), 256)
    actions, _ = jax.vmap(lambda k: policy(jnp.zeros(5), k))(keys)
    assert float(jnp.std(actions)) == pytest.approx(3.0, rel=0.2) and float(jnp.max(jnp.abs(actions))) > 1.0
    squashed = train_config.from_dict(
        {"ppo": {"policy_hidden_sizes": [8], "value_hidden_sizes": [8], "init_noise_std": 3.0}}
    )
    nets = make_networks(squashed, 5, 2)
    ts2 = init_training_state(squashed, nets, jax.random.PRNGKey(0), 5)
    pol2 = ppo_networks.make_inference_fn(nets)((ts2.normalizer, ts2.params.policy), deterministic=False)
    assert float(jnp.max(jnp.abs(jax.vmap(lambda k: pol2(jnp.zeros(5), k))(keys)[0]))) <= 1.0


def test_observation_clip_bounds_what_the_networks_see():
    """ppo.observation_clip: a feature far outside its statistics reaches the networks clipped (0: unclipped)."""
    from train.learners.ppo.networks import init_training_state, make_networks

    def values(clip: float) -> np.ndarray:
        config = train_config.from_dict(
            {"ppo": {"observation_clip": clip, "policy_hidden_sizes": [8], "value_hidden_sizes": [8]}}
        )
        networks = make_networks(config, 3, 2)
        ts = init_training_state(config, networks, jax.random.PRNGKey(0), 3)
        obs = jnp.array([[10.0, 0.0, 0.0], [1e6, 0.0, 0.0], [-1e6, 0.0, 0.0], [-10.0, 0.0, 0.0]])  # mean 0, std 1
        return np.asarray(networks.value_network.apply(ts.normalizer, ts.params.value, obs))

    clipped, raw = values(10.0), values(0.0)
    np.testing.assert_allclose(clipped[1], clipped[0], rtol=1e-6)  # 1e6 std away = 10 std away
    np.testing.assert_allclose(clipped[2], clipped[3], rtol=1e-6)
    np.testing.assert_allclose(raw[0], clipped[0], rtol=1e-6)  # within the clip nothing changes
    assert abs(raw[1] - raw[0]) > 1e3 * max(abs(clipped[1] - clipped[0]), 1e-6)


def test_collection_option_is_checked_resolved_and_its_old_name_mapped():
    import jax

    from train.devices.strategies import resolve_collection

    with pytest.raises(ValueError, match=r"run.collection.*'one_device', 'pmap', 'thread_per_device'"):
        train_config.from_dict({"run": {"collection": "shard_map"}})
    with pytest.raises(ValueError, match=r"run.multi_device.*'auto', 'pmap', 'per_device'"):
        train_config.from_dict({"run": {"multi_device": "shard_map"}})
    cpu = jax.devices("cpu")[:1]

    class FakeGpu:
        platform = "gpu"

    for mode, devices, expected in (
        ("auto", cpu, "one_device"),
        ("auto", [FakeGpu()], "one_device"),
        ("auto", [FakeGpu(), FakeGpu()], "thread_per_device"),
        ("auto", cpu * 2, "pmap"),
        ("thread_per_device", cpu, "thread_per_device"),
        ("pmap", [FakeGpu(), FakeGpu()], "pmap"),
    ):
        config = train_config.from_dict({"run": {"collection": mode}})
        assert resolve_collection(config, devices) == expected, (mode, len(devices))
    for old, new in (("per_device", "thread_per_device"), ("pmap", "pmap"), ("auto", "auto")):  # older configs
        assert train_config.from_dict({"run": {"multi_device": old}}).run.collection == new


def test_restart_count_keeps_mean_and_std_and_lets_new_data_move_them():
    from brax.training.acme import running_statistics as rs

    from train.learners.ppo.policy import restart_count

    old = rs.init_state(jnp.zeros(3))
    old = rs.update(old, jax.random.normal(jax.random.PRNGKey(0), (100_000, 3)) * jnp.array([1.0, 0.1, 2.0]))
    fresh = restart_count(old, 1_000)
    np.testing.assert_allclose(fresh.mean, old.mean)
    np.testing.assert_allclose(fresh.std, old.std)
    np.testing.assert_allclose(
        rs.update(fresh, jnp.zeros((1, 3))).std, rs.update(old, jnp.zeros((1, 3))).std, rtol=2e-3
    )
    shifted = jnp.full((1_000, 3), 5.0)  # a new task's observations
    assert float(rs.update(fresh, shifted).mean[0]) == pytest.approx(2.5, abs=0.05)  # half-way after as many samples
    assert float(rs.update(old, shifted).mean[0]) < 0.1
    assert restart_count(old, 10**9) is old  # never more samples than it had


def test_terrain_evaluation_counts_how_episodes_ended():
    from hsa_mjx.task import termination
    from train.episodes import terrain_eval

    reasons = np.zeros((4, len(termination.REASONS)), bool)
    reasons[0, termination.REASONS.index("goal_reached")] = reasons[1, termination.REASONS.index("goal_reached")] = True
    reasons[2, termination.REASONS.index("qacc_limit")] = True  # episode 3 ran out of steps
    assert terrain_eval.ended_by(reasons) == {"qacc_limit": 0.25, "goal_reached": 0.5, "time_out": 0.25}


def test_evaluation_summary_counts_spiral_checkpoints_per_episode():
    """Three hand-made spiral episodes: 2 checkpoints and a time-out, 5 then qacc_limit, 0 and a time-out."""
    from hsa_mjx.task import termination

    episodes, steps, dt = 3, 4, 0.02
    alive = np.array([[1, 1, 1, 1], [1, 1, 0, 0], [1, 1, 1, 1]], float)
    checkpoint_index = np.array([[0, 1, 2, 2], [3, 5, 0, 0], [0, 0, 0, 0]], float)  # episode 2 reset after its end
    reasons = np.zeros((episodes, steps, len(termination.REASONS)))
    reasons[1, 1, termination.REASONS.index("qacc_limit")] = 1.0
    done = np.zeros((episodes, steps))
    done[1, 1] = 1.0
    traces = {
        "alive": alive,
        "checkpoint": checkpoint_index,
        "reasons": reasons,
        "done": done,
        "xy": np.zeros((episodes, steps, 2)),
        "start_xy": np.zeros((episodes, 2)),
        "distance": np.ones((episodes, steps)),
        "start_distance": np.ones(episodes),
        "success": np.zeros((episodes, steps)),
    }
    result = rollout.summarize(traces, dt, checkpoints=True)
    assert result["checkpoints_per_episode"] == [2, 5, 0]  # read at each episode's own last step
    assert result["mean_checkpoints_collected"] == pytest.approx(7 / 3)
    # checkpoint 1: episode 0 at its 2nd step, episode 1 (which holds 3 at its first) at its 1st
    assert result["checkpoint_timeline"][:3] == [
        {"checkpoint": 1, "episodes": 2, "mean_step": 1.5},
        {"checkpoint": 2, "episodes": 2, "mean_step": 2.0},
        {"checkpoint": 3, "episodes": 1, "mean_step": 1.0},
    ]
    assert [row["episodes"] for row in result["checkpoint_timeline"]] == [2, 2, 1, 1, 1]
    assert result["termination/qacc_limit"] == pytest.approx(1 / 3) and result["not_finished"] == pytest.approx(2 / 3)
    assert result["termination/simulator_health"] == pytest.approx(1 / 3)  # the two kinds apart (0: not listed)
    assert "termination/task_failure" not in result
    assert "checkpoints_per_episode" not in rollout.summarize(traces, dt)  # goals without checkpoints
    json.dumps(result)  # eval.json stays plain JSON
    done[2, 3] = 1.0  # episode 3 truncated at the env's limit: done, but by no termination reason
    ended = rollout.summarize(traces, dt)
    assert ended["time_out"] == pytest.approx(1 / 3) and ended["not_finished"] == pytest.approx(1 / 3)


def test_evaluation_summary_gives_success_by_the_goals_bearing_from_the_robots_axis():
    """Goals ahead, behind (either end of the axis counts), at 45 degrees and beside: the near-axis ones reached."""
    goals = np.array([[1.0, 0.0], [-1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    traces = {"goal": goals[:, None, :], "start_xy": np.zeros((4, 2)), "start_heading": np.tile([1.0, 0.0], (4, 1))}
    success = np.array([True, True, False, False])
    assert rollout.by_goal_bearing(traces, success) == {"0-30": 1.0, "30-60": 0.0, "60-90": 0.0}
    near = {name: value[:2] for name, value in traces.items()}
    assert rollout.by_goal_bearing(near, success[:2])["60-90"] is None  # no episode there


def test_init_from_a_shipped_policy_starts_with_its_actions_and_a_fresh_critic():
    """--init-from flat (the CPU quickstart's start): the policy network and normaliser come from the
    policy file, so the run's first deterministic actions are the file's; a mismatch is named."""
    from brax.training.agents.ppo import networks as ppo_networks

    from hsa_mjx.deploy import policy_file
    from train.learners.ppo.networks import init_training_state, make_networks
    from train.run.warm_start import read_init_from, warm_start

    config = train_config.load("configs/train_quickstart_cpu.yaml")
    init = read_init_from(config)
    assert init["path"].name == "flat" and init["step"] > 60_000_000 and "policy" in init
    networks = make_networks(config, 28, 8)
    fresh = init_training_state(config, networks, jax.random.PRNGKey(0), 28)
    ts = warm_start(config, fresh, init)
    shipped = policy_file.load_policy("policies/flat")
    obs = (
        shipped.params["obs_mean"] + shipped.params["obs_std"] * np.random.default_rng(0).normal(size=(16, 28))
    ).astype(np.float32)
    act = ppo_networks.make_inference_fn(networks)((ts.normalizer, ts.params.policy), deterministic=True)
    np.testing.assert_allclose(np.asarray(act(jnp.asarray(obs), jax.random.PRNGKey(2))[0]), shipped(obs), atol=1e-5)
    assert jax.tree.all(jax.tree.map(np.array_equal, ts.params.value, fresh.params.value))  # the critic is new
    smaller = train_config.from_dict(
        train_config.apply_overrides(train_config.to_dict(config), ["ppo.policy_hidden_sizes=[32, 32]"])
    )
    with pytest.raises(ValueError, match=r"policy in .*flat does not fit.*ppo.policy_hidden_sizes"):
        read_init_from(smaller)


def test_a_policy_file_starts_a_run_with_a_history_as_the_file_acts():
    """A history added after the file's observation: the new inputs start at zero weight, so the first
    actions are the file's whatever the history holds; a changed observation is still refused."""
    from brax.training.agents.ppo import networks as ppo_networks

    from hsa_mjx.deploy import policy_file
    from train.learners.ppo.networks import init_training_state, make_networks
    from train.run.warm_start import read_init_from, warm_start

    config = train_config.load("configs/train_quickstart_cpu.yaml", ["env.observation.history_steps=2"])
    size = observation_size(config.env.observation)
    assert size == 28 + 2 * (28 + 8)
    networks = make_networks(config, size, 8)
    ts = warm_start(config, init_training_state(config, networks, jax.random.PRNGKey(0), size), read_init_from(config))
    shipped = policy_file.load_policy("policies/flat")
    rng = np.random.default_rng(0)
    now = (shipped.params["obs_mean"] + shipped.params["obs_std"] * rng.normal(size=(16, 28))).astype(np.float32)
    obs = np.concatenate([now, rng.normal(size=(16, size - 28)).astype(np.float32)], axis=1)
    act = ppo_networks.make_inference_fn(networks)((ts.normalizer, ts.params.policy), deterministic=True)
    np.testing.assert_allclose(np.asarray(act(jnp.asarray(obs), jax.random.PRNGKey(2))[0]), shipped(now), atol=1e-5)
    clock = train_config.load("configs/train_quickstart_cpu.yaml", ["env.observation.clock_period_s=2.0"])
    with pytest.raises(ValueError, match="observation size"):
        read_init_from(clock)


def test_learner_refuses_an_env_built_for_another_batch():
    """The env is sized for the batch a device steps in one place (strategies.build); another size is refused."""
    from hsa_mjx.task.env import HSAEnv
    from train.devices import strategies
    from train.learners.ppo.learner import PPOLearner

    config = train_config.from_dict({"run": {"num_envs": 8}, "ppo": {"batch_size": 8, "num_minibatches": 1}})
    devices = jax.local_devices()[:1]
    strategy = strategies.build(config, devices)
    assert strategy.name == "one_device" and strategy.learner.env.num_envs == 8 and strategy.learner.axis is None
    with pytest.raises(ValueError, match="built for batches of 1.*steps 8 envs"):
        strategies.OneDevice(PPOLearner(config, HSAEnv(config.env), axis=None), devices)
    with pytest.raises(ValueError, match="without a device axis"):
        strategies.OneDevice(strategy.learner.__class__(config, strategy.learner.env), devices)


def test_goal_curriculum_starts_from_the_env_goal_range():
    """One key for the start range (env.goal.radial_range); an older config's curriculum.initial_range maps onto it."""
    from hsa_mjx.curricula import goal_curriculum

    near = {"dead_zone_radius": 0.5}
    config = train_config.from_dict({"env": {"goal": {"radial_range": [0.6, 0.9]}}, "goal_curriculum": near})
    assert not hasattr(config.goal_curriculum, "initial_range")  # one key: the env's
    start = tuple(config.env.goal.radial_range)
    assert float(goal_curriculum.init(config.goal_curriculum, start).max_distance) == pytest.approx(0.9)
    old = train_config.from_dict({"curriculum": {**near, "initial_range": [0.7, 1.0]}})  # older keys
    assert old.env.goal.radial_range == (0.7, 1.0) and old.goal_curriculum == config.goal_curriculum
    with pytest.raises(ValueError, match="differs from env.goal.radial_range"):
        train_config.from_dict(
            {"env": {"goal": {"radial_range": [0.6, 0.9]}}, "curriculum": {**near, "initial_range": [0.7, 1.0]}}
        )
    off = train_config.from_dict(
        {"curriculum": {"enabled": False, "initial_range": [0.7, 1.0]}}
    )  # had no effect: dropped
    assert off.env.goal.radial_range == (1.5, 1.8)
    assert train_config.from_dict(train_config.to_dict(old)) == old  # a saved config reloads


def test_progress_counts_to_the_last_whole_epoch():
    import io

    from train.run.logger import ProgressBar
    from train.trainer import final_step

    assert final_step(0, 1600, 640) == 1920  # whole epochs: 3 of 640 steps pass 1,600
    assert final_step(1280, 1600, 640) == 1920 and final_step(1920, 1600, 640) == 1920  # resumed, or already done
    assert final_step(0, 1280, 640) == 1280
    bar = ProgressBar(final_step(0, 1600, 640), stream=io.StringIO())
    bar.update(640, {})
    assert bar.update(1920, {}).split(" | ")[0].endswith("1,920/1,920 100.0%")
    assert "ETA 0:00:00" in bar.update(1920, {})  # never a negative ETA at the end


def test_health_and_task_failures_are_grouped_apart():
    from hsa_mjx.task import termination

    assert set(termination.GROUPS["simulator_health"]) | set(termination.GROUPS["task_failure"]) == set(
        termination.FAILURE_REASONS
    )
    assert not set(termination.GROUPS["simulator_health"]) & set(termination.GROUPS["task_failure"])
    reasons = {name: jnp.asarray(name == "out_of_bounds") for name in termination.FAILURE_REASONS}
    assert {k: bool(v) for k, v in termination.grouped(reasons).items()} == {
        "simulator_health": False,
        "task_failure": True,
    }


def test_result_files_record_no_absolute_paths(tmp_path, monkeypatch):
    from pathlib import Path

    from train.run.folder import portable

    monkeypatch.chdir(tmp_path)
    assert portable(tmp_path / "runs" / "flat" / "checkpoints") == "runs/flat/checkpoints"
    assert portable(Path("runs/flat")) == "runs/flat"
    assert portable(tmp_path.parent / "elsewhere" / "rough") == "rough"  # outside: its name
    assert portable(tmp_path / "r" / "checkpoints" / "step_1", tmp_path / "r") == "checkpoints/step_1"


def test_host_workers_cut_episodes_into_ordered_shards_and_refuse_where_they_cannot_help():
    """``--workers``: keys cut in order and the traces joined back in it; asked off C MuJoCo or per terrain,
    a ValueError naming the fix (before anything loads)."""
    from train.episodes import host_workers
    from train.episodes.play import EvalSpec, check_workers

    keys = np.arange(10).reshape(5, 2)
    parts = host_workers.shards(keys, 3)
    assert [len(p) for p in parts] == [2, 2, 1] and len(host_workers.shards(keys[:2], 8)) == 2
    traces = host_workers.joined([{"k": p[:, 0], "t": p[:, None, :]} for p in parts])
    np.testing.assert_array_equal(traces["k"], keys[:, 0])
    assert traces["t"].shape == (5, 1, 2)
    with pytest.raises(ValueError, match="--backend c"):
        check_workers(EvalSpec(policy="flat", workers=2, backend="jax"))
    with pytest.raises(ValueError, match="terrain"):
        check_workers(EvalSpec(policy="flat", workers=2, backend="c", levels=(0.0, 1.0)))
    with pytest.raises(ValueError, match=">= 1"):
        check_workers(EvalSpec(policy="flat", workers=0))
