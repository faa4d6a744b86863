"""Open-loop gaits for the fidelity guard: pure functions of time returning the 8 normalised actions.

A gait maps time ``t`` (seconds, any shape) to actions in [-1, 1] of shape ``t.shape + (8,)`` in the
env's action-slot order. The env adds ``max_increment * action`` to the servo targets at every
0.02 s control step (``hsa_mjx.task.control``), so an action is a target *velocity*: a square wave of
period T drives each target back and forth by ``max_increment * T / (2 * 0.02)`` rad.

Which servo sits on which block, in which HSA unit, is read from the model by name
(:func:`gait_layout`), never from hard-coded slots.

    extend_contract  all eight servos together, square wave (period 4 s)
    crawl            block A's servos a quarter period ahead of block B's (square wave, 4 s)
    sine             all eight servos together, sine (period 4 s)
    wave             a sine travelling through the four HSA units, a quarter period apart (4 s)
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Callable

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from hsa_mjx.sim.model import ACTUATED_JOINTS, BLOCKS

PERIOD_S = 4.0


@dataclasses.dataclass(frozen=True)
class GaitLayout:
    """Where each action slot's servo sits, resolved by name (numpy, static)."""

    on_block_a: np.ndarray  # (8,) float 1.0 where the servo's cylinder hangs on block_a
    unit: np.ndarray  # (8,) int HSA unit number 1..4
    contracting: np.ndarray  # (8,) float 1.0 for the "cont" (A) cylinders, 0.0 for "ext" (C)


def gait_layout(model: mujoco.MjModel) -> GaitLayout:
    """Resolve the block, unit and handedness of every actuated hinge from the model's names."""
    on_a, units, cont = [], [], []
    for joint in ACTUATED_JOINTS:
        body = model.jnt_bodyid[model.joint(joint).id]
        parent = model.body(model.body_parentid[body]).name
        if parent not in BLOCKS:
            raise ValueError(f"actuated joint {joint!r} hangs on {parent!r}, not on one of {BLOCKS}")
        match = re.fullmatch(r"cylinder(\d)([ac])", model.body(body).name)
        if match is None:
            raise ValueError(f"actuated joint {joint!r} is on body {model.body(body).name!r}, not cylinder<k><a|c>")
        on_a.append(float(parent == BLOCKS[0]))
        units.append(int(match.group(1)))
        cont.append(float(match.group(2) == "a"))
    return GaitLayout(np.asarray(on_a, np.float32), np.asarray(units, np.int32), np.asarray(cont, np.float32))


def _square(phase: jax.Array) -> jax.Array:
    """+1 on the first half of each cycle, -1 on the second (0 exactly on the switch)."""
    return jnp.sign(jnp.sin(phase))


def _phase(t: jax.Array, period: float) -> jax.Array:
    return 2.0 * jnp.pi * jnp.asarray(t, jnp.float32)[..., None] / period


def extend_contract(t: jax.Array, layout: GaitLayout, period: float = PERIOD_S) -> jax.Array:
    """All servos turn together: targets sweep out and back (square-wave increments)."""
    return jnp.broadcast_to(_square(_phase(t, period)), jnp.shape(t) + (len(layout.unit),))


def crawl(t: jax.Array, layout: GaitLayout, period: float = PERIOD_S) -> jax.Array:
    """Block A's servos lead block B's by a quarter period (square-wave increments)."""
    lag = (1.0 - layout.on_block_a) * (jnp.pi / 2.0)
    return _square(_phase(t, period) - lag)


def sine(t: jax.Array, layout: GaitLayout, period: float = PERIOD_S) -> jax.Array:
    """All servos together, sinusoidal increments (smooth extend-contract)."""
    return jnp.broadcast_to(jnp.sin(_phase(t, period)), jnp.shape(t) + (len(layout.unit),))


def wave(t: jax.Array, layout: GaitLayout, period: float = PERIOD_S) -> jax.Array:
    """Sinusoidal increments travelling through HSA units 1 -> 4, a quarter period apart."""
    return jnp.sin(_phase(t, period) - (layout.unit - 1) * (jnp.pi / 2.0))


Gait = Callable[[jax.Array, GaitLayout], jax.Array]
GAITS: dict[str, Gait] = {
    "extend_contract": extend_contract,
    "crawl": crawl,
    "sine": sine,
    "wave": wave,
}


def gait_actions(name: str, layout: GaitLayout, steps: int, control_dt: float) -> np.ndarray:
    """The gait's actions at the start of each control step, shape (steps, 8), float32."""
    if name not in GAITS:
        raise ValueError(f"unknown gait {name!r}; available gaits: {sorted(GAITS)}")
    times = np.arange(steps, dtype=np.float32) * np.float32(control_dt)
    return np.asarray(GAITS[name](jnp.asarray(times), layout), np.float32)
