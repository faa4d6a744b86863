"""The pmap that compiles across processes: no zero-size array enters or is baked into its program.

Two processes of one GPU each segfault in XLA's compile when a pmapped program takes or holds an
array of zero size (docs/scaling.md); a CPU compiles such programs, so these tests check the cause
in the lowered program instead of the crash.
"""

import re

import jax
import jax.numpy as jnp
import numpy as np

from hsa_mjx.curricula import goal_curriculum
from train import config as train_config
from train.devices import strategies
from train.devices.replicas import PmapWithoutEmpty
from train.learners.ppo.learner import AXIS

ARGUMENT = re.compile(r"%arg\d+: tensor<([^>]*)>")


def _zero_size(lowered: jax.stages.Lowered) -> dict:
    """The zero-size parameters and constants of a lowered program's entry (StableHLO text)."""
    text = lowered.as_text()
    main = next(line for line in text.splitlines() if "func.func public @main" in line)
    parameters = [t for t in ARGUMENT.findall(main) if "0" in t.split("x")[:-1]]
    return {"parameters": parameters, "constants": text.count("stablehlo.constant dense<> ")}


def _toy():
    """A function with a zero-size argument and a zero-size closed-over array, and its arguments."""
    held = jnp.zeros((3, 0))

    def fn(x, state):
        return {"sum": jax.lax.psum(x + state["empty"].sum() + held.sum(), AXIS), "empty": state["empty"] + 1.0}

    return fn, (np.ones((1, 2), np.float32), {"empty": np.zeros((1, 4, 0), np.float32), "kept": np.ones((1, 1))})


def test_a_plain_pmap_program_takes_and_holds_zero_size_arrays():
    fn, args = _toy()
    found = _zero_size(jax.pmap(fn, axis_name=AXIS).lower(*args))
    assert found["parameters"] == ["1x4x0xf32"] and found["constants"] >= 1


def test_pmap_without_empty_takes_and_holds_none_and_computes_the_same():
    fn, args = _toy()
    wrapped = PmapWithoutEmpty(fn, axis_name=AXIS)
    assert _zero_size(wrapped.lower(*args)) == {"parameters": [], "constants": 0}
    got, want = wrapped(*args), jax.pmap(fn, axis_name=AXIS)(*args)
    assert jax.tree.structure(got) == jax.tree.structure(want)
    for a, b in zip(jax.tree.leaves(got), jax.tree.leaves(want)):
        assert a.shape == b.shape and np.array_equal(a, b)


def test_the_learners_reset_compiles_without_zero_size_arrays_and_resets_as_before(env):
    assert any(np.size(c) == 0 for c in jax.make_jaxpr(env.reset)(jax.random.PRNGKey(0)).consts)  # MJX's data
    config = train_config.load("configs/train_flat.yaml", ["run.num_envs=4", "run.collection=pmap"])
    strategy = strategies.build(config, jax.local_devices()[:1])
    learner = strategy.learner
    keys = jax.random.split(jax.random.PRNGKey(1), 4)[None]
    start = goal_curriculum.init(config.goal_curriculum, tuple(config.env.goal.radial_range))
    goal = jax.tree.map(lambda x: np.asarray(x)[None], start)
    assert _zero_size(strategy._reset.lower(keys, goal, None)) == {"parameters": [], "constants": 0}
    got = strategy._reset(keys, goal, None)
    want = jax.pmap(learner.reset, axis_name=AXIS)(keys, goal, None)
    for a, b in zip(jax.tree.leaves(got), jax.tree.leaves(want)):
        assert a.shape == b.shape and np.array_equal(a, b)
