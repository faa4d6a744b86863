"""The deployment loop: an exported policy driving the robot at the control rate from its sensors alone.

The pieces a hardware port replaces are behind :class:`Robot` (``read()`` the sensors, ``command()``
the eight servo targets, ``wait()`` for the next control tick). :class:`SimulatedRobot` implements
it with the policy's own C MuJoCo model; a real robot implements the same three methods.

What the policy sees is built from :class:`Readings` only: the hinge encoders (angles and
velocities), the two blocks' positions from a tracker (their velocity is the tracker's finite
difference over one control step, not the simulator's velocity) and the controller's own servo
targets and clock. The observation is assembled by its slot labels (``policy.json``), so its order
is the training env's. Actions go through the training env's control law (increments of at most
``control.max_increment`` rad, targets clipped to the servo range, ramped over the substeps when
``control.smooth_positions``), after ``latency`` control steps. A policy with a history input
(``observation.history_steps``) gets its last observations and actions from the controller's own
record, built by the env's rule (``hsa_mjx.task.history``).
"""

from __future__ import annotations

import collections
import dataclasses
import time
from collections.abc import Callable
from typing import Any, Protocol

import mujoco
import numpy as np

from hsa_mjx.config import EnvConfig
from hsa_mjx.deploy.perturbation import ModelPerturbation, perturbed_model
from hsa_mjx.servo_config import resolve_servo
from hsa_mjx.sim import servo
from hsa_mjx.sim.model import RobotIndex
from hsa_mjx.task import history
from hsa_mjx.task.control import next_targets, substep_targets
from hsa_mjx.task.observation import GOAL_EPS, HEADING_EPS, SERVO_TARGET_LABELS, core_labels


@dataclasses.dataclass(frozen=True)
class Readings:
    """One control tick's sensor values."""

    hinge_angles: np.ndarray  # (8,) rad, action-slot order
    hinge_velocities: np.ndarray  # (8,) rad/s
    block_positions: np.ndarray  # (2, 3) m, block A and block B origins (a tracker)


class Robot(Protocol):
    """What the loop needs from a robot (simulated or real)."""

    def read(self) -> Readings: ...

    def command(self, targets: np.ndarray) -> None: ...

    def wait(self) -> None: ...


class SimulatedRobot:
    """The policy's model in C MuJoCo: ``command`` runs the ``frame_skip`` substeps of one control tick.

    Args:
        mj_model: the compiled scene (``hsa_mjx.sim.model.load_mj_model`` of the policy's env config).
        index: its name index.
        config: the env config (spawn height, control settings).
        realtime: sleep so that each tick lasts ``config.dt`` of wall time (as on hardware).
        perturbation: a robot unlike the model (friction, masses, springs, servo gain and torque limit),
            written into a copy of ``mj_model`` (``hsa_mjx.deploy.perturbation``); None: the model as it is.
    """

    def __init__(
        self,
        mj_model: mujoco.MjModel,
        index: RobotIndex,
        config: EnvConfig,
        realtime: bool = False,
        perturbation: ModelPerturbation | None = None,
    ):
        if perturbation is not None and not perturbation.nominal:
            mj_model = perturbed_model(mj_model, index, perturbation)
        self.model, self.index, self.config, self.realtime = mj_model, index, config, realtime
        self.motors = resolve_servo(config.servo)  # DC-motor servos' figures; None: the asset's springs
        self.data = mujoco.MjData(mj_model)
        self.data.qpos[index.block_z] = config.spawn_height
        mujoco.mj_forward(mj_model, self.data)
        self._targets = np.zeros(len(index.servo_ids))
        self._tick = time.perf_counter()

    def read(self) -> Readings:
        """Encoders and tracker, exact (noise is the loop's to add)."""
        d, idx = self.data, self.index
        return Readings(
            np.array(d.qpos[idx.joint_qpos]), np.array(d.qvel[idx.joint_qvel]), np.array(d.xpos[idx.block_body])
        )

    def command(self, targets: np.ndarray) -> None:
        """Move the servo targets to ``targets`` over one control tick (ramped or held)."""
        control = self.config.control
        targets = np.asarray(targets, np.float64)
        for target in substep_targets(self._targets, targets, control.frame_skip, control.smooth_positions, xp=np):
            servo.write_controls(self.model, self.data, self.index, self.motors, target)
            mujoco.mj_step(self.model, self.data)
        self._targets = targets

    def wait(self) -> None:
        """Sleep to the next tick when ``realtime``."""
        if self.realtime:
            self._tick += self.config.dt
            time.sleep(max(0.0, self._tick - time.perf_counter()))


def _hinge_entries(angles: np.ndarray, mode: str) -> dict[str, float]:
    """The hinge angle slots for the observation's ``hinge_angles`` mode."""
    if mode == "sincos":
        return {
            **{f"hinge_sin_{i}": v for i, v in enumerate(np.sin(angles))},
            **{f"hinge_cos_{i}": v for i, v in enumerate(np.cos(angles))},
        }
    if mode == "wrapped":
        angles = np.mod(angles + np.pi, 2.0 * np.pi) - np.pi
    return {f"hinge_angle_{i}": v for i, v in enumerate(angles)}


def observation_entries(
    readings: Readings,
    velocity: np.ndarray,
    goal_xy: np.ndarray,
    targets: np.ndarray,
    time_s: float,
    config: EnvConfig,
    tracked_xy: np.ndarray | None = None,
) -> dict[str, float]:
    """Every observation slot the env can have, by label, from the sensors and the controller's state
    (``tracked_xy``: the tracker's reading for the position entries; the goal entries use the blocks')."""
    obs_cfg = config.observation
    blocks = readings.block_positions
    position = blocks[:, :2].mean(axis=0)
    delta = np.asarray(goal_xy, np.float64) - position
    distance = float(np.linalg.norm(delta))
    direction = delta / (distance + GOAL_EPS)
    heading = (blocks[1, :2] - blocks[0, :2]) / (np.linalg.norm(blocks[1, :2] - blocks[0, :2]) + HEADING_EPS)
    cos, sin = heading
    entries = {
        **_hinge_entries(readings.hinge_angles, obs_cfg.hinge_angles),
        **{f"hinge_velocity_{i}": v for i, v in enumerate(readings.hinge_velocities)},
        "robot_x": position[0] if tracked_xy is None else tracked_xy[0],
        "robot_y": position[1] if tracked_xy is None else tracked_xy[1],
        "block_vx": velocity[0],
        "block_vy": velocity[1],
        "block_vz": velocity[2],
        "goal_distance": distance,
        "goal_dir_x": direction[0],
        "goal_dir_y": direction[1],
        "heading_cos": cos,
        "heading_sin": sin,
        "goal_dir_ahead": cos * direction[0] + sin * direction[1],
        "goal_dir_left": cos * direction[1] - sin * direction[0],
        **{f"servo_target_{i}": v for i, v in enumerate(targets)},
    }
    if obs_cfg.clock_period_s > 0:
        phase = 2.0 * np.pi * np.mod(time_s / obs_cfg.clock_period_s, 1.0)
        entries.update(clock_sin=np.sin(phase), clock_cos=np.cos(phase))
    return entries


def check_deployable(config: EnvConfig, labels: list[str]) -> None:
    """ValueError when the policy needs an input a robot does not read (the terrain height scan, the path
    direction over the terrain's map)."""
    if config.observation.height_scan.enabled:
        raise ValueError(
            "this policy reads a terrain height scan, which the deployment loop has no sensor "
            "for; deploy a policy without observation.height_scan (e.g. flat)"
        )
    if config.observation.path_direction:
        raise ValueError(
            "this policy reads the path direction to its goal from the terrain's distance fields, which "
            "the deployment loop has no map for; deploy a policy without observation.path_direction"
        )
    entries = observation_entries(
        Readings(np.zeros(8), np.zeros(8), np.zeros((2, 3))), np.zeros(3), np.zeros(2), np.zeros(8), 0.0, config
    )
    missing = [label for label in labels if label not in entries and not history.is_history(label)]
    if missing:
        raise ValueError(f"the deployment loop cannot build observation slots {missing}")
    past = [label for label in labels if history.is_history(label)]
    steps = config.observation.history_steps
    expected = history.labels(core_labels(config.observation), steps, len(SERVO_TARGET_LABELS))
    if tuple(past) != expected or labels[len(labels) - len(past) :] != past:
        raise ValueError(
            f"the policy's history slots do not follow observation.history_steps = {steps} "
            "(hsa_mjx.task.history); the deployment loop cannot feed them"
        )


@dataclasses.dataclass
class Controller:
    """Policy, latency queue and the control law: ``act(readings, goal)`` -> the next servo targets."""

    policy: Callable[[np.ndarray], np.ndarray]
    labels: list[str]
    config: EnvConfig
    action_size: int
    latency: int = 0
    # applied to this tick's observation, without the history (e.g. a sim-to-real test)
    noise: Callable[[np.ndarray], np.ndarray] | None = None
    # m of uniform jitter per axis on each tracker reading of the robot (its position and differenced
    # velocity entries); None: the policy's own (observation.noise.position with velocity 'differenced')
    tracker_noise: float | None = None
    seed: int = 0

    def __post_init__(self):
        if self.latency < 0:
            raise ValueError(f"latency must be >= 0 control steps, got {self.latency}")
        self.targets = np.zeros(self.action_size)  # the servo targets at reset, as in the env
        self.queue: collections.deque = collections.deque([np.zeros_like(self.targets)] * self.latency)
        self.previous: np.ndarray | None = None
        self.steps = 0
        self.history_steps = self.config.observation.history_steps
        self.core_size = len(core_labels(self.config.observation))
        self.history = np.zeros(history.size(self.core_size, self.history_steps, self.action_size), np.float32)
        self.last_obs = np.zeros(0, np.float32)
        if self.tracker_noise is None:
            obs_cfg = self.config.observation
            self.tracker_noise = obs_cfg.noise.position if obs_cfg.velocity == "differenced" else 0.0
        self.rng = np.random.default_rng(self.seed)

    def observe(self, readings: Readings, goal_xy: np.ndarray) -> np.ndarray:
        """The policy's observation from this tick's readings (velocity by finite difference of the
        tracker's readings, each with ``tracker_noise`` of jitter)."""
        now = readings.block_positions.mean(axis=0)
        if self.tracker_noise:
            now = now + self.rng.uniform(-self.tracker_noise, self.tracker_noise, 3)
        velocity = np.zeros(3) if self.previous is None else (now - self.previous) / self.config.dt
        self.previous = now
        entries = observation_entries(
            readings, velocity, goal_xy, self.targets, self.steps * self.config.dt, self.config, now[:2]
        )
        now_labels = self.labels[: len(self.labels) - self.history.shape[0]]
        obs = np.asarray([entries[label] for label in now_labels], np.float32)
        self.last_obs = obs if self.noise is None else np.asarray(self.noise(obs), np.float32)
        return np.concatenate([self.last_obs, self.history])

    def act(self, readings: Readings, goal_xy: np.ndarray) -> np.ndarray:
        """The servo targets to command this tick (the action of ``latency`` ticks ago applied)."""
        action = np.asarray(self.policy(self.observe(readings, goal_xy)), np.float64).reshape(-1)
        action = np.clip(np.where(np.isfinite(action), action, 0.0), -1.0, 1.0)
        core = self.last_obs[: self.core_size]
        self.history = history.advance(self.history, core, action, self.history_steps, np)
        self.queue.append(action)
        applied = self.queue.popleft()
        control = self.config.control
        self.targets = next_targets(self.targets, applied, control.max_increment, control.servo_target_limit, xp=np)
        self.steps += 1
        return self.targets


def play(targets: np.ndarray, robot: Robot) -> np.ndarray:
    """Play a test signal (``hsa_mjx.sysid``): each row of ``targets`` (ticks, 8) commanded for one control
    tick; the hinge angles read at each tick before its command, (ticks, 8): a log's angle columns."""
    angles = []
    for row in np.asarray(targets, np.float64):
        angles.append(robot.read().hinge_angles)
        robot.command(row)
        robot.wait()
    return np.asarray(angles)


def run(
    controller: Controller, robot: Robot, goal_xy: np.ndarray, max_steps: int, success_radius: float
) -> dict[str, Any]:
    """Drive ``robot`` to ``goal_xy``: until within ``success_radius`` or ``max_steps`` ticks; a summary."""
    goal_xy = np.asarray(goal_xy, np.float64)
    start = robot.read().block_positions[:, :2].mean(axis=0)
    path = [start]
    for step in range(1, max_steps + 1):  # noqa: B007  (the count of ticks taken, read after the loop)
        robot.command(controller.act(robot.read(), goal_xy))
        robot.wait()
        path.append(robot.read().block_positions[:, :2].mean(axis=0))
        if np.linalg.norm(path[-1] - goal_xy) < success_radius:
            break
    final = float(np.linalg.norm(path[-1] - goal_xy))
    return {
        "reached": final < success_radius,
        "steps": step,
        "seconds": step * controller.config.dt,
        "start_distance": float(np.linalg.norm(start - goal_xy)),
        "final_distance": final,
        "path": np.asarray(path),
    }


# ----- set-up from a policy file ------------------------------------------------------------------
def policy_env(meta: dict) -> tuple[EnvConfig, list[str], tuple[float, float]]:
    """(env config, observation labels, goal range it trained for) from a policy's ``policy.json``
    (ValueError when its observation needs an input the loop cannot read)."""
    from hsa_mjx.config import from_dict

    saved = meta.get("config", {})
    config = from_dict(saved.get("env", {}))
    labels = list(meta["observation"]["labels"])
    check_deployable(config, labels)
    curriculum = saved.get("curriculum", {})
    target = curriculum.get("target_range") if curriculum.get("enabled") else None
    return config, labels, tuple(target or config.goal.radial_range)


def latency_steps(ms: float, dt: float) -> int:
    """Control ticks of ``ms`` milliseconds (ValueError unless a whole number >= 0)."""
    steps = ms / 1000.0 / dt
    if ms < 0 or abs(steps - round(steps)) > 1e-6:
        raise ValueError(f"latency must be a whole number >= 0 of {dt * 1000:g} ms control ticks, got {ms} ms")
    return int(round(steps))


def load_model(config: EnvConfig) -> tuple[mujoco.MjModel, RobotIndex]:
    """The env's compiled C MuJoCo scene and its name index."""
    from hsa_mjx.sim.model import build_index, load_mj_model

    mj_model = load_mj_model(config)
    return mj_model, build_index(mj_model)
