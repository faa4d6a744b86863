"""The bare single-env C MuJoCo loop of an env's model: the ceiling one env on a CPU is measured against.

``mj_step`` x ``frame_skip`` through the env's control law (interpolated position targets from random
increments) and servo model, with no observation, reward, reset or Python env around it.
``benchmarks.speed.single_env`` interleaves it with the Gymnasium env's rounds; ``benchmarks.speed.throughput``
reports its rate beside the batched env's.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import mujoco
import numpy as np

import hsa_mjx
from hsa_mjx.sim import servo


def c_loop(env: hsa_mjx.HSAEnv, seed: int = 0) -> Callable[[int], float]:
    """The bare single-env C MuJoCo loop of the env's model and settings (random increments through the
    env's control law and servo model, no observation, reward or reset): ``run(n)`` plays ``n`` env
    steps and returns the seconds they took."""
    model, servos, ctl = env.robot.mj_model, env.index.servo_ids, env.config.control
    data = mujoco.MjData(model)
    data.qpos[env.index.block_z] = env.config.spawn_height
    mujoco.mj_forward(model, data)
    rng = np.random.default_rng(seed)
    ramp = np.arange(1, ctl.frame_skip + 1)[:, None] / ctl.frame_skip
    ramp = ramp if ctl.smooth_positions else np.ones_like(ramp)  # the env's control law

    def run(n: int) -> float:
        tic = time.perf_counter()
        for _ in range(n):
            start = data.ctrl[servos].copy()
            end = np.clip(
                start + ctl.max_increment * rng.uniform(-1, 1, len(servos)),
                -ctl.servo_target_limit,
                ctl.servo_target_limit,
            )
            for target in start + ramp * (end - start):
                servo.write_controls(model, data, env.index, env.motors, target)  # the env's servo model
                mujoco.mj_step(model, data)
        return time.perf_counter() - tic

    return run


def cpu_baseline(env: hsa_mjx.HSAEnv, seconds: float, seed: int = 0) -> dict[str, float]:
    """Single-env C MuJoCo on the host CPU (:func:`c_loop`) for about ``seconds``."""
    run, steps, spent = c_loop(env, seed), 0, 0.0
    while steps < 10 or spent < seconds:
        spent += run(10)
        steps += 10
    rate = steps / spent
    return {
        "cpu_mujoco_env_steps_per_s": round(rate, 1),
        "cpu_mujoco_physics_steps_per_s": round(rate * env.config.control.frame_skip, 1),
    }
