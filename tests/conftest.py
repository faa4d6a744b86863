"""Shared fixtures: one env, its jitted reset/step compiled once per session, a small batch."""

from __future__ import annotations

import json
import os
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")  # offscreen rendering without a display
os.environ.setdefault("JAX_PLATFORMS", "cpu")
# XLA's CPU backend without LLVM optimisation: the suite's time is mostly compiling MJX programs, which
# this cuts by about 30 %; results are the same computation (the tests check behaviour, never speed).
# Subprocesses inherit it, and the persistent compilation cache keys on it.
XLA_TEST_FLAGS = "--xla_backend_optimization_level=0"
os.environ["XLA_FLAGS"] = " ".join(f for f in (os.environ.get("XLA_FLAGS", ""), XLA_TEST_FLAGS) if f)

import jax  # noqa: E402
import pytest  # noqa: E402

CACHE = Path(os.environ.get("HSA_MJX_JAX_CACHE", Path.home() / ".cache" / "hsa_mjx_jax"))
jax.config.update("jax_compilation_cache_dir", str(CACHE))
jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)

BATCH = 4


class TraceCounter:
    """Wrap a function and count how often JAX traces it (a retracing guard)."""

    def __init__(self, fn):
        self.fn, self.traces = fn, 0

    def __call__(self, *args):
        self.traces += 1
        return self.fn(*args)


@pytest.fixture(scope="session")
def env():
    import hsa_mjx

    return hsa_mjx.make_env("flat")


# For the few jitted functions the tests call hundreds of times: XLA's full optimisation back (the flat
# 4-env step compiles in 7.5 instead of 5.4 s and runs in 13.5 instead of 136 ms per call).
OPTIMISED = {"xla_backend_optimization_level": 3}


@pytest.fixture(scope="session")
def jit_batch(env):
    """(reset, step, step trace counter) vmapped over a batch of envs (the step fully optimised)."""
    counter = TraceCounter(env.step)
    return jax.jit(jax.vmap(env.reset)), jax.jit(jax.vmap(counter), compiler_options=OPTIMISED), counter


@pytest.fixture(scope="session")
def jit_single(env, jit_batch):
    """(reset, step, step trace counter) for one env. The step runs the env as every row of ``jit_batch``'s
    compiled step and keeps row 0 (the same function under ``vmap``): one compile of the step for both."""
    _, batch_step, counter = jit_batch

    def step(state, action):
        rows = jax.tree.map(lambda x: jax.numpy.broadcast_to(x, (BATCH, *x.shape)), (state, jax.numpy.asarray(action)))
        return jax.tree.map(lambda x: x[0], batch_step(*rows))

    return jax.jit(env.reset), step, counter


TERRAIN_BATCH = 12
# Every generator but the spiral (a checkpoint track that needs goal.mode spiral), equal shares.
MIXED_TYPES = (
    "flat",
    "wavy",
    "perlin",
    "stairs",
    "incline",
    "craters",
    "poles",
    "flat_with_incline",
    "flat_with_ramp",
    "corridor",
)


@pytest.fixture(scope="session")
def terrain_env():
    import hsa_mjx

    return hsa_mjx.make_env("mixed", terrain__types=list(MIXED_TYPES))


@pytest.fixture(scope="session")
def terrain_batch(terrain_env):
    """(reset, step, step trace counter) of the mixed-terrain env, vmapped over a batch."""
    counter = TraceCounter(terrain_env.step)
    return jax.jit(jax.vmap(terrain_env.reset)), jax.jit(jax.vmap(counter)), counter


# A tiny PPO run with the curriculum: 80 env steps, checkpoints at 40 and 80 (tests/test_train_run.py
# resumes it to 160 steps; tests that only read it must not depend on which checkpoint is the latest).
TINY_RUN = {
    "env": {
        "preset": "flat",
        "goal": {"mode": "radial"},
        "physics": {"iterations": 4, "ls_iterations": 8},
        "termination": {"max_episode_steps": 15},
    },
    # success_threshold 0: every full window widens the range, so the wiring is visible in 80 steps
    "goal_curriculum": {
        "enabled": True,
        "window_size": 4,
        "min_episodes": 4,
        "success_threshold": 0.0,
        "failure_threshold": 0.0,
    },
    "ppo": {
        "unroll_length": 5,
        "batch_size": 4,
        "num_minibatches": 2,
        "num_updates_per_batch": 1,
        "policy_hidden_sizes": [8],
        "value_hidden_sizes": [8],
    },
    "run": {"num_timesteps": 80, "num_envs": 4, "checkpoint_every": 40, "seed": 1},
}


@pytest.fixture(scope="session")
def tiny_run_dir(tmp_path_factory):
    """The run directory of ``TINY_RUN``, trained once per session on the CPU."""
    import hsa_mjx_train.config
    from hsa_mjx_train.trainer import train

    path = tmp_path_factory.mktemp("run")
    summary = train(hsa_mjx_train.config.from_dict(json.loads(json.dumps(TINY_RUN))), path, quiet=True)
    assert summary["env_steps"] == 80
    return path


VECTOR_ENVS = 8
VECTOR_EPISODE_STEPS = 6  # short episodes: every few steps each env truncates and auto-resets


@pytest.fixture(scope="session")
def vector_env():
    """The Gymnasium vector env (numpy outputs) of ``VECTOR_ENVS`` flat envs, compiled once."""
    import gymnasium

    import hsa_mjx  # noqa: F401  (registers hsa_mjx/HSA-v0)

    envs = gymnasium.make_vec(
        "hsa_mjx/HSA-v0",
        num_envs=VECTOR_ENVS,
        vectorization_mode="vector_entry_point",
        render_mode="rgb_array",
        width=96,
        height=72,
        termination__max_episode_steps=VECTOR_EPISODE_STEPS,
    )
    yield envs
    envs.close()


# Scheduling under pytest-xdist (``-n 2``): each module runs on one worker (its module fixtures compile
# once), the modules sharing ``tiny_run_dir`` run on the same worker (one tiny run per session), and the
# longest modules start first so that neither worker is left with them at the end.
SHARED_RUN_MODULES = ("tests/test_train_run.py", "tests/test_export.py", "tests/test_policies.py")
# test_backend second: it compiles Warp's CPU kernels into Warp's kernel cache early, on the other worker,
# before the shared run's Warp evaluation needs them (each process compiling them at once would pay twice).
LONGEST_FIRST = (
    "tests/test_multi_device.py",
    "tests/test_backend.py",
    *SHARED_RUN_MODULES,
    "tests/test_sb3.py",
    "tests/test_gym_vector.py",
    "tests/test_quickstart.py",
    "tests/test_checkpoint_compat.py",
    "tests/test_env.py",
    "tests/test_terrain_env.py",
    "tests/test_install.py",
)


def _module(nodeid: str) -> str:
    """The test file of a node id."""
    return nodeid.split("::", 1)[0]


def pytest_collection_modifyitems(items):
    """Order the modules longest first (a stable sort: the tests of a module keep their order)."""
    rank = {name: i for i, name in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(_module(item.nodeid), len(rank)))


def pytest_xdist_make_scheduler(config, log):
    """Send whole modules to workers, the shared-run modules together."""
    from xdist.scheduler import LoadFileScheduling

    class ModuleScheduling(LoadFileScheduling):
        def _split_scope(self, nodeid: str) -> str:
            module = _module(nodeid)
            return SHARED_RUN_MODULES[0] if module in SHARED_RUN_MODULES else module

    return ModuleScheduling(config, log)
