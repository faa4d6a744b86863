"""Shared fixtures: one env, its jitted reset/step compiled once per session, a small batch."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")  # offscreen rendering without a display
# Bytecode: the test command installs with ``pip install --no-compile`` (byte-compiling the 20,000-odd
# modules of torch, JAX, SciPy and the rest takes half the install, and the tests import a fraction).
# The test processes write the .pyc of what they import once, for every later process, even where
# the machine sets PYTHONDONTWRITEBYTECODE (each process would compile them again: ~4 s each).
os.environ.pop("PYTHONDONTWRITEBYTECODE", None)
sys.dont_write_bytecode = False
os.environ.setdefault("JAX_PLATFORMS", "cpu")
# XLA's CPU backend without LLVM optimisation and with its classic loop emitters instead of the fusion
# emitters: the suite's time is mostly compiling MJX programs, which the two cut by about half (the flat
# 4-env step: 5.8 s -> 2.9 s, and it runs in 83 instead of 148 ms); results are the same computation
# (the tests check behaviour, never speed). Each program is also generated as one LLVM module instead of
# XLA's default 32 split for parallel code generation: on two cores already busy with the two workers,
# the split saves no time and costs CPU (the flat step's compile: 3.9 instead of 4.8 CPU-s, mean of three
# each, 2026-11-28). Subprocesses inherit them, and the persistent compilation cache keys on them.
XLA_NO_LLVM_OPTIMISATION = "--xla_backend_optimization_level=0"
XLA_TEST_FLAGS = (
    f"{XLA_NO_LLVM_OPTIMISATION} --xla_cpu_use_fusion_emitters=false --xla_cpu_parallel_codegen_split_count=1"
)
if XLA_TEST_FLAGS not in os.environ.get("XLA_FLAGS", ""):  # once: subprocesses inherit them and import this file
    os.environ["XLA_FLAGS"] = " ".join(f for f in (os.environ.get("XLA_FLAGS", ""), XLA_TEST_FLAGS) if f)

import jax  # noqa: E402
import pytest  # noqa: E402


def quick_warp_kernels() -> None:
    """MuJoCo Warp's CPU kernels compiled at LLVM's -O0 (Warp's default is -O2): the same results, compiled
    in about 60 % of the time (the flat env's kernels: 20 s against 32 s on the 2-core development
    machine); the tests check behaviour, never speed. Warp keeps the level in its cache key."""
    try:
        import warp
    except ImportError:
        return
    warp.config.optimization_level = 0


quick_warp_kernels()
CACHE = Path(os.environ.get("HSA_MJX_JAX_CACHE", Path.home() / ".cache" / "hsa_mjx_jax"))
jax.config.update("jax_compilation_cache_dir", str(CACHE))
# every program, however quick to compile: the suite's many processes (xdist workers, the multi-device
# scenarios, the installed copy) each compile the same small programs (a reset, a network's init, a
# normaliser update) otherwise; cold, the multi-device module took 487 instead of 603 CPU-s
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)

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
    from train import config as train_config
    from train.trainer import train

    path = tmp_path_factory.mktemp("run")
    summary = train(train_config.from_dict(json.loads(json.dumps(TINY_RUN))), path, quiet=True)
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
# once), the modules sharing ``tiny_run_dir`` run on the same worker (one tiny run per session), the
# modules that step MuJoCo Warp on the CPU run one after another on one worker (Warp compiles its CPU
# kernels once, into its cache: two workers compiling the same kernels at once would pay twice; the
# Warp part of test_multi_device's scenario comes minutes later, from the cache), and the longest
# modules start first so that neither worker is left with them at the end.
SHARED_RUN_MODULES = (
    "tests/test_train_run.py",
    "tests/test_export.py",
    "tests/test_policies.py",
    "tests/test_scaling.py",  # its epoch is the tiny run's program
)
WARP_MODULES = ("tests/test_backend.py", "tests/test_randomization.py")
GROUPS = {module: group[0] for group in (SHARED_RUN_MODULES, WARP_MODULES) for module in group}
# Modules by their time on the 2-core machine (cold caches, longest first; the rest, a few seconds each,
# follow in file order). xdist sends a worker the next module in this order when it is nearly done with
# its last, so the long ones start early and the short ones fill the end.
LONGEST_FIRST = (
    "tests/test_multi_device.py",
    *WARP_MODULES,
    *SHARED_RUN_MODULES,
    "tests/test_env.py",
    "tests/test_install.py",
    "tests/test_checkpoint_compat.py",
    "tests/test_terrain_env.py",
    "tests/test_gym_vector.py",
    "tests/test_servo.py",
    "tests/test_terrain_progress_env.py",
    "tests/test_ppo_update.py",
    "tests/test_sb3.py",
    "tests/test_host_physics.py",
    "tests/test_video.py",
    "tests/test_fidelity.py",
    "tests/test_model.py",
    "tests/test_gymnasium.py",
    "tests/test_tracker.py",
    "tests/test_terrain.py",
    "tests/test_robustness.py",
    "tests/test_gym_vector_ppo.py",
)


def _module(nodeid: str) -> str:
    """The test file of a node id."""
    return nodeid.split("::", 1)[0]


def pytest_collection_modifyitems(items):
    """Order the modules longest first (a stable sort: the tests of a module keep their order)."""
    rank = {name: i for i, name in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(_module(item.nodeid), len(rank)))


def pytest_xdist_make_scheduler(config, log):
    """Send whole modules to workers, each group of modules (above) together, in ``LONGEST_FIRST``'s order
    (xdist would otherwise reorder them by their number of tests)."""
    from xdist.scheduler import LoadFileScheduling

    config.option.loadscopereorder = False

    class ModuleScheduling(LoadFileScheduling):
        def _split_scope(self, nodeid: str) -> str:
            module = _module(nodeid)
            return GROUPS.get(module, module)

    return ModuleScheduling(config, log)
