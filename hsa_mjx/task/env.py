"""HSAEnv: the HSA crawling task as pure ``reset``/``step`` functions over an MJX model (Brax ``Env``).

Wiring only: control, physics, observation, reward, termination and goals live in their modules.
"""

from __future__ import annotations

import copy
import dataclasses
from collections.abc import Callable
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from brax.envs.base import Env as BraxEnv

from hsa_mjx import pose
from hsa_mjx.config import EnvConfig
from hsa_mjx.robots import drawn_servos, env_motors
from hsa_mjx.servo_config import resolve_servo
from hsa_mjx.sim import backend, physics
from hsa_mjx.sim.backend import mjx
from hsa_mjx.sim.host_physics import HostPhysics
from hsa_mjx.sim.model import RobotModel, compiled_kinematics, load_robot, local_device
from hsa_mjx.task import (
    control,
    goals,
    observation,
    outcome,
    privileged,
    progress,
    randomization,
    reward,
)
from hsa_mjx.task.metrics import reset_metrics, step_metrics
from hsa_mjx.task.observer import Observer
from hsa_mjx.task.params import EnvParams
from hsa_mjx.task.types import EnvState, PhysicsCall, SimState, TaskState
from hsa_mjx.terrain.world import TerrainWorld

GOAL_MARKER_Z = 0.1
Simulate = Callable[[mjx.Data, jax.Array, dict], tuple[mjx.Data, physics.SubstepStats]]


class HSAEnv(BraxEnv):
    """The HSA two-block robot crawling to per-env goals, as a jittable, vmappable Brax env.

    ``reset(rng)`` and ``step(state, action)`` are pure functions of their arguments (the model
    and config are fixed at construction); vmap them for a batch. Actions are 8 normalised
    increments in [-1, 1] (non-finite entries become 0, counted in ``metrics["nonfinite_action"]``).
    ``state.done`` is 1.0 when the episode terminated (``metrics["termination/<reason>"]``) or was
    truncated at ``max_episode_steps`` (``info["truncation"]``).

    On the terrain scene each env draws its own terrain tile at every reset from the run's pool
    (``config.terrain``: types, proportions, generator parameters, tiles per type; ``per_env:
    false`` shares one), spawns resting on it, and measures block heights from the ground under
    each block (see ``docs/terrain.md``).

    With ``config.randomization`` each env draws its own physical scales, action latency and push
    times at every reset and ``observation.noise`` adds noise to its observation (all off by
    default; ``hsa_mjx.task.randomization``, ``docs/robustness.md``).

    Args:
        config: the environment config.
        asset_dir: where the scene XMLs are (default: the repository's ``assets/``).
        num_envs: how many envs ``reset``/``step`` will be vmapped over. Only the Warp backend
            uses it: the envs of a batch share one contact buffer of
            ``physics.contacts_per_env * num_envs`` slots (the batch wrappers check it).
        privileged: also put the privileged critic inputs (``hsa_mjx.task.privileged``) into
            ``state.info["privileged_obs"]`` (the PPO learner's ``ppo.privileged_critic``).
    """

    def __init__(self, config: EnvConfig, asset_dir: Path | None = None, num_envs: int = 1, privileged: bool = False):
        if isinstance(num_envs, bool) or not isinstance(num_envs, (int, np.integer)) or num_envs < 1:
            raise ValueError(f"num_envs must be an integer >= 1, got {num_envs!r}")
        self.config, self.num_envs, self.privileged = config, int(num_envs), bool(privileged)
        self.robot: RobotModel = load_robot(config, asset_dir)
        self.index = self.robot.index
        spiral_sites = config.goal.mode == "spiral" and config.reward.progress == "geodesic"
        self.world = TerrainWorld(
            config.terrain,
            self.robot.pool,
            self.robot.mj_model,
            self.index.block_body,
            goals.spiral_checkpoints(config.goal, config.terrain.spiral) if spiral_sites else None,
        )
        self.progress = progress.GoalProgress(config, self.world)
        self.observer = Observer(config, self.robot, self.progress, self.privileged)
        self.weights = reward.RewardWeights.from_config(config.reward)
        self.motors = env_motors(config.servo, config.randomization.robots)  # None: the asset's springs
        # physics.backend c: the substeps in C MuJoCo on the host (one env after another under vmap)
        self._host = HostPhysics(self.robot.mj_model, self.index, self.motors) if self.robot.backend == "c" else None
        self._init_static_arrays()

    def _init_static_arrays(self) -> None:
        """Precompute the reset state and static addresses once."""
        cfg, model = self.config, self.robot.mjx_model
        data = backend.make_data(
            self.robot.mj_model,
            self.robot.backend,
            local_device(),
            self.num_envs,
            cfg.physics.contacts_per_env,
            cfg.physics.constraints_per_env,
        )
        qpos = data.qpos.at[self.index.block_z].set(cfg.spawn_height)
        self._data0 = compiled_kinematics(model, data.replace(qpos=qpos))
        self._checkpoints = jnp.asarray(
            goals.spiral_checkpoints(cfg.goal, cfg.terrain.spiral)
            if cfg.goal.mode == "spiral"
            else np.zeros((1, 2), np.float32)
        )
        self._radial_range = jnp.asarray(cfg.goal.radial_range, jnp.float32)
        self._origin = observation.robot_xy(self._data0, self.index)  # the spawn pose's position
        own, robots = resolve_servo(cfg.servo), tuple(drawn_servos(cfg.randomization.robots))
        self._nominal = randomization.NominalModel.from_model(self.robot.mj_model, self.index, own, robots)

    def with_terrain(self, tiles) -> HSAEnv:
        """This env on the terrain ``tiles`` (``hsa_mjx.terrain.regeneration.TerrainTiles``, traced): the
        physics' heightfield, the ground, goals and distance fields all read them."""
        env = copy.copy(self)
        env.world = self.world.with_tiles(tiles)
        env.robot = dataclasses.replace(self.robot, mjx_model=self.robot.mjx_model.replace(hfield_data=tiles.atlas))
        env.progress = progress.GoalProgress(self.config, env.world)
        env.observer = self.observer.with_progress(env.progress)
        return env

    # ----- Brax Env interface -------------------------------------------------------------
    @property
    def observation_size(self) -> int:
        """Observation length: the original's 24 plus the enabled optional entries (``observation``)."""
        return observation.observation_size(self.config.observation)

    @property
    def action_size(self) -> int:
        return len(self.index.servo_ids)

    @property
    def privileged_size(self) -> int:
        """Length of ``info["privileged_obs"]`` (0 unless built with ``privileged=True``)."""
        return privileged.size(self.config.observation, self.config.randomization) if self.privileged else 0

    @property
    def backend(self) -> str:
        """Brax's pipeline name (always ``"mjx"``); ``physics_backend`` says which physics steps it."""
        return "mjx"

    @property
    def host_physics(self) -> HostPhysics | None:
        """The C MuJoCo substeps a ``physics.backend: c`` env steps with (``step`` is ``step_with`` them),
        else None."""
        return self._host

    @property
    def physics_backend(self) -> str:
        """The physics this env steps with: ``"jax"`` or ``"warp"`` (MJX) or ``"c"`` (C MuJoCo substeps)."""
        return self.robot.backend

    def warm_up_physics(self, all_at_once: bool = False) -> float | None:
        """On MJX's Warp backend, one physics step of one env, so the kernels MuJoCo Warp makes for this
        model's sizes build now (``hsa_mjx.sim.warp_kernels.warm_up``): its seconds. ``all_at_once``: a dry
        run of the step names them and threads build them together (``warp_kernels.build_for_model``;
        only in a process that discards its results). None on the other backends (nothing to build)."""
        if self.robot.backend != "warp":
            return None
        from hsa_mjx.sim import warp_kernels

        build = warp_kernels.build_for_model if all_at_once else warp_kernels.warm_up
        return build(self.robot.mjx_model, self._data0)

    @property
    def spawn_xy(self) -> jax.Array:
        """Where the robot starts an episode (its position at the spawn pose), (2,): goal distances count from here."""
        return self._origin

    @property
    def dt(self) -> float:
        """Seconds per env step (timestep x frame_skip)."""
        return self.config.dt

    def default_params(self) -> EnvParams:
        """The episode parameters of the config: its radial goal range, terrain drawn by proportion."""
        return EnvParams.make(self._radial_range)

    def reset(self, rng: jax.Array, params: EnvParams | None = None) -> EnvState:
        """Start an episode: the robot at rest at its spawn pose and a goal drawn from ``rng``.

        ``params`` (traced; default :meth:`default_params`): the radial goal range and the terrain cell
        to draw a tile of, as a curriculum chooses them per env.
        """
        return self._reset(rng, self.default_params() if params is None else params)

    def reset_at_checkpoint(self, rng: jax.Array, index: int | jax.Array) -> EnvState:
        """Start a spiral episode at checkpoint ``index``, as ``goal.track_starts`` would draw it.

        Index 0 is the original start; k > 0 stands the robot on checkpoint k - 1, facing
        checkpoint k, its goal. A traced ``index`` is clipped to 0..num_checkpoints - 1.

        Raises:
            ValueError: the env's goal mode is not ``spiral``, or a Python ``index`` is out of range.
        """
        goal = self.config.goal
        if goal.mode != "spiral":
            raise ValueError(f"reset_at_checkpoint needs goal.mode 'spiral', got {goal.mode!r}")
        if isinstance(index, (int, np.integer)) and not 0 <= index < goal.num_checkpoints:
            raise ValueError(f"checkpoint index must be in 0..{goal.num_checkpoints - 1}, got {index}")
        index = jnp.clip(jnp.asarray(index, jnp.int32), 0, goal.num_checkpoints - 1)
        return self._reset(rng, self.default_params(), index)

    def _reset(self, rng: jax.Array, params: EnvParams, start_index: jax.Array | None = None) -> EnvState:
        """The reset behind the public ones; ``start_index`` forces a track start there."""
        rng, goal_key = jax.random.split(rng)
        terrain_key = None
        if self.world.per_env:  # only then: plane scenes keep their key stream
            rng, terrain_key = jax.random.split(rng)
        tile, terrain_id = self.world.draw(terrain_key, params.terrain_cell)
        drawn = randomization.nominal_state(self.config.randomization, self.action_size)
        if self.config.randomization.draws:  # static: without randomization the key stream stays as it was
            rng, draw_key = jax.random.split(rng)
            drawn = randomization.reset_state(
                draw_key, self.config.randomization, self.action_size, self.dt, params.randomization_scale
            )
        if self.config.goal.track_starts or start_index is not None:  # static; off keeps the key stream
            rng, start_key = jax.random.split(rng)
            index, goal_xy, move = self._track_start(start_key, start_index)
        else:
            index, move = jnp.zeros((), jnp.int32), None
            goal_xy = goals.initial_goal(goal_key, self.config, params.goal_range, self._checkpoints, terrain_id)
        site, goal_xy = self.progress.place_goal(goal_key, tile, terrain_id, params.goal_range, index, goal_xy)
        data = self._with_goal_marker(self._spawn(tile, move), goal_xy, tile)
        task = TaskState.start(
            self.action_size,
            self.config.reward.stagnation_window,
            goal_xy=goal_xy,
            checkpoints=self._checkpoints,
            checkpoint_index=index,
            rng=rng,
            tile=tile,
            terrain_id=terrain_id,
            site=site,
            randomization=drawn,
        )
        distance, direction = self.progress.measure(task, observation.robot_xy(data, self.index))
        task = task.replace(prev_distance=distance, start_distance=distance)
        obs, critic, task = self.observer.at_reset(data, task, direction)
        metrics = reset_metrics(distance, task.checkpoint_index)
        info = {"truncation": jnp.zeros(()), **({} if critic is None else {"privileged_obs": critic})}
        return EnvState(
            pipeline_state=SimState(data, task),
            obs=obs,
            reward=jnp.zeros(()),
            done=jnp.zeros(()),
            metrics=metrics,
            info=info,
        )

    def set_goal(self, state: EnvState, goal_xy: jax.Array) -> EnvState:
        """Replace the current goal (non-spiral modes); progress terms restart from it (along the straight
        line: a goal set by hand has no site on the tile)."""
        sim: SimState = state.pipeline_state
        data = self._with_goal_marker(sim.physics, goal_xy, sim.task.tile)
        task = sim.task.replace(goal_xy=goal_xy, site=jnp.asarray(progress.NO_SITE, jnp.int32))
        distance, direction = self.progress.measure(task, observation.robot_xy(data, self.index))
        task = task.replace(prev_distance=distance, start_distance=distance)
        obs, critic, task = self.observer.after_goal_change(data, task, direction, self._episode_time(task), state.obs)
        info = state.info if critic is None else dict(state.info, privileged_obs=critic)
        return state.replace(pipeline_state=SimState(data, task), obs=obs, info=info)

    def step(self, state: EnvState, action: jax.Array) -> EnvState:
        """Advance one env step (``frame_skip`` physics steps) with a normalised action."""
        return self.step_with(self._simulate, state, action)

    def step_with(self, simulate: Simulate, state: EnvState, action: jax.Array) -> EnvState:
        """``step`` with another physics engine: ``simulate(data, targets (frame_skip, 8), fields) ->
        (data, SubstepStats)`` runs the substeps with this episode's randomised model fields
        (``hsa_mjx.task.randomization.model_fields``; e.g. ``hsa_mjx.sim.host_physics``: C MuJoCo for
        one env on a CPU); control, observation, reward and termination are this env's own."""
        state, call = self.before_physics(state, action)
        return self.after_physics(state, call, *simulate(call.data, call.targets, call.fields))

    def before_physics(self, state: EnvState, action: jax.Array) -> tuple[EnvState, PhysicsCall]:
        """``step_with``'s first half: the action sanitised and delayed, a push, the substeps' targets and
        model fields. A host may run the substeps between two jitted halves (``hsa_mjx.adapters.gymnasium``)."""
        cfg, idx = self.config, self.index
        action, bad_action = control.sanitize_action(jnp.asarray(action, jnp.float32))
        state, data, applied = self._randomize_before_physics(state, action)
        start = data.ctrl[idx.servo_ids]
        end = control.next_targets(start, applied, cfg.control.max_increment, cfg.control.servo_target_limit)
        targets = control.substep_targets(start, end, cfg.control.frame_skip, cfg.control.smooth_positions)
        before = (observation.robot_xy(data, idx), observation.heading(data, idx))
        scales = state.pipeline_state.task.randomization.physics
        fields = randomization.model_fields(self._nominal, scales, cfg.randomization)
        return state, PhysicsCall(data, targets, fields, action, bad_action, before)

    def _simulate(self, data: mjx.Data, targets: jax.Array, fields: dict) -> tuple[mjx.Data, physics.SubstepStats]:
        """The substeps on this env's physics (MJX's JAX or Warp implementation, or C MuJoCo), with
        this episode's randomised model fields."""
        if self._host is not None:
            return self._host(data, targets, fields)
        return physics.simulate(self.robot.mjx_model.replace(**fields), data, targets, self.index, self.motors)

    def _randomize_before_physics(self, state: EnvState, action: jax.Array) -> tuple[EnvState, mjx.Data, jax.Array]:
        """The delayed action the servos see and a push when one is due (state with the queue and key)."""
        cfg, sim = self.config.randomization, state.pipeline_state
        task, data, applied = sim.task, sim.physics, action
        if cfg.max_latency > 0:
            drawn = task.randomization
            applied, queue = randomization.delay(drawn.action_queue, action, drawn.latency)
            task = task.replace(randomization=drawn.replace(action_queue=queue))
        if cfg.pushes:
            rng, key = jax.random.split(task.rng)
            qvel, drawn = randomization.apply_push(
                key, task.randomization, data.qvel, task.step_count, cfg, self.config.dt, self.index.block_qvel
            )
            task, data = task.replace(rng=rng, randomization=drawn), data.replace(qvel=qvel)
        return state.replace(pipeline_state=SimState(data, task)), data, applied

    def after_physics(
        self, state: EnvState, call: PhysicsCall, new_data: mjx.Data, stats: physics.SubstepStats
    ) -> EnvState:
        """``step_with``'s second half, everything after the physics: goal, observation, termination,
        reward, metrics."""
        cfg, idx, action, before = self.config, self.index, call.action, call.before
        task, data = state.pipeline_state.task, state.pipeline_state.physics
        after = observation.robot_xy(new_data, idx)
        task, collected, completed = self.progress.advance_checkpoint(task, after)
        new_data = self._with_goal_marker(new_data, task.goal_xy, task.tile)
        distance, direction = self.progress.measure(task, after)
        steps = task.step_count + 1
        obs, critic, task = self.observer.after_step(new_data, task, direction, steps * cfg.dt, state.obs, action)
        ending = outcome.judge(cfg, idx, self.world, new_data, stats, obs, after, task, completed)
        task, moved, full = progress.record_position(task, after)
        moves = outcome.Progress((after - before[0]) / cfg.dt, direction, distance, moved, full, collected, completed)
        inputs = outcome.reward_inputs(cfg, idx, new_data, task, action, before[1], moves, ending)
        components = reward.compute_rewards(inputs, self.weights)
        total = reward.total_reward(components)
        reasons, terminated = ending.reasons, ending.terminated
        truncated = (steps >= cfg.termination.max_episode_steps) & jnp.logical_not(terminated)
        task = task.replace(
            prev_action=action, prev_joint_vel=inputs.joint_vel, prev_distance=distance, step_count=steps
        )
        new_data, obs, total = self._sanitize(data, new_data, obs, total, reasons["non_finite"])
        metrics = step_metrics(components, reasons, call.bad_action, distance, task.checkpoint_index)
        info = dict(state.info, truncation=truncated.astype(jnp.float32))
        if critic is not None:
            info["privileged_obs"] = jnp.where(jnp.isfinite(critic), critic, 0.0)
        return state.replace(
            pipeline_state=SimState(new_data, task),
            obs=obs,
            reward=total,
            done=(terminated | truncated).astype(jnp.float32),
            metrics=metrics,
            info=info,
        )

    # ----- helpers ------------------------------------------------------------------------
    def _episode_time(self, task: TaskState) -> jax.Array:
        """Seconds since this episode's reset (env steps x dt)."""
        return task.step_count * self.config.dt

    def _track_start(self, key: jax.Array, index: jax.Array | None) -> tuple[jax.Array, jax.Array, tuple]:
        """A spiral start along the track (drawn, or at ``index``): (index, goal, move for ``_spawn``)."""
        index, target, yaw = goals.track_start(
            key, self._checkpoints, self.config.goal.track_starts, self._origin, index
        )
        return index, self._checkpoints[index], (self._origin, target, yaw)

    def _spawn(self, tile: jax.Array, move: tuple | None = None) -> mjx.Data:
        """The reset state: on terrain the floor is moved to put this env's tile under the origin and
        both blocks are lifted to rest on it; ``move`` = (centre, target, yaw) turns and shifts the
        robot first (``hsa_mjx.pose``)."""
        if not self.world.enabled and move is None:
            return self._data0
        data = self._data0
        qpos = data.qpos
        if self.world.enabled:
            qpos = qpos.at[self.index.block_z].set(self.world.spawn_height(tile, move))
            floor = data.mocap_pos.at[self.index.terrain_mocap].set(self.world.floor_position(tile))
            data = data.replace(mocap_pos=floor)
        if move is not None:
            qpos = pose.move_free_joints(qpos, self.index.block_qpos, *move)
        return compiled_kinematics(self.robot.mjx_model, data.replace(qpos=qpos))

    def _with_goal_marker(self, data: mjx.Data, goal_xy: jax.Array, tile: jax.Array) -> mjx.Data:
        """Place this env's goal marker above the ground at the goal (a mocap body; purely visual)."""
        z = self.world.ground(tile, goal_xy) + GOAL_MARKER_Z
        marker = jnp.concatenate([goal_xy, z[None]])
        return data.replace(mocap_pos=data.mocap_pos.at[self.index.goal_mocap].set(marker))

    def _sanitize(
        self, old: mjx.Data, new: mjx.Data, obs: jax.Array, total: jax.Array, non_finite: jax.Array
    ) -> tuple[mjx.Data, jax.Array, jax.Array]:
        """Keep non-finite values away from learners: last finite physics, zeroed obs, finite reward."""
        data = backend.select(non_finite, old, new)
        obs = jnp.where(jnp.isfinite(obs), obs, 0.0)
        total = jnp.where(jnp.isfinite(total), total, -self.weights.termination)
        return data, obs, total
