"""A CleanRL-style PPO (one file, one loop, JAX + optax learner) trains a few updates on the vector env.

The loop is what a Gymnasium user writes: numpy in and out of ``envs.step``, Gymnasium's own
``RecordEpisodeStatistics`` for episode returns, and truncated episodes bootstrapped from
``info["final_obs"]`` (same-step autoreset: the returned obs already belongs to the next episode).
"""

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
import optax
from conftest import VECTOR_EPISODE_STEPS

STEPS, UPDATES, EPOCHS, MINIBATCHES = 16, 3, 2, 4
GAMMA, LAMBDA, CLIP, LR = 0.99, 0.95, 0.2, 3e-4


def init_params(key: jax.Array, obs_size: int, act_size: int, hidden: int = 32) -> dict:
    """Actor mean and critic MLPs (two tanh layers each) and a state-independent log std."""

    def mlp(k, sizes):
        keys = jax.random.split(k, len(sizes) - 1)
        return [(jax.random.normal(kk, (a, b)) / np.sqrt(a), jnp.zeros(b)) for kk, a, b in zip(keys, sizes, sizes[1:])]

    k_pi, k_v = jax.random.split(key)
    return {
        "pi": mlp(k_pi, [obs_size, hidden, hidden, act_size]),
        "v": mlp(k_v, [obs_size, hidden, hidden, 1]),
        "log_std": jnp.full(act_size, -0.5),
    }


def forward(layers: list, x: jax.Array) -> jax.Array:
    for w, b in layers[:-1]:
        x = jnp.tanh(x @ w + b)
    w, b = layers[-1]
    return x @ w + b


def log_prob(params: dict, obs: jax.Array, action: jax.Array) -> jax.Array:
    std = jnp.exp(params["log_std"])
    z = (action - forward(params["pi"], obs)) / std
    return jnp.sum(-0.5 * z**2 - params["log_std"] - 0.5 * jnp.log(2 * jnp.pi), axis=-1)


@jax.jit
def act(params: dict, obs: jax.Array, key: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    mean = forward(params["pi"], obs)
    action = mean + jnp.exp(params["log_std"]) * jax.random.normal(key, mean.shape)
    return action, log_prob(params, obs, action), forward(params["v"], obs)[:, 0]


@jax.jit
def value(params: dict, obs: jax.Array) -> jax.Array:
    return forward(params["v"], obs)[:, 0]


def ppo_loss(params: dict, batch: dict) -> jax.Array:
    ratio = jnp.exp(log_prob(params, batch["obs"], batch["action"]) - batch["logp"])
    adv = (batch["adv"] - batch["adv"].mean()) / (batch["adv"].std() + 1e-8)
    policy = -jnp.minimum(ratio * adv, jnp.clip(ratio, 1 - CLIP, 1 + CLIP) * adv).mean()
    return policy + 0.5 * ((value(params, batch["obs"]) - batch["ret"]) ** 2).mean()


OPTIMIZER = optax.chain(optax.clip_by_global_norm(0.5), optax.adam(LR))


@jax.jit
def update(params: dict, opt_state: optax.OptState, batch: dict):
    loss, grads = jax.value_and_grad(ppo_loss)(params, batch)
    updates, opt_state = OPTIMIZER.update(grads, opt_state)
    return optax.apply_updates(params, updates), opt_state, loss


def gae(rewards, values, dones, last_value):
    """Advantages and returns; ``dones[t]`` ends the episode after step t (the next obs is a new one)."""
    adv, running = np.zeros_like(rewards), 0.0
    for t in reversed(range(len(rewards))):
        next_value = last_value if t == len(rewards) - 1 else values[t + 1]
        delta = rewards[t] + GAMMA * next_value * (1 - dones[t]) - values[t]
        running = delta + GAMMA * LAMBDA * (1 - dones[t]) * running
        adv[t] = running
    return adv, adv + values


def collect(envs, params, obs, key):
    """STEPS steps of every env under the current policy; returns buffers, next obs, key, episode lengths."""
    buf = {k: [] for k in ("obs", "action", "logp", "reward", "done", "value")}
    lengths = []
    for _ in range(STEPS):
        key, sub = jax.random.split(key)
        action, logp, v = (np.asarray(x) for x in act(params, obs, sub))
        next_obs, reward, terminated, truncated, info = envs.step(np.clip(action, -1, 1))
        # same-step autoreset: a truncated episode's value continues from its final observation
        reward = reward + GAMMA * np.asarray(value(params, info["final_obs"])) * truncated
        for name, item in zip(buf, (obs, action, logp, reward, terminated | truncated, v)):
            buf[name].append(item)
        if "episode" in info:
            lengths += info["episode"]["l"][info["_episode"]].tolist()
        obs = next_obs
    return {k: np.stack(v) for k, v in buf.items()}, obs, key, lengths


def test_cleanrl_style_ppo_updates(vector_env):
    envs = gymnasium.wrappers.vector.RecordEpisodeStatistics(vector_env)
    key = jax.random.PRNGKey(0)
    params = init_params(key, envs.single_observation_space.shape[0], envs.single_action_space.shape[0])
    start, opt_state = params, OPTIMIZER.init(params)
    obs, _ = envs.reset(seed=0)
    losses, lengths, dones = [], [], 0
    for _ in range(UPDATES):
        buf, obs, key, ended = collect(envs, params, obs, key)
        lengths += ended
        dones += int(buf["done"].sum())
        adv, ret = gae(buf["reward"], buf["value"], buf["done"].astype(np.float32), np.asarray(value(params, obs)))
        flat = {"obs": buf["obs"], "action": buf["action"], "logp": buf["logp"], "adv": adv, "ret": ret}
        flat = {k: v.reshape(-1, *v.shape[2:]) for k, v in flat.items()}
        for _ in range(EPOCHS):
            key, sub = jax.random.split(key)
            for idx in np.array_split(np.asarray(jax.random.permutation(sub, len(flat["obs"]))), MINIBATCHES):
                params, opt_state, loss = update(params, opt_state, {k: v[idx] for k, v in flat.items()})
                losses.append(float(loss))
    assert np.all(np.isfinite(losses)) and len(losses) == UPDATES * EPOCHS * MINIBATCHES
    assert not np.allclose(params["pi"][0][0], start["pi"][0][0])  # the learner moved
    assert not np.allclose(params["log_std"], start["log_std"])
    total_steps = UPDATES * STEPS * vector_env.num_envs
    assert dones == len(lengths) >= total_steps // VECTOR_EPISODE_STEPS  # every ending counted, all truncations
    assert max(lengths) <= VECTOR_EPISODE_STEPS and sum(lengths) <= total_steps
