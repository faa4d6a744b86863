"""Can an open-loop gait turn the robot? Differential versions of the corridor's best gaits on flat ground.

``python -m benchmarks.turn_gaits [--seconds 20] [--out benchmarks/results/turn_gaits_flat_cpu]``

The spiral's first checkpoint lies 0.94 m to the robot's left, and no PPO run has collected it
(docs/training.md, session 7). This sweep asks whether the robot can turn at all with the Loose
servo range (+-6.28 rad): it takes the gaits that moved it furthest in the corridor
(``benchmarks.gait_sweep``) and plays them on both sides, on one side only (the other held), or
with one lead on the left and the other on the right (forwards on one side, backwards on the
other, as a tracked vehicle turns). Gait names say the lead per side: ``leftA_rightB``. The side of every servo
(left: +y of the axis from block_a to block_b at the model's reset pose) is read from the model.
Reported per gait: the displacement of the blocks' midpoint in the start frame (x along that axis)
and the yaw change, summed step by step so that turns past 180 degrees count in full.
"""

from __future__ import annotations


import jax
import jax.numpy as jnp
import mujoco
import numpy as np

import hsa_mjx
from benchmarks import fidelity, gaits
from benchmarks.gait_sweep import PHYSICS, gait_actions, gait_targets
from benchmarks.run_info import gait_sweep_cli
from hsa_mjx import config as ec
from hsa_mjx.model import ACTUATED_JOINTS, BLOCKS

# (shape, amplitude, period, signs): the gaits that moved furthest in the corridor sweep
BASE_GAITS = {"square_T4": ("square", 6.28, 4.0, "same"), "sine_a2.2_T2_opposite": ("sine", 2.2, 2.0, "opposite")}
# (left lead, right lead): "-" holds that side at 0; equal leads are the straight gait
SIDES = (("A", "A"), ("B", "B"), ("A", "-"), ("-", "A"), ("B", "-"), ("-", "B"), ("A", "B"), ("B", "A"))


def left_side(model: mujoco.MjModel) -> np.ndarray:
    """(8,) 1.0 where the action slot's cylinder sits left of the block_a -> block_b axis at reset, else 0.0."""
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    a, b = (data.xpos[model.body(name).id] for name in BLOCKS)
    axis = (b - a)[:2] / np.linalg.norm((b - a)[:2])
    left = np.array([-axis[1], axis[0]])
    offsets = [data.xpos[model.jnt_bodyid[model.joint(j).id]][:2] - (a + b)[:2] / 2 for j in ACTUATED_JOINTS]
    side = np.array([float(np.dot(o, left)) for o in offsets])
    if np.any(np.abs(side) < 1e-6):
        raise ValueError(f"a cylinder sits on the robot's axis, neither left nor right: {side.tolist()}")
    return (side > 0).astype(np.float32)


def mixed_targets(base: tuple, left_lead: str, right_lead: str, left: np.ndarray, layout: gaits.GaitLayout,
                  times: np.ndarray) -> np.ndarray:
    """Servo targets (len(times), 8): the base gait with lead ``left_lead`` on the left servos and
    ``right_lead`` on the right ones ("A", "B", or "-" for held at 0)."""
    shape, amplitude, period, signs = base

    def side(lead: str) -> np.ndarray:
        if lead == "-":
            return np.zeros((len(times), 8))
        return gait_targets(shape, amplitude, period, lead, signs, layout, times)

    return np.where(left[None] > 0, side(left_lead), side(right_lead))


def variants(layout: gaits.GaitLayout, left: np.ndarray, steps: int, dt: float, max_increment: float,
             limit: float) -> dict:
    """Name -> actions (steps, 8) of every gait in the sweep (``hold`` first)."""
    times = np.arange(steps + 1) * dt
    out = {"hold": np.zeros((steps, 8), np.float32)}
    for name, base in BASE_GAITS.items():
        for left_lead, right_lead in SIDES:
            targets = mixed_targets(base, left_lead, right_lead, left, layout, times)
            out[f"{name}_left{left_lead}_right{right_lead}"] = gait_actions(targets, max_increment, limit)
    return out


def rollout_fn(env: hsa_mjx.HSAEnv):
    """jit(vmap) of one episode per action sequence: displacement in the start frame and summed yaw change."""
    blocks = env.index.block_body

    def pose(s) -> tuple[jax.Array, jax.Array]:
        a, b = s.pipeline_state.physics.xpos[blocks[0], :2], s.pipeline_state.physics.xpos[blocks[1], :2]
        return (a + b) / 2, jnp.arctan2(b[1] - a[1], b[0] - a[0])

    def one(actions: jax.Array, key: jax.Array):
        state = env.reset(key)
        start, yaw0 = pose(state)

        def body(carry, a):
            s, yaw = carry
            s = env.step(s, a)
            _, new = pose(s)
            return (s, new), (jnp.arctan2(jnp.sin(new - yaw), jnp.cos(new - yaw)), s.done)

        (end_state, _), (turns, done) = jax.lax.scan(body, (state, yaw0), actions)
        moved = pose(end_state)[0] - start
        rot = jnp.array([[jnp.cos(yaw0), jnp.sin(yaw0)], [-jnp.sin(yaw0), jnp.cos(yaw0)]])
        return rot @ moved, jnp.sum(turns), jnp.sum(done)

    return jax.jit(jax.vmap(one))


def sweep(seconds: float) -> list[dict]:
    """Every gait of the sweep on the flat preset with the Loose servo range: one row each."""
    overrides = {"control": {"servo_target_limit": 6.28}, "physics": PHYSICS}
    env = hsa_mjx.make_env(ec.from_dict(overrides, base=ec.get_preset("flat")))
    steps = int(round(seconds / env.dt))
    if steps > env.config.termination.max_episode_steps:
        raise ValueError(f"--seconds {seconds} is {steps} steps, past the flat preset's episode limit "
                         f"({env.config.termination.max_episode_steps} steps)")
    model = fidelity.load_mj_model(fidelity.fidelity_config())
    layout, left = gaits.gait_layout(model), left_side(model)
    control = env.config.control
    table = variants(layout, left, steps, env.dt, control.max_increment, control.servo_target_limit)
    keys = jax.random.split(jax.random.PRNGKey(0), len(table))
    moved, yaw, done = jax.device_get(rollout_fn(env)(jnp.asarray(np.stack(list(table.values()))), keys))
    return [{"gait": name, "seconds": seconds, "forward_m": round(float(moved[i][0]), 3),
             "left_m": round(float(moved[i][1]), 3), "yaw_deg": round(float(np.degrees(yaw[i])), 1),
             "done_steps": int(done[i])} for i, name in enumerate(table)]


HEAD = ["gait", "forward_m", "left_m", "yaw_deg", "done_steps"]


def caption(seconds: float) -> str:
    """What the table shows."""
    return (f"Flat preset, servo range +-6.28 rad, {seconds:g} s per open-loop gait: displacement of the blocks' "
            "midpoint in the start frame (forward: from block_a towards block_b; left: +y of that) and the summed "
            "yaw change (positive: counter-clockwise, to the left); done_steps counts the steps with the env's done "
            "flag set (0: no termination)")


def main(argv: list[str] | None = None) -> None:
    """Run the sweep, print and write the table."""
    gait_sweep_cli(argv, "python -m benchmarks.turn_gaits", __doc__, "benchmarks/results/turn_gaits_flat_cpu",
                   sweep, caption, HEAD)


if __name__ == "__main__":
    main()
