"""TD3 (run.learner: td3): n-step samples, the C51 projection, learning a toy task from scratch (a
flipped actor update cannot), a tiny run on the robot that resumes, exports and deploys."""

from __future__ import annotations

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import TINY_RUN

from hsa_mjx.deploy import policy_file
from hsa_mjx.deploy.__main__ import main as deploy
from train import config as train_config
from train import export
from train.config.td3 import TD3Config
from train.learners.td3 import replay
from train.learners.td3.networks import act, init_state, make_networks
from train.learners.td3.update import TD3Update, project
from train.run import checkpoint

TINY_TD3 = {"actor_hidden_sizes": [8], "critic_hidden_sizes": [8], "batch_size": 8, "buffer_size": 64}


def tiny(**run) -> train_config.TrainConfig:
    data = json.loads(json.dumps(TINY_RUN))
    data["run"].update(learner="td3", **run)
    data["td3"] = dict(TINY_TD3, num_atoms=11, learning_starts=3)
    return train_config.from_dict(data)


def row(obs, reward, ended, terminal):
    f = jnp.asarray
    return replay.Transition(f(obs), f([[0.0]]), f(reward), f(obs) + 100.0, f(ended), f(terminal))


def test_an_n_step_sample_sums_rewards_to_the_episodes_end_and_bootstraps_there():
    steps = [  # one env: (obs, reward, ended, terminal); the episode ends by termination at step 2, truncated at 4
        (0.0, 1.0, 0.0, 0.0),
        (1.0, 2.0, 0.0, 0.0),
        (2.0, 4.0, 1.0, 1.0),
        (3.0, 8.0, 0.0, 0.0),
        (4.0, 16.0, 1.0, 0.0),
    ]
    buffer = replay.init(8, row([[0.0]], [0.0], [0.0], [0.0]))
    for obs, r, e, t in steps:
        buffer = replay.add(buffer, row([[obs]], [r], [e], [t]))
    got = {}
    for seed in range(40):  # every start row of the 3 windows the buffer holds whole
        s = replay.sample(buffer, jax.random.PRNGKey(seed), 4, 3, 0.5)
        for i in range(4):
            got[float(s.obs[i, 0])] = (float(s.reward[i]), float(s.next_obs[i, 0]), float(s.discount[i]))
    assert got == {
        0.0: (1 + 0.5 * 2 + 0.25 * 4, 102.0, 0.0),  # three steps, the last one terminal: no bootstrap
        1.0: (2 + 0.5 * 4, 102.0, 0.0),  # cut at the termination
        2.0: (4.0, 102.0, 0.0),
    }
    buffer = replay.add(buffer, row([[5.0]], [32.0], [0.0], [0.0]))
    buffer = replay.add(buffer, row([[6.0]], [64.0], [0.0], [0.0]))
    buffer = replay.end_newest(replay.end_newest(buffer, jnp.array([False])), jnp.array([True]))  # a re-draw cut
    assert buffer.rows.ended[:, 0].tolist() == [0, 0, 1, 0, 1, 0, 1, 0]  # the newest row (6) ended, no other
    s = replay.sample(buffer, jax.random.PRNGKey(0), 64, 3, 0.5)
    truncated = np.asarray(s.obs[:, 0]) == 3.0
    assert truncated.any()  # a truncation ends the sum but bootstraps from its own next input
    np.testing.assert_allclose(s.reward[truncated], 8 + 0.5 * 16)
    np.testing.assert_allclose(s.next_obs[truncated, 0], 104.0)
    np.testing.assert_allclose(s.discount[truncated], 0.25)


def test_the_projection_keeps_the_mass_and_moves_the_mean():
    support = jnp.linspace(-10.0, 10.0, 21)
    probs = jax.nn.softmax(jax.random.normal(jax.random.PRNGKey(0), (5, 21)))
    reward, discount = jnp.array([0.3, -1.7, 2.0, 0.0, 9.0]), jnp.array([0.9, 0.5, 0.8, 0.0, 0.9])
    target = project(support, probs, reward, discount)
    np.testing.assert_allclose(target.sum(-1), 1.0, atol=1e-6)
    want = reward + discount * (probs @ support)
    inside = np.array([True, True, True, True, False])  # the last moves atoms past v_max: clipped
    np.testing.assert_allclose((target @ support)[inside], want[inside], atol=1e-5)


ENVS, HORIZON = 32, 10


def toy_return(flip: bool) -> float:
    """A point on a line learns to move to 0 (reward -|x|, 10 steps, starts in [-1, 1]): TD3's actor and
    critics, buffer and update from scratch, 300 env steps of 32 envs; the deterministic return after.
    A random actor scores about -5, the best about -0.5."""
    td3 = TD3Config(
        actor_hidden_sizes=(32, 32),
        critic_hidden_sizes=(64, 64),
        batch_size=256,
        buffer_size=ENVS * 200,
        num_atoms=51,
        v_min=-10.0,
        v_max=1.0,
        weight_decay=0.0,
        discounting=0.9,
        actor_learning_rate=1e-3,
        critic_learning_rate=1e-3,
        tau=0.05,
    )
    net = make_networks(td3, 2, 1)
    update = TD3Update(net, td3, None)
    if flip:  # a broken update: the actor descends the critics' value
        loss = update.actor_loss
        update.actor_loss = lambda actor, state, batch: -loss(actor, state, batch)

    def observe(x, t):
        return jnp.stack([x, t / HORIZON], -1)

    def move(ts, x, t):
        x = jnp.clip(x + 0.25 * act(net, ts.params.actor, ts.normalizer, observe(x, t))[:, 0], -2.0, 2.0)
        return x, -jnp.abs(x)

    @jax.jit
    def iteration(ts, buffer, x, t, key):
        k_noise, k_reset, k_update = jax.random.split(key, 3)
        obs = observe(x, t)
        action = jnp.clip(
            act(net, ts.params.actor, ts.normalizer, obs) + 0.3 * jax.random.normal(k_noise, (ENVS, 1)), -1, 1
        )
        x2 = jnp.clip(x + 0.25 * action[:, 0], -2.0, 2.0)
        end = (t + 1 >= HORIZON).astype(jnp.float32)
        step = replay.Transition(obs, action, -jnp.abs(x2), observe(x2, t + 1), end, jnp.zeros_like(end))
        buffer = replay.add(buffer, step)
        for k in jax.random.split(k_update, 2):
            k_sample, k_step = jax.random.split(k)
            ts = update.step(ts, replay.sample(buffer, k_sample, 256, td3.n_step, td3.discounting), k_step)[0]
        fresh = jax.random.uniform(k_reset, (ENVS,), minval=-1.0, maxval=1.0)
        return ts, buffer, jnp.where(end > 0, fresh, x2), jnp.where(end > 0, 0, t + 1)

    key = jax.random.PRNGKey(0)
    ts = init_state(td3, net, key, 2)
    zeros = jnp.zeros(ENVS)
    buffer = replay.init(
        200, replay.Transition(observe(zeros, zeros), zeros[:, None], zeros, observe(zeros, zeros), zeros, zeros)
    )
    x, t = jax.random.uniform(key, (ENVS,), minval=-1.0, maxval=1.0), jnp.zeros(ENVS, jnp.int32)
    for i in range(300):
        if i < td3.n_step:  # the first updates need n steps in the buffer: the actor explores until then
            buffer = replay.add(
                buffer, replay.Transition(observe(x, t), zeros[:, None], -jnp.abs(x), observe(x, t + 1), zeros, zeros)
            )
            t = t + 1
            continue
        ts, buffer, x, t = iteration(ts, buffer, x, t, jax.random.fold_in(key, i))
    start = jnp.linspace(-1.0, 1.0, 64)
    _, rewards = jax.lax.scan(lambda x, t: move(ts, x, jnp.full_like(x, t)), start, jnp.arange(HORIZON))
    return float(rewards.sum(0).mean())


def test_td3_learns_a_toy_task_from_scratch_and_a_flipped_update_does_not():
    assert toy_return(flip=False) > -1.5
    assert toy_return(flip=True) < -4.0


@pytest.fixture(scope="module")
def td3_run(tmp_path_factory):
    from train.trainer import train

    path = tmp_path_factory.mktemp("td3_run")
    summary = train(tiny(num_timesteps=40), path, quiet=True)
    assert summary["env_steps"] == 40
    return path


def test_a_td3_run_logs_its_diagnostics_resumes_on_the_cpu_and_keeps_its_checkpoint_small(td3_run):
    from train.run.logger import read_jsonl
    from train.trainer import train

    last = read_jsonl(td3_run / "metrics.jsonl")[-1]
    for key in ("critic_loss", "actor_loss", "q_mean", "q_std", "buffer_size", "buffer_age", "noise_std_mean"):
        assert np.isfinite(last[f"loss/{key}"]), key
    assert last["loss/buffer_size"] == 40  # 10 steps of 4 envs (of 16 rows)
    assert (td3_run / "td3_diagnostics.png").is_file()
    first = checkpoint.latest(td3_run)
    summary = train(tiny(num_timesteps=80), td3_run, resume=True, quiet=True)
    assert summary["env_steps"] == 80 and checkpoint.latest(td3_run).name == "step_000000000080"
    assert [r["step"] for r in read_jsonl(td3_run / "metrics.jsonl")][-1] == 80
    size = sum(f.stat().st_size for f in first.iterdir())
    assert size < 200_000  # the learner state alone: the replay buffer is refilled on resume
    spent = checkpoint.read_meta(checkpoint.latest(td3_run))["training_walltime_s"]
    summary = train(tiny(num_timesteps=400, max_training_s=spent), td3_run, resume=True, quiet=True)
    assert summary["env_steps"] == 80 and summary["stopped_by"] == "max_training_s"  # its clock's budget is spent


def test_an_exported_td3_actor_runs_in_the_deployment_loop(td3_run, tmp_path, capsys):
    assert export.main([str(td3_run), "--format", "npz", "--out", str(tmp_path / "actor")]) == 0
    policy = policy_file.load_policy(tmp_path / "actor")
    assert policy.meta["network"]["distribution_type"] == "tanh_normal"
    from train.learners.td3.networks import act as td3_act
    from train.run.saved import load_training_state

    latest = checkpoint.latest(td3_run)
    config = train_config.from_dict(checkpoint.read_meta(latest)["config"])
    networks, ts = load_training_state(config, latest, policy.observation_size, policy.action_size)
    obs = np.asarray(policy.params["obs_mean"] + policy.params["obs_std"], np.float32)[None]
    np.testing.assert_allclose(policy(obs), td3_act(networks, ts.params.actor, ts.normalizer, obs), atol=1e-5)
    assert deploy(["--policy", str(tmp_path / "actor"), "--goal", "0.5", "0", "--max-steps", "3"]) == 0
    capsys.readouterr()


def test_td3_settings_are_checked_before_anything_compiles():
    with pytest.raises(ValueError, match="run.learner"):
        train_config.from_dict({"run": {"learner": "sac"}})
    with pytest.raises(ValueError, match="thread_per_device trains PPO only"):
        train_config.from_dict({"run": {"learner": "td3", "collection": "thread_per_device"}})
    with pytest.raises(ValueError, match="td3.learning_starts"):
        train_config.from_dict({"td3": {"n_step": 5, "learning_starts": 2}})
    with pytest.raises(ValueError, match="never learn"):
        train_config.from_dict({"run": {"learner": "td3", "num_envs": 64}, "td3": {"buffer_size": 512}})
    with pytest.raises(ValueError, match="td3.v_min"):
        train_config.from_dict({"td3": {"v_min": 1.0, "v_max": 0.0}})
