"""Sim-to-sim: a policy scored by ``benchmarks.robustness.score`` on MJX, played again on C MuJoCo.

Each cell's episodes run through the deployment loop (``hsa_mjx.deploy.loop``: the policy sees only
sensor readings, actions go through the control law after the cell's latency) against a
``SimulatedRobot`` carrying the cell's model (``ModelPerturbation``) and its observation noise, to the
goals the MJX episodes had. Cells with pushes are left out (the loop has no pushes). An episode ends
at the goal or after the step limit; with ``--qacc-rule off`` the MJX episodes also end only on
simulator health, which a stable C simulation does not trip. Episodes run in worker processes (one C
MuJoCo model each; ``--workers 1``: in this process).
"""

from __future__ import annotations

import dataclasses
import functools
import multiprocessing
import os
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.robustness import grids
from benchmarks.stats import paired_difference_interval, wilson_interval

PHYSICS = "c_mujoco"


def perturbation_of(cell: dict[str, Any]):
    """The cell's model as a ``ModelPerturbation``."""
    from hsa_mjx.deploy.perturbation import ModelPerturbation

    return ModelPerturbation(**{name: cell[name] for name in grids.MODEL})


def play_episode(directory: str, cell: dict[str, Any], goal: list[float], max_steps: int | None, seed: int) -> bool:
    """One episode of the deployment loop on the cell's robot; whether it reached the goal."""
    from hsa_mjx.deploy import loop
    from hsa_mjx.randomization_config import ObservationNoiseConfig
    from hsa_mjx.task.history import is_history
    from hsa_mjx.task.randomization import noise_scales

    policy, config, labels, (mj_model, index) = _loaded(directory, cell["servo"])
    if cell["servo"] is None and config.servo.model != "spring":  # the gain and torque cells as motor figures
        cell, figures = grids.dc_motor_cell(cell, config.servo.stall_torque)
        config = dataclasses.replace(config, servo=scaled_motor(config.servo, *figures[:2]))
    noise, tracked = None, config.observation.velocity == "differenced"
    if cell["noise"]:  # on this tick's readings; a history repeats what the policy saw
        sensed = tuple(label for label in labels if not is_history(label))
        scales = noise_scales(sensed, ObservationNoiseConfig(**grids.NOISE), tracked=tracked)
        rng = np.random.default_rng(seed)
        noise = lambda obs: obs + scales * rng.uniform(-1.0, 1.0, obs.shape).astype(np.float32)  # noqa: E731
    latency = loop.latency_steps(cell["latency_ms"], config.dt)
    jitter = grids.NOISE["position"] if cell["noise"] and tracked else 0.0  # the tracker's, as the env's
    controller = loop.Controller(policy, labels, config, policy.action_size, latency, noise, jitter, seed)
    robot = loop.SimulatedRobot(mj_model, index, config, perturbation=perturbation_of(cell))
    steps = max_steps or config.termination.max_episode_steps
    return bool(loop.run(controller, robot, np.asarray(goal), steps, config.goal.success_radius)["reached"])


def scaled_motor(motor, stall: float, speed: float):
    """A DC-motor ``ServoConfig`` with its stall torque and no-load speed scaled, its loop gains held at the
    nominal motor's (as the MJX env scales its figures: ``hsa_mjx.task.randomization.servo_fields``)."""
    from hsa_mjx.servo_config import resolve_servo

    nominal = resolve_servo(motor)
    return dataclasses.replace(
        motor,
        stall_torque=stall * motor.stall_torque,
        no_load_speed=speed * motor.no_load_speed,
        kp=nominal.kp,
        speed_gain=nominal.speed_gain,
    )


@functools.lru_cache(maxsize=8)
def _loaded(directory: str, servo_class: str | None = None) -> tuple:
    """(policy, env config, observation labels, (C model, index)) of a policy directory, its servos
    replaced by robot profile ``servo_class``'s where given; once per worker. The cell's model is the
    perturbation's alone: the ranges the policy trained over (a spring servo's gain and torque limit
    among them, which a DC-motor servo refuses) are dropped, as the MJX rollout drops them."""
    from hsa_mjx.deploy import loop, policy_file
    from hsa_mjx.randomization_config import RandomizationConfig
    from hsa_mjx.robots import profile_servo

    policy = policy_file.load_policy(Path(directory))
    config, labels, _ = loop.policy_env(policy.meta)
    if servo_class is not None:
        config = dataclasses.replace(config, servo=profile_servo(servo_class), randomization=RandomizationConfig())
    return policy, config, labels, loop.load_model(config)


def play_cells(
    directory: Path, rows: list[dict], max_steps: int | None, qacc_rule: bool, workers: int | None
) -> list[dict[str, Any]]:
    """Each MJX row's episodes (no pushes) on C MuJoCo, to the same goals: a sim-to-sim row per cell."""
    chosen = [r for r in rows if not r["pushes"]]
    jobs = [(str(directory), _cell(r), goal, max_steps, i) for r in chosen for i, goal in enumerate(r["goals"])]
    if workers == 1:  # in this process: no interpreter to start
        reached = [play_episode(*job) for job in jobs]
    else:
        context = multiprocessing.get_context("spawn")  # a clean interpreter: no JAX or GPU state inherited
        with ProcessPoolExecutor(workers or os.cpu_count(), mp_context=context, initializer=_on_the_cpu) as pool:
            reached = list(pool.map(play_episode, *zip(*jobs), chunksize=4))
    out, start = [], 0
    for r in chosen:
        n = len(r["goals"])
        played = np.asarray(reached[start : start + n], bool)
        successes = int(played.sum())
        start += n
        low, high = wilson_interval(successes, n)
        pairs = paired_counts(played, np.asarray(r["reached"], bool))
        _, gap_low, gap_high = paired_difference_interval(*pairs)
        out.append(
            {
                **_cell(r),
                "label": r["label"],
                "physics": PHYSICS,
                "qacc_rule": "on" if qacc_rule else "off",
                "successes": successes,
                "episodes": n,
                "success_rate": successes / n,
                "ci95": [low, high],
                "mjx_success_rate": r["success_rate"],
                "mjx_ci95": r["ci95"],
                "gap": successes / n - r["success_rate"],
                "gap_ci95": [gap_low, gap_high],  # paired: the same goals and starts on both
                "pairs": dict(zip(("both", "c_only", "mjx_only", "neither"), pairs)),
            }
        )
    return out


def paired_counts(c_mujoco: np.ndarray, mjx: np.ndarray) -> tuple[int, int, int, int]:
    """The episodes' 2 x 2 table of outcomes on the two physics: (both reached, C only, MJX only, neither)."""
    return (
        int(np.sum(c_mujoco & mjx)),
        int(np.sum(c_mujoco & ~mjx)),
        int(np.sum(~c_mujoco & mjx)),
        int(np.sum(~c_mujoco & ~mjx)),
    )


def _on_the_cpu() -> None:
    """A worker's JAX on the CPU: the loop's few JAX calls (the perturbed model fields) need no GPU, and
    sixteen workers each taking a GPU context would fill its memory."""
    os.environ["JAX_PLATFORMS"] = "cpu"
    import jax

    jax.config.update("jax_platforms", "cpu")


def _cell(row: dict[str, Any]) -> dict[str, Any]:
    """The factors of a result row."""
    return {name: row[name] for name in grids.FACTORS}
