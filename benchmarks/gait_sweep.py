"""Which open-loop gaits move the robot in the corridor, and what does the corridor's reward pay for them?

``python -m benchmarks.gait_sweep [--seconds 20] [--out benchmarks/results/gait_sweep_corridor_cpu]``
plays a family of two-block gaits for ``--seconds`` through the corridor preset (shipped heightfield
physics) and reports the displacement and the mean per-step reward with its largest components,
as JSON and a markdown table. Each gait sets the servo targets directly as a periodic wave; the
actions are the target increments divided by ``max_increment`` and clipped to [-1, 1]:

    hold    all actions 0: the robot stands (the baseline any gait has to beat)
    square  full-range triangle waves (actions +-1), the fidelity guard's crawl
    sine    targets amplitude x sin(2 pi t / period - lag)

``lead`` says which block's servos lead the other's by a quarter period; ``signs`` is ``same`` (all
servos turn the same way) or ``opposite`` (the C cylinders turn against the A cylinders). Which
servo sits on which block and cylinder is read from the model by name (benchmarks/gaits.py).
Session 7 used it to see why PPO stood still in the corridor: docs/training.md.
"""

from __future__ import annotations

import itertools

import jax
import jax.numpy as jnp
import numpy as np

import hsa_mjx
from benchmarks import fidelity, gaits
from benchmarks.run_info import gait_sweep_cli
from hsa_mjx import config as ec

PHYSICS = {"integrator": "implicitfast", "iterations": 8, "ls_iterations": 8}
COMPONENTS = ("forward", "constraint_cost", "constraint_bonus", "stagnation_cost", "distance")


def gait_targets(shape: str, amplitude: float, period: float, lead: str, signs: str,
                 layout: gaits.GaitLayout, times: np.ndarray) -> np.ndarray:
    """Servo targets (len(times), 8) of one gait, starting at 0."""
    lag = (1.0 - layout.on_block_a if lead == "A" else layout.on_block_a) * (np.pi / 2.0)
    sign = np.ones(8) if signs == "same" else np.where(layout.contracting > 0, 1.0, -1.0)
    phase = 2.0 * np.pi * times[:, None] / period - lag[None]
    if shape == "square":  # +-amplitude by half periods: the env's targets run there at full speed
        return sign * amplitude * np.sign(np.sin(phase))
    wave = amplitude * sign * np.sin(phase)
    return wave - wave[0]


def gait_actions(targets: np.ndarray, max_increment: float, limit: float) -> np.ndarray:
    """Normalised actions that make the env's (clipped) targets follow ``targets`` as closely as it can."""
    actions, current = [], np.zeros(targets.shape[1])
    for goal in targets[1:]:
        action = np.clip((goal - current) / max_increment, -1.0, 1.0)
        current = np.clip(current + max_increment * action, -limit, limit)
        actions.append(action)
    return np.asarray(actions, np.float32)


def variants(layout: gaits.GaitLayout, steps: int, dt: float, max_increment: float, limit: float) -> dict:
    """Name -> actions (steps, 8) of every gait in the sweep."""
    times = np.arange(steps + 1) * dt
    out = {"hold": np.zeros((steps, 8), np.float32)}  # the baseline: standing still
    for period, lead in itertools.product((2.0, 4.0, 8.0), ("A", "B")):
        targets = gait_targets("square", limit, period, lead, "same", layout, times)
        out[f"square_T{period:g}_lead{lead}"] = gait_actions(targets, max_increment, limit)
    for amplitude, period, signs, lead in itertools.product((1.5, 2.2, 3.0), (2.0, 4.0), ("same", "opposite"),
                                                            ("A", "B")):
        targets = gait_targets("sine", amplitude, period, lead, signs, layout, times)
        out[f"sine_a{amplitude:g}_T{period:g}_{signs}_lead{lead}"] = gait_actions(targets, max_increment, limit)
    return out


def rollout_fn(env: hsa_mjx.HSAEnv):
    """jit(vmap) of one episode per action sequence: displacement, goal and mean reward components."""
    blocks = env.index.block_body

    def one(actions: jax.Array, key: jax.Array):
        state = env.reset(key)
        start = jnp.mean(state.pipeline_state.physics.xpos[blocks, :2], 0)

        def body(s, a):
            s = env.step(s, a)
            return s, (s.reward, {c: s.metrics[f"reward/{c}"] for c in COMPONENTS})

        end_state, (reward, parts) = jax.lax.scan(body, state, actions)
        end = jnp.mean(end_state.pipeline_state.physics.xpos[blocks, :2], 0)
        return end - start, end_state.pipeline_state.task.goal_xy, reward.mean(), jax.tree.map(jnp.mean, parts)

    return jax.jit(jax.vmap(one))


def sweep(seconds: float) -> list[dict]:
    """Every gait of the sweep in the corridor preset: one row each."""
    env = hsa_mjx.make_env(ec.from_dict({"physics": PHYSICS}, base=ec.get_preset("corridor")))
    layout = gaits.gait_layout(fidelity.load_mj_model(fidelity.fidelity_config()))
    control = env.config.control
    table = variants(layout, int(round(seconds / env.dt)), env.dt, control.max_increment, control.servo_target_limit)
    names = list(table)
    keys = jax.random.split(jax.random.PRNGKey(0), len(names))
    moved, goal, reward, parts = jax.device_get(rollout_fn(env)(jnp.asarray(np.stack(list(table.values()))), keys))
    return [{"gait": name, "seconds": seconds, "dx_m": round(float(moved[i][0]), 3), "dy_m": round(float(moved[i][1]), 3),
             "goal_x_m": round(float(goal[i][0]), 2), "reward_per_step": round(float(reward[i]), 4),
             **{c: round(float(parts[c][i]), 4) for c in COMPONENTS}} for i, name in enumerate(names)]


HEAD = ["gait", "dx_m", "dy_m", "goal_x_m", "reward_per_step", *COMPONENTS]


def main(argv: list[str] | None = None) -> None:
    """Run the sweep, print and write the table."""
    gait_sweep_cli(argv, "python -m benchmarks.gait_sweep", __doc__, "benchmarks/results/gait_sweep_corridor_cpu",
                   sweep, lambda seconds: f"Corridor preset, {seconds:g} s per open-loop gait: displacement (m; the "
                   "goal lies at goal_x on the corridor's line) and the mean per-step reward with its main components",
                   HEAD)


if __name__ == "__main__":
    main()
