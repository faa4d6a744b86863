"""Which multi-GPU pieces compile, and does one-jit-per-GPU env stepping scale? One piece per call.

    python3 benchmarks/device/split_check.py PIECE [ENVS_PER_DEVICE]

Pieces compiled under ``jax.pmap`` over every local device (exit 0 and ``ok PIECE`` when it ran,
a crash shows as the exit status): ``learn`` (Brax PPO SGD passes with gradient ``pmean`` and the
observation normaliser, our learner's update on fake data), ``chol`` (batched Cholesky),
``while`` (a batched ``while_loop``), ``kinematics`` (``mjx.kinematics``), ``fwd_cg`` and
``fwd_noconstraint`` (``mjx.forward`` with the CG solver / without constraints).
``per_device``: the training env step (``AutoResetEnv``) under ``lax.scan`` jitted once per GPU,
each GPU with its own env copy and no communication; env-steps/s for 1, 2, 4, ... GPUs at once,
called from one host thread, then from one thread per GPU (keys made on each GPU beforehand).
"""

import functools
import sys
import time
from concurrent.futures import ThreadPoolExecutor

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import mjx

from hsa_mjx.env import HSAEnv
from hsa_mjx.training_env import AutoResetEnv
from train import config as tcfg

CONFIG = "configs/train_flat.yaml"
STEPS, REPEATS = 16, 3


def stacked(tree, n: int):
    """``n`` host copies of ``tree`` along a new leading axis."""
    return jax.tree.map(lambda x: np.stack([np.asarray(x)] * n), tree)


def pmapped_piece(piece: str, n: int):
    """Run one piece under pmap over ``n`` devices; returns an output to block on."""
    config = tcfg.load(CONFIG)
    if piece == "chol":
        a = np.eye(24, dtype=np.float32) * 2 + 0.1
        return jax.pmap(jax.vmap(jnp.linalg.cholesky))(np.broadcast_to(a, (n, 8, 24, 24)).copy())
    if piece == "while":
        f = jax.vmap(lambda x: jax.lax.while_loop(lambda c: c[1] < 10 * (c[0] > 0), lambda c: (c[0] * 0.9, c[1] + 1),
                                                   (x, 0))[0])
        return jax.pmap(f)(np.ones((n, 8), np.float32))
    env = HSAEnv(config.env)
    model = env.robot.mjx_model
    if piece == "kinematics":
        return jax.pmap(lambda d: mjx.kinematics(model, d).xpos)(stacked(mjx.make_data(model), n))
    if piece in ("fwd_cg", "fwd_noconstraint"):
        opt = model.opt
        if piece == "fwd_cg":
            opt = opt.replace(solver=mujoco.mjtSolver.mjSOL_CG)
        else:
            opt = opt.replace(disableflags=opt.disableflags | mujoco.mjtDisableBit.mjDSBL_CONSTRAINT)
        m = model.replace(opt=opt)
        return jax.pmap(lambda d: mjx.forward(m, d).qacc)(stacked(mjx.make_data(m), n))
    if piece == "learn":
        return learn_piece(config, env, n)
    raise ValueError(f"unknown piece {piece!r}")


def learn_piece(config, env, n: int):
    """The learner's SGD passes under pmap on fake data shaped like a collection."""
    from train import ppo
    learner = ppo.PPOLearner(config, env, n)
    learner.batch_env = AutoResetEnv(env, config.curriculum)  # shapes only: no device axis outside pmap
    ts = ppo.init_training_state(config, learner.networks, jax.random.PRNGKey(0), env.observation_size)
    keys = jax.random.split(jax.random.PRNGKey(1), config.run.num_envs // n)
    state = jax.eval_shape(learner.batch_env.reset, keys)
    data = jax.eval_shape(learner._collect, ts, state, jax.random.PRNGKey(2))[1]
    rng = np.random.default_rng(0)
    fake = jax.tree.map(lambda s: (rng.standard_normal((n,) + s.shape) * 0.1).astype(s.dtype), data)

    def learn(ts, data, key):
        carry = (ts.params, ts.optimizer_state, ts.normalizer, key, jnp.zeros(()))
        (params, *_), metrics = jax.lax.scan(functools.partial(learner._sgd_pass, data=data), carry, None,
                                             length=config.ppo.num_updates_per_batch)
        return jax.tree.map(jnp.mean, metrics)["total_loss"] if "total_loss" in metrics else params

    out = jax.pmap(learn, axis_name=ppo.AXIS)(stacked(ts, n), fake, jax.random.split(jax.random.PRNGKey(3), n))
    return jax.tree.leaves(out)[0]


def per_device(per_env: int) -> None:
    """Env-steps/s of independent per-GPU jits run at once, for 1, 2, 4, ... GPUs."""
    config = tcfg.load(CONFIG)
    devices, runs = jax.local_devices(), []
    for d in devices:
        with jax.default_device(d):
            batch_env = AutoResetEnv(HSAEnv(config.env), config.curriculum)

            def loop(state, key, batch_env=batch_env):
                def body(s, k):
                    a = jax.random.uniform(k, (per_env, batch_env.action_size), minval=-1.0, maxval=1.0)
                    return batch_env.step(s, a), None
                return jax.lax.scan(body, state, jax.random.split(key, STEPS))[0]

            keys = jax.device_put(jax.random.split(jax.random.PRNGKey(0), per_env), d)
            state = jax.jit(batch_env.reset)(keys)
            t0 = time.time()
            fn = jax.jit(loop, donate_argnums=0)
            state = jax.block_until_ready(fn(state, jax.device_put(jax.random.PRNGKey(1), d)))
            print(f"{d}: compile+first run {time.time() - t0:.1f} s", flush=True)
            runs.append((fn, state, d))
    pool = ThreadPoolExecutor(len(devices))
    for threads in (False, True):
        base, k = None, 1
        while k <= len(devices):
            times = []
            for r in range(REPEATS):
                keys = [jax.device_put(np.asarray(jax.random.PRNGKey(10 + r)), d) for d in devices[:k]]
                jax.block_until_ready(keys)  # made before the clock starts, each on its own GPU
                t0 = time.time()
                call = lambda i: runs[i][0](runs[i][1], keys[i])  # noqa: E731
                outs = list(pool.map(call, range(k))) if threads else [call(i) for i in range(k)]
                jax.block_until_ready(outs)
                times.append(time.time() - t0)
                runs[:k] = [(fn, o, d) for (fn, _, d), o in zip(runs[:k], outs)]
            rate = k * per_env * STEPS / float(np.median(times))
            base = base or rate
            print(f"per_device {'one thread per GPU' if threads else 'one host thread'}: {k} GPU(s) x {per_env:,} "
                  f"envs: {rate:,.0f} env-steps/s, speed-up {rate / base:.2f}, efficiency {100 * rate / base / k:.0f} %",
                  flush=True)
            k *= 2


def main() -> None:
    """Run the piece named on the command line."""
    piece = sys.argv[1]
    if piece == "per_device":
        per_device(int(sys.argv[2]) if len(sys.argv) > 2 else 8192)
        return
    t0 = time.time()
    out = jax.block_until_ready(pmapped_piece(piece, jax.local_device_count()))
    print(f"ok {piece}: {jax.local_device_count()} devices, {time.time() - t0:.1f} s, "
          f"finite {bool(np.all(np.isfinite(np.asarray(out))))}", flush=True)


if __name__ == "__main__":
    main()
