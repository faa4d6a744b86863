"""What the policy and the privileged critic see of one env, as pure functions of the physics and task states.

``Observer`` holds an env config's static observation pieces (the scan's points and rest height, the
noise scales, where the history rows start) and builds the policy's observation
(``hsa_mjx.task.observation``, with the optional height scan, path direction and noise) and its
history rows (``hsa_mjx.task.history``) at a reset, after a goal change and after a step, with the
critic's inputs (``hsa_mjx.task.privileged``) when the env has a privileged critic.
"""

from __future__ import annotations

import copy

import jax
import jax.numpy as jnp
import numpy as np

from hsa_mjx.config import EnvConfig
from hsa_mjx.sim.backend import mjx
from hsa_mjx.sim.model import RobotModel
from hsa_mjx.task import history, observation, privileged, randomization
from hsa_mjx.task.progress import GoalProgress
from hsa_mjx.task.types import TaskState
from hsa_mjx.terrain import height_scan
from hsa_mjx.terrain.placement import Footprint

Seen = tuple[jax.Array, jax.Array | None, TaskState]  # (observation, critic inputs or None, task state)


class Observer:
    """The observations of one env config on its terrain (static); the task state carries the noise keys."""

    def __init__(self, config: EnvConfig, robot: RobotModel, goal_progress: GoalProgress, privileged_critic: bool):
        cfg = config.observation
        self.config, self.index, self.progress = config, robot.index, goal_progress
        self.privileged = privileged_critic
        self.size = observation.observation_size(cfg)
        self.core_size = len(observation.core_labels(cfg))  # a history row's observation part
        self.history_start = self.size - history.size(self.core_size, cfg.history_steps, len(robot.index.servo_ids))
        self._scan_points = jnp.asarray(height_scan.local_points(cfg.height_scan))
        self._tracked = cfg.velocity == "differenced"  # the tracker's readings carry the position noise
        labels = observation.observation_labels(cfg)[: self.history_start]
        self._noise = randomization.noise_scales(labels, cfg.noise, tracked=self._tracked)
        # block-origin height above level ground with the robot resting on it: the scan's zero
        self._rest_height = float(np.max(Footprint.from_model(robot.mj_model, robot.index.block_body).drop))

    def with_progress(self, goal_progress: GoalProgress) -> Observer:
        """This observer reading another terrain (the goal measures and ground of ``goal_progress``)."""
        other = copy.copy(self)
        other.progress = goal_progress
        return other

    def at_reset(self, data: mjx.Data, task: TaskState, path: jax.Array) -> Seen:
        """A new episode's observation: its history rows are zeros. ``path`` is the goal progress's measured
        direction at the robot (``GoalProgress.measure``), read only by ``observation.path_direction``."""
        obs, critic, task = self._current(data, task, path, 0.0, "reset")
        return self._with_rows(obs, jnp.zeros((self.size - self.history_start,), jnp.float32)), critic, task

    def after_goal_change(
        self, data: mjx.Data, task: TaskState, path: jax.Array, time_s: jax.Array, previous: jax.Array
    ) -> Seen:
        """The observation with a new goal, mid-step: the history rows of ``previous`` stay (and the
        tracker's readings: no new one)."""
        obs, critic, task = self._current(data, task, path, time_s, "keep")
        return self._with_rows(obs, previous[self.history_start :]), critic, task

    def after_step(
        self,
        data: mjx.Data,
        task: TaskState,
        path: jax.Array,
        time_s: jax.Array,
        previous: jax.Array,
        action: jax.Array,
    ) -> Seen:
        """The observation after a step: ``previous`` (with ``action``) becomes the newest history row."""
        obs, critic, task = self._current(data, task, path, time_s)
        steps = self.config.observation.history_steps
        if steps:  # static: without a history the step computes none
            rows = history.advance(previous[self.history_start :], previous[: self.core_size], action, steps, jnp)
            obs = self._with_rows(obs, rows)
        return obs, critic, task

    def _with_rows(self, obs: jax.Array, rows: jax.Array) -> jax.Array:
        """The observation with its history rows appended (unchanged without a history)."""
        if self.config.observation.history_steps == 0:
            return obs
        return jnp.concatenate([obs, rows])

    def _current(
        self, data: mjx.Data, task: TaskState, path: jax.Array, time_s: jax.Array | float, reading: str = "read"
    ) -> Seen:
        """The observation without history rows, the critic's inputs and the task state (its key advanced
        when the scan, the tracker or the observation draws noise). ``reading``: the tracker reads anew
        (``read``), starts an episode (``reset``: no velocity yet) or keeps its readings (``keep``)."""
        cfg = self.config.observation
        clean = scan = tracked = None
        if cfg.height_scan.enabled:
            clean, scan, task = self._height_scan(data, task)
        if self._tracked:  # static: without the tracker the key stream stays as it was
            tracked, task = self._track(data, task, reading)
        obs = observation.observe(
            data, task.goal_xy, self.index, cfg, time_s, scan, path if cfg.path_direction else None, tracked
        )
        if cfg.noise.enabled:  # static: without noise the key stream stays as it was
            rng, key = jax.random.split(task.rng)
            task, obs = task.replace(rng=rng), randomization.add_noise(obs, key, self._noise)
        if not self.privileged:
            return obs, None, task
        clean = jnp.zeros((0,), jnp.float32) if clean is None else clean
        true_model = (
            randomization.true_model(task.randomization, self.config.randomization)
            if self.config.randomization.draws
            else jnp.zeros((0,), jnp.float32)
        )
        level = self.progress.world.level_fraction(task.tile)
        critic = privileged.inputs(data, self.index, clean, task.terrain_id, level, true_model)
        return obs, critic, task

    def _track(self, data: mjx.Data, task: TaskState, reading: str) -> tuple[tuple[jax.Array, jax.Array], TaskState]:
        """The position tracker: ((xy, velocity) of its newest readings, task state). A reading is the
        blocks' midpoint with uniform jitter of +-``noise.position`` per axis; the velocity is the last
        two readings' difference over one control step, zero at reset (as ``hsa_mjx.deploy.loop``)."""
        readings = task.tracker
        if reading != "keep":
            rng, key = jax.random.split(task.rng)
            jitter = self.config.observation.noise.position * jax.random.uniform(key, (3,), jnp.float32, -1.0, 1.0)
            now = jnp.mean(data.xpos[self.index.block_body], axis=0) + jitter
            readings = jnp.stack([now, now]) if reading == "reset" else jnp.stack([readings[1], now])
            task = task.replace(rng=rng, tracker=readings)
        return (readings[1, :2], (readings[1] - readings[0]) / self.config.dt), task

    def _height_scan(self, data: mjx.Data, task: TaskState) -> tuple[jax.Array, jax.Array, TaskState]:
        """(noise-free scan, the policy's noisy copy, task state) as the observation holds them."""
        cfg = self.config.observation.height_scan
        heights = height_scan.read(
            lambda xy: self.progress.world.ground(task.tile, xy),
            self._scan_points,
            observation.robot_xy(data, self.index),
            observation.heading(data, self.index),
            jnp.mean(data.xpos[self.index.block_body, 2]),
            self._rest_height,
        )
        noisy = heights
        if cfg.noise > 0:  # static: without noise the key stream stays as it was
            rng, key = jax.random.split(task.rng)
            task, noisy = task.replace(rng=rng), height_scan.add_noise(heights, key, cfg)
        return height_scan.shape(heights, cfg), height_scan.shape(noisy, cfg), task
