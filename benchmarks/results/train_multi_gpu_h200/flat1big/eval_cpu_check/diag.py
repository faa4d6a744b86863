import sys, json, time
import jax, jax.numpy as jnp, numpy as np
from pathlib import Path
from train.evaluate import load_policy
from train import checkpoint
from brax.training.agents.ppo import networks as ppo_networks
from hsa_mjx import termination
run = Path(sys.argv[1]); n = int(sys.argv[2]); stochastic = sys.argv[3] == "stoch"
config, env, policy, path, step = load_policy(run)
if stochastic:
    from train.ppo import make_networks, init_training_state
    from hsa_mjx import curriculum as cur
    nets = make_networks(config, env.observation_size, env.action_size)
    tmpl = {"training_state": init_training_state(config, nets, jax.random.PRNGKey(0), env.observation_size), "curriculum": cur.init(config.curriculum), "rng": jax.random.PRNGKey(0)}
    ts = jax.tree.map(jnp.asarray, checkpoint.load(path, tmpl)["training_state"])
    policy = ppo_networks.make_inference_fn(nets)((ts.normalizer, ts.params.policy), deterministic=False)
gr = jnp.asarray([1.5, 4.5], jnp.float32)
def one(key):
    k0, k1 = jax.random.split(key)
    s = env.reset_with_goal_range(k0, gr)
    goal_d = s.metrics["distance_to_goal"]
    def body(c, _):
        s, alive, k, end = c
        k, ka = jax.random.split(k)
        a, _ = policy(s.obs, ka)
        ns = env.step(s, a)
        ns = jax.tree.map(lambda new, old: jnp.where(alive, new, old), ns, s)
        reasons = jnp.stack([ns.metrics[f"termination/{r}"] for r in termination.REASONS])
        end = jnp.where(alive & (ns.done > 0.5), reasons, end)
        return (ns, alive & (ns.done < 0.5), k, end), None
    (s, alive, _, end), _ = jax.lax.scan(body, (s, jnp.ones((), bool), k1, jnp.zeros(len(termination.REASONS))), None, length=config.env.termination.max_episode_steps)
    return goal_d, end, s.metrics["distance_to_goal"], alive
t = time.time()
g, end, fd, alive = jax.device_get(jax.jit(jax.vmap(one))(jax.random.split(jax.random.PRNGKey(1), n)))
ri = {r: i for i, r in enumerate(termination.REASONS)}
succ = end[:, ri["goal_reached"]] > 0.5
out = {"mode": sys.argv[3], "n": n, "success": float(succ.mean()), "secs": time.time() - t,
       "reasons": {r: int(end[:, i].sum()) for r, i in ri.items()}, "timeouts": int(alive.sum()),
       "by_distance": {f"{lo}-{lo+1}": float(succ[(g >= lo) & (g < lo + 1)].mean()) if ((g >= lo) & (g < lo + 1)).any() else None for lo in (1.5, 2.5, 3.5)},
       "goal_d_fail": np.round(g[~succ], 2).tolist(), "final_d_fail": np.round(fd[~succ], 2).tolist()}
print(json.dumps(out))
