"""The timed loops of the throughput harness: the env's batch step under ``lax.scan`` with random actions,
the bare ``mjx.step`` loop beside it (the physics ceiling), ahead-of-time compilation and timing, memory."""

from __future__ import annotations

import dataclasses
import statistics
import time
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

import hsa_mjx
from hsa_mjx.sim.backend import mjx
from hsa_mjx.task import control


@dataclasses.dataclass(frozen=True)
class Timed:
    """A compiled batched loop and what was measured on it."""

    seconds: list[float]  # wall time of each timed call
    compile_s: float
    compiled_bytes: int | None  # arguments + outputs + temporaries - aliased, from XLA
    counters: dict[str, float]  # summed over the timed calls
    last: dict[str, float]  # the last timed call's counters


def _env_state(state: Any) -> Any:
    """The per-env EnvState inside a wrapper's batch state (or the state itself)."""
    return getattr(state, "env", state)


def env_loop(env: hsa_mjx.HSAEnv, wrapper: Any | None, steps: int) -> tuple[Callable, Callable]:
    """(reset(keys), run(state, key)): run takes ``steps`` random-action batch steps in a scan."""
    reset = wrapper.reset if wrapper is not None else jax.vmap(env.reset)
    step = wrapper.step if wrapper is not None else jax.vmap(env.step)

    def run(state: Any, key: jax.Array) -> tuple[Any, dict[str, jax.Array]]:
        batch = _env_state(state).obs.shape[0]

        def body(state, k):
            state = step(state, jax.random.uniform(k, (batch, env.action_size), minval=-1.0, maxval=1.0))
            if wrapper is not None:  # fresh terrain tiles when due (a no-op without regeneration)
                state = wrapper.tick(state, jax.random.fold_in(k, 1))
            inner = _env_state(state)
            reasons = {name: jnp.sum(value) for name, value in inner.metrics.items() if name.startswith("termination/")}
            return state, {
                **reasons,
                "obs_non_finite": jnp.sum(~jnp.isfinite(inner.obs)).astype(jnp.float32),
                "done": jnp.sum(inner.done),
            }

        state, counts = jax.lax.scan(body, state, jax.random.split(key, steps))
        return state, jax.tree.map(jnp.sum, counts)

    return reset, run


def ceiling_start(env: hsa_mjx.HSAEnv, keys: jax.Array) -> mjx.Data:
    """Physics state of freshly reset envs (the env's own reset pose, each on its own terrain tile)."""
    return jax.jit(jax.vmap(env.reset))(keys).pipeline_state.physics


def ceiling_loop(env: hsa_mjx.HSAEnv, steps: int) -> Callable:
    """run(data, key): ``steps`` env steps of bare ``mjx.step`` substeps per env, vmapped."""
    model, servos, ctl = env.robot.mjx_model, env.index.servo_ids, env.config.control

    def one_env(data: mjx.Data, key: jax.Array) -> mjx.Data:

        def env_step(data, k):
            start = data.ctrl[servos]
            action = jax.random.uniform(k, (len(servos),), minval=-1.0, maxval=1.0)
            end = control.next_targets(start, action, ctl.max_increment, ctl.servo_target_limit)

            def substep(d, target):
                return mjx.step(model, d.replace(ctrl=d.ctrl.at[servos].set(target))), None

            targets = control.substep_targets(start, end, ctl.frame_skip, ctl.smooth_positions)
            data, _ = jax.lax.scan(substep, data, targets)
            return data, None

        data, _ = jax.lax.scan(env_step, data, jax.random.split(key, steps))
        return data

    def run(data: mjx.Data, key: jax.Array) -> tuple[mjx.Data, dict[str, jax.Array]]:
        data = jax.vmap(one_env)(data, jax.random.split(key, data.qpos.shape[0]))
        bad = ~jnp.all(jnp.isfinite(data.qpos), axis=-1)
        return data, {"non_finite_envs": jnp.sum(bad).astype(jnp.float32)}

    return run


def _compiled_bytes(compiled: Any) -> int | None:
    """Bytes XLA reserves for one call: arguments + outputs + temporaries - aliased."""
    try:
        mem = compiled.memory_analysis()
        return int(
            mem.argument_size_in_bytes + mem.output_size_in_bytes + mem.temp_size_in_bytes - mem.alias_size_in_bytes
        )
    except (AttributeError, NotImplementedError, TypeError):
        return None


def time_loop(run: Callable, state: Any, key: jax.Array, repeats: int, donate: bool) -> tuple[Timed, Any]:
    """Compile ``run`` ahead of time, warm up once, then time ``repeats`` calls (median later)."""
    jitted = jax.jit(run, donate_argnums=(0,) if donate else ())
    tic = time.perf_counter()
    compiled = jitted.lower(state, key).compile()
    compile_s = time.perf_counter() - tic
    keys = jax.random.split(key, repeats + 1)
    state, _ = jax.block_until_ready(compiled(state, keys[0]))
    seconds, totals, last = [], {}, {}
    for k in keys[1:]:
        tic = time.perf_counter()
        state, counts = jax.block_until_ready(compiled(state, k))
        seconds.append(time.perf_counter() - tic)
        last = {name: float(value) for name, value in counts.items()}
        totals = {name: totals.get(name, 0.0) + value for name, value in last.items()}
    return Timed(seconds, compile_s, _compiled_bytes(compiled), totals, last), state


def tree_bytes(tree: Any) -> int:
    """Total bytes of the arrays in a pytree."""
    return int(sum(x.nbytes if hasattr(x, "nbytes") else np.asarray(x).nbytes for x in jax.tree.leaves(tree)))


def device_bytes(stat: str = "peak_bytes_in_use") -> int | None:
    """A memory statistic of device 0 (None where JAX reports none, e.g. on CPU).

    ``peak_bytes_in_use`` is the high-water mark since the process started; ``bytes_in_use`` now.
    """
    stats = jax.devices()[0].memory_stats()
    return int(stats[stat]) if stats and stat in stats else None


CEILING_FIELDS = (
    "physics_ceiling_env_steps_per_s",
    "physics_ceiling_physics_steps_per_s",
    "env_over_ceiling",
    "ceiling_call_s",
    "compile_s_ceiling",
    "ceiling_compiled_bytes_per_env",
    "ceiling_non_finite_envs_at_end",
    "ceiling_non_finite_per_million_env_steps",
)


def per_env(total: int | None, batch: int) -> int | None:
    """``total`` bytes per env of a ``batch`` (None stays None)."""
    return None if total is None else round(total / batch)


def measure_ceiling(
    env: hsa_mjx.HSAEnv, key: jax.Array, batch: int, steps: int, repeats: int, donate: bool, env_s: float
) -> dict[str, Any]:
    """The bare physics loop at the same batch: its rate, compile time, memory and non-finite envs."""
    start = ceiling_start(env, jax.random.split(key, batch))
    ceil_t, start = time_loop(ceiling_loop(env, steps), start, key, repeats, donate)
    del start
    ceil_s = statistics.median(ceil_t.seconds)
    return {
        "physics_ceiling_env_steps_per_s": round(batch * steps / ceil_s, 1),
        "physics_ceiling_physics_steps_per_s": round(batch * steps * env.config.control.frame_skip / ceil_s, 1),
        "env_over_ceiling": round(ceil_s / env_s, 4),
        "ceiling_call_s": [round(s, 5) for s in ceil_t.seconds],
        "compile_s_ceiling": round(ceil_t.compile_s, 2),
        "ceiling_compiled_bytes_per_env": per_env(ceil_t.compiled_bytes, batch),
        "ceiling_non_finite_envs_at_end": int(ceil_t.last.get("non_finite_envs", 0)),
        # an env stays NaN once it is (no reset): envs lost per million env steps run, warm-up included
        "ceiling_non_finite_per_million_env_steps": round(
            1e6 * ceil_t.last.get("non_finite_envs", 0) / (batch * steps * (repeats + 1)), 3
        ),
    }
