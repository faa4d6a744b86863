"""Per-env physical randomisation, action latency, pushes and observation noise (pure JAX).

Each env draws its physical scales from its reset key (:func:`draw`) and keeps them for the episode
(``TaskState.randomization``); every step writes them into the model fields below (:func:`model_fields`)
before the substeps, the same dict for MJX's JAX and Warp implementations (``mjx.Model.replace``:
both batch these fields per world) and for C MuJoCo substeps (set on the C model). Only the fields
of scales whose range differs from [1, 1] are written; the others stay the asset's.

=================  =========================================================================
scale              model fields
=================  =========================================================================
friction           ``geom_friction[:, 0]`` of every geom and ``pair_friction[:, :2]`` of the
                   foot-floor pairs (the sliding coefficients: every contact's friction scales)
foot_friction      ``pair_friction[:, :2]`` of each foot-floor pair by its own draw (four per env)
foot_anisotropy    each foot-floor pair's lower sliding coefficient alone (across the robot on a
                   plane; world Y on a heightfield, whose contact frames are world-fixed)
block_mass         ``body_mass`` and ``body_inertia`` of each block (one draw per block)
hsa_stiffness      ``tendon_stiffness`` of every HSA tendon spring
hsa_damping        ``tendon_damping`` of every HSA tendon spring
servo_gain         the servos' ``actuator_gainprm[:, 0]`` and ``actuator_biasprm[:, 1]`` (kp)
servo_force_limit  the servos' ``actuator_forcerange`` (the model is compiled force-limited)
robots             one drawn profile's DC-motor servo: the drive actuators' ``actuator_gainprm``
                   (stall torque, the drive's figures and model: ``hsa_mjx.sim.servo.SLOTS``),
                   ``actuator_biasprm[:, 2]`` (back-EMF), ``actuator_forcerange`` (the stall
                   torque) and the hinges' ``dof_damping``, ``dof_frictionloss`` and ``dof_armature``,
                   as the env built with that profile's servo holds them
servo_figures      scales of the stall torque, no-load speed, damping, friction and rotor inertia
                   of the env's servo (or of the drawn robot's), in the same fields
=================  =========================================================================
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from flax import struct

from hsa_mjx.randomization_config import (
    NOISE_GROUPS,
    NOMINAL,
    ObservationNoiseConfig,
    RandomizationConfig,
)
from hsa_mjx.servo_config import ServoParams
from hsa_mjx.sim import servo
from hsa_mjx.sim.model import RobotIndex

FIELDS = (
    "geom_friction",
    "pair_friction",
    "body_mass",
    "body_inertia",
    "tendon_stiffness",
    "tendon_damping",
    "actuator_gainprm",
    "actuator_biasprm",
    "actuator_forcerange",
    "dof_damping",
    "dof_frictionloss",
    "dof_armature",
)
SERVO_FIGURES = ("stall_torque", "no_load_speed", "damping", "friction", "armature")  # servo_figures' scales
# observation slot label prefixes of each noise group (hsa_mjx.task.observation.observation_labels)
NOISE_LABELS = {
    "hinge_angles": ("hinge_angle_", "hinge_sin_", "hinge_cos_"),
    "hinge_velocities": ("hinge_velocity_",),
    "position": ("robot_x", "robot_y"),
    "velocity": ("block_v",),
    "goal": ("goal_distance", "goal_dir_x", "goal_dir_y"),
    "heading": ("heading_", "goal_dir_ahead", "goal_dir_left", "path_dir_"),
}


@struct.dataclass
class PhysicsScales:
    """One env's physical parameters for an episode (scales of the asset's values; traced arrays)."""

    friction: jax.Array  # ()
    block_mass: jax.Array  # (2,) block_a, block_b
    hsa_stiffness: jax.Array  # ()
    hsa_damping: jax.Array  # ()
    servo_gain: jax.Array  # ()
    servo_force_limit: jax.Array  # () N m (inf: no limit)
    foot_friction: jax.Array  # (4,) each foot's floor contact, both sliding coefficients
    foot_anisotropy: jax.Array  # (4,) each foot's lower sliding coefficient alone
    robot: jax.Array  # () int32, the drawn robot's place in ``randomization.robots`` (0: none drawn)
    servo_figures: jax.Array  # (5,) scales of SERVO_FIGURES

    @staticmethod
    def nominal() -> PhysicsScales:
        """The asset's own values (all scales 1, no torque limit)."""
        one = jnp.ones((), jnp.float32)
        return PhysicsScales(
            friction=one,
            block_mass=jnp.ones((2,), jnp.float32),
            hsa_stiffness=one,
            hsa_damping=one,
            servo_gain=one,
            servo_force_limit=jnp.full((), jnp.inf, jnp.float32),
            foot_friction=jnp.ones((4,), jnp.float32),
            foot_anisotropy=jnp.ones((4,), jnp.float32),
            robot=jnp.zeros((), jnp.int32),
            servo_figures=jnp.ones((len(SERVO_FIGURES),), jnp.float32),
        )


def _uniform(key: jax.Array, bounds: tuple[float, float], shape: tuple = ()) -> jax.Array:
    """Uniform in [lo, hi] (exactly lo when lo == hi)."""
    lo, hi = bounds
    return lo + (hi - lo) * jax.random.uniform(key, shape, jnp.float32)


def _robot(key: jax.Array, robots: int, weights: tuple[float, ...]) -> jax.Array:
    """The index of the drawn robot profile: uniform, or in proportion to ``weights``."""
    if not weights:
        return jax.random.randint(key, (), 0, robots, jnp.int32)
    return jax.random.choice(key, robots, p=jnp.asarray(weights, jnp.float32) / sum(weights)).astype(jnp.int32)


def draw(key: jax.Array, config: RandomizationConfig) -> PhysicsScales:
    """One env's scales, uniform in the config's ranges (the same for the same key on every backend)."""
    keys = jax.random.split(key, 6)
    feet = jax.random.split(jax.random.fold_in(key, 6), 2)  # the other draws stay what they were before the feet's
    robots = max(len(config.robots), 1)
    limit = _uniform(keys[5], config.servo_force_limit) if config.limits_force else jnp.full((), jnp.inf)
    return PhysicsScales(
        friction=_uniform(keys[0], config.friction),
        block_mass=_uniform(keys[1], config.block_mass, (2,)),
        hsa_stiffness=_uniform(keys[2], config.hsa_stiffness),
        hsa_damping=_uniform(keys[3], config.hsa_damping),
        servo_gain=_uniform(keys[4], config.servo_gain),
        servo_force_limit=limit.astype(jnp.float32),
        foot_friction=_uniform(feet[0], config.foot_friction, (4,)),
        foot_anisotropy=_uniform(feet[1], config.foot_anisotropy, (4,)),
        robot=_robot(jax.random.fold_in(key, 7), robots, config.robot_weights),
        servo_figures=_uniform(jax.random.fold_in(key, 8), config.servo_figures, (len(SERVO_FIGURES),)),
    )


@dataclasses.dataclass(frozen=True)
class NominalModel:
    """The asset's values of the randomised fields (numpy) and the ids they are written at."""

    values: dict[str, np.ndarray]
    blocks: np.ndarray
    servos: np.ndarray
    tendons: np.ndarray
    feet: np.ndarray  # (4,) each foot's floor contact pair
    lower: np.ndarray  # (4,) the column (0, 1) of each foot pair's lower sliding coefficient
    drives: np.ndarray  # the DC-motor servos' drive actuators (none for the asset's springs)
    hinges: np.ndarray  # (8,) the actuated hinges' dofs
    hinge_damping: np.ndarray  # (8,) their damping without the servo's (the asset's own)
    servo_rows: np.ndarray  # (robots, SERVO_ROW) the env's own servo, or each drawable robot's

    @staticmethod
    def from_model(
        mj_model: mujoco.MjModel, index: RobotIndex, own: ServoParams | None = None, robots: tuple = ()
    ) -> NominalModel:
        """Read the fields once from the compiled C model; ``own``: the env's DC-motor servo (None: the
        springs), ``robots``: the drawable robots' servos (``hsa_mjx.robots.drawn_servos``)."""
        values = {name: np.array(getattr(mj_model, name), np.float32) for name in FIELDS}
        feet = np.asarray(index.foot_pairs)
        lower = np.argmin(values["pair_friction"][feet, :2], axis=1)
        hinges = np.asarray(index.joint_qvel)
        rows = np.asarray([servo_row(p) for p in (robots or ([own] if own else []))], np.float32)
        damping = values["dof_damping"][hinges] - (own.damping if own else 0.0)
        ids = np.asarray(index.servo_ids), np.arange(mj_model.ntendon)
        drives = np.asarray(index.drive_ids)
        return NominalModel(values, np.asarray(index.block_body), *ids, feet, lower, drives, hinges, damping, rows)


def servo_row(params: ServoParams) -> list[float]:
    """A DC-motor servo's figures as one row: its drive actuators' gain slots, then SERVO_FIGURES[1:]."""
    return [*servo.gain_slots(params), params.no_load_speed, params.damping, params.friction, params.armature]


def model_fields(nominal: NominalModel, scales: PhysicsScales, config: RandomizationConfig) -> dict[str, jax.Array]:
    """The model fields ``config`` randomises, for one env (pass to ``mjx.Model.replace`` or a C model);
    fields left at their nominal range are not in the dict (the model keeps them unbatched)."""
    v, blocks, servos = nominal.values, nominal.blocks, nominal.servos
    fields = {}
    if config.friction != NOMINAL:
        fields["geom_friction"] = jnp.asarray(v["geom_friction"]).at[:, 0].multiply(scales.friction)
        fields["pair_friction"] = jnp.asarray(v["pair_friction"]).at[:, :2].multiply(scales.friction)
    if config.per_foot:
        pair, feet = fields.get("pair_friction", jnp.asarray(v["pair_friction"])), nominal.feet
        pair = pair.at[feet, :2].multiply(scales.foot_friction[:, None])
        fields["pair_friction"] = pair.at[feet, nominal.lower].multiply(scales.foot_anisotropy)
    if config.block_mass != NOMINAL:
        fields["body_mass"] = jnp.asarray(v["body_mass"]).at[blocks].multiply(scales.block_mass)
        fields["body_inertia"] = jnp.asarray(v["body_inertia"]).at[blocks].multiply(scales.block_mass[:, None])
    if config.hsa_stiffness != NOMINAL:
        fields["tendon_stiffness"] = jnp.asarray(v["tendon_stiffness"]) * scales.hsa_stiffness
    if config.hsa_damping != NOMINAL:
        fields["tendon_damping"] = jnp.asarray(v["tendon_damping"]) * scales.hsa_damping
    if config.servo_gain != NOMINAL:
        fields["actuator_gainprm"] = jnp.asarray(v["actuator_gainprm"]).at[servos, 0].multiply(scales.servo_gain)
        fields["actuator_biasprm"] = jnp.asarray(v["actuator_biasprm"]).at[servos, 1].multiply(scales.servo_gain)
    if config.limits_force:
        limit = jnp.stack([-scales.servo_force_limit, scales.servo_force_limit])
        fields["actuator_forcerange"] = jnp.asarray(v["actuator_forcerange"]).at[servos].set(limit)
    if config.robots or config.servo_figures != NOMINAL:
        row = jnp.asarray(nominal.servo_rows)[scales.robot]
        fields.update(servo_fields(nominal, row, scales.servo_figures))
    return fields


def servo_fields(nominal: NominalModel, row: jax.Array, figures: jax.Array) -> dict[str, jax.Array]:
    """The drive actuators' and hinges' fields of the servo ``row`` (:func:`servo_row`: the drawn robot's,
    or the env's own where none is drawn) with its SERVO_FIGURES scaled by ``figures`` (5,)
    (``hsa_mjx.sim.servo``: where each figure sits)."""
    v, drives, hinges = nominal.values, nominal.drives, nominal.hinges
    slots, (speed, damping, friction, armature) = row[: servo.FIGURE_SLOTS], row[servo.FIGURE_SLOTS :]
    stall = slots[servo.STALL] * figures[0]
    return {
        "actuator_gainprm": jnp.asarray(v["actuator_gainprm"])
        .at[drives, : servo.FIGURE_SLOTS]
        .set(slots.at[servo.STALL].set(stall)),
        "actuator_biasprm": jnp.asarray(v["actuator_biasprm"]).at[drives, 2].set(-stall / (speed * figures[1])),
        "actuator_forcerange": jnp.asarray(v["actuator_forcerange"]).at[drives].set(jnp.stack([-stall, stall])),
        "dof_damping": jnp.asarray(v["dof_damping"]).at[hinges].set(nominal.hinge_damping + damping * figures[2]),
        "dof_frictionloss": jnp.asarray(v["dof_frictionloss"]).at[hinges].set(friction * figures[3]),
        "dof_armature": jnp.asarray(v["dof_armature"]).at[hinges].set(armature * figures[4]),
    }


# ----- latency and pushes ---------------------------------------------------------------------
@struct.dataclass
class RandomizationState:
    """This episode's sim-to-real draws (``randomization``): physical scales, action latency, pushes."""

    physics: PhysicsScales  # the model's scales this episode (nominal when nothing is randomised)
    action_queue: jax.Array  # (max latency + 1, actions) the last actions, newest first
    latency: jax.Array  # () int32, control steps an action waits before the servos see it
    next_push: jax.Array  # () int32, the step count at which the next push comes
    push_scale: jax.Array  # () float32, the share of push_speed this episode's pushes reach (the curriculum's)


NEVER = np.iinfo(np.int32).max  # next_push without pushes
# the privileged critic's view of an episode's model (hsa_mjx.task.privileged), in true_model's order
TRUE_MODEL_LABELS = (
    "true_friction",
    "true_block_mass_a",
    "true_block_mass_b",
    "true_hsa_stiffness",
    "true_hsa_damping",
    "true_servo_gain",
    "true_inverse_torque_limit",  # 1 / (N m); 0: no limit
    "true_latency_steps",
)


# appended where each foot draws its own friction (``RandomizationConfig.per_foot``)
FOOT_MODEL_LABELS = tuple(f"true_foot_{kind}_{i}" for kind in ("friction", "anisotropy") for i in range(4))


def servo_model_labels(config: RandomizationConfig) -> tuple[str, ...]:
    """Appended where each env draws its robot (one per profile: the drawn one 1, the others 0) and its
    servo figures (their scales)."""
    robots = tuple(f"true_robot_{name}" for name in config.robots)
    return robots + (tuple(f"true_servo_{name}" for name in SERVO_FIGURES) if config.servo_figures != NOMINAL else ())


def true_model(state: RandomizationState, config: RandomizationConfig) -> jax.Array:
    """The episode's model as the privileged critic sees it, float32 in ``TRUE_MODEL_LABELS``' order (8
    values), then where drawn the feet's in ``FOOT_MODEL_LABELS``' order and the drawn robot's and the
    servo figures' (``servo_model_labels``)."""
    p = state.physics
    parts = [
        jnp.stack([p.friction]),
        p.block_mass,
        jnp.stack([p.hsa_stiffness, p.hsa_damping, p.servo_gain, 1.0 / p.servo_force_limit]),
        jnp.stack([state.latency.astype(jnp.float32)]),
    ]
    parts += [p.foot_friction, p.foot_anisotropy] if config.per_foot else []
    parts += [jax.nn.one_hot(p.robot, len(config.robots))] if config.robots else []
    parts += [p.servo_figures] if config.servo_figures != NOMINAL else []
    return jnp.concatenate(parts).astype(jnp.float32)


def nominal_state(config: RandomizationConfig, action_size: int) -> RandomizationState:
    """An episode without draws: the asset's model, no latency, no pushes (the queue sized for the config)."""
    return RandomizationState(
        physics=PhysicsScales.nominal(),
        action_queue=jnp.zeros((config.max_latency + 1, action_size), jnp.float32),
        latency=jnp.zeros((), jnp.int32),
        next_push=jnp.asarray(NEVER, jnp.int32),
        push_scale=jnp.ones((), jnp.float32),
    )


def reset_state(
    key: jax.Array, config: RandomizationConfig, action_size: int, dt: float, scale: jax.Array | float = 1.0
) -> RandomizationState:
    """An episode's draws from ``key``: scales, latency (uniform in ``latency_steps``), first push.

    ``scale`` in [0, 1] shrinks every range towards the nominal model (:func:`toward_nominal`; the
    randomisation curriculum's level): 1 draws from the config's ranges, 0 gives the asset's model.
    """
    k_physics, k_latency, k_push = jax.random.split(key, 3)
    scale = jnp.asarray(scale, jnp.float32)
    physics = toward_nominal(draw(k_physics, config), scale) if config.physical else PhysicsScales.nominal()
    lo, hi = config.latency_steps
    latency = jax.random.randint(k_latency, (), lo, hi + 1, jnp.int32)
    latency = jnp.floor(latency * scale + 0.5).astype(jnp.int32)
    next_push = push_interval_steps(k_push, config, dt) if config.pushes else jnp.asarray(NEVER, jnp.int32)
    return RandomizationState(
        physics=physics,
        action_queue=jnp.zeros((config.max_latency + 1, action_size), jnp.float32),
        latency=latency,
        next_push=next_push,
        push_scale=scale,
    )


def toward_nominal(physics: PhysicsScales, scale: jax.Array) -> PhysicsScales:
    """The draws moved towards the nominal model: scales to ``1 + scale (draw - 1)``, the inverse torque
    limit to ``scale / limit`` (0: none). At ``scale`` 1 the draws are returned exactly."""

    def toward_one(x: jax.Array) -> jax.Array:
        return x * scale + (1.0 - scale)  # exact at scale 1

    return PhysicsScales(
        friction=toward_one(physics.friction),
        block_mass=toward_one(physics.block_mass),
        hsa_stiffness=toward_one(physics.hsa_stiffness),
        hsa_damping=toward_one(physics.hsa_damping),
        servo_gain=toward_one(physics.servo_gain),
        servo_force_limit=physics.servo_force_limit / scale,  # inf at scale 0: no limit
        foot_friction=toward_one(physics.foot_friction),
        foot_anisotropy=toward_one(physics.foot_anisotropy),
        robot=physics.robot,  # a robot is drawn whole at every level
        servo_figures=toward_one(physics.servo_figures),
    )


def apply_push(
    key: jax.Array,
    state: RandomizationState,
    qvel: jax.Array,
    step_count: jax.Array,
    config: RandomizationConfig,
    dt: float,
    block_qvel: np.ndarray,
) -> tuple[jax.Array, RandomizationState]:
    """Push both blocks when this step is the push's (and draw the next one); qvel and the new state."""
    k_velocity, k_next = jax.random.split(key)
    due = step_count >= state.next_push
    velocity = push_velocity(k_velocity, config.push_speed) * state.push_scale
    qvel = jnp.where(due, pushed(qvel, velocity, block_qvel), qvel)
    next_push = jnp.where(due, step_count + push_interval_steps(k_next, config, dt), state.next_push)
    return qvel, state.replace(next_push=next_push)


def delay(queue: jax.Array, action: jax.Array, latency: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Queue ``action`` (newest first, (max latency + 1, 8)); the action ``latency`` steps old, and the queue."""
    queue = jnp.concatenate([action[None], queue[:-1]])
    return queue[latency], queue


def push_interval_steps(key: jax.Array, config: RandomizationConfig, dt: float) -> jax.Array:
    """Control steps until the next push (at least 1), uniform in ``push_interval_s``."""
    return jnp.maximum(jnp.round(_uniform(key, config.push_interval_s) / dt), 1).astype(jnp.int32)


def push_velocity(key: jax.Array, max_speed: float) -> jax.Array:
    """A horizontal velocity (3,) of uniform direction and speed in [0, max_speed]."""
    k_dir, k_speed = jax.random.split(key)
    angle = jax.random.uniform(k_dir, (), jnp.float32, 0.0, 2.0 * jnp.pi)
    speed = jax.random.uniform(k_speed, (), jnp.float32, 0.0, max_speed)
    return jnp.stack([speed * jnp.cos(angle), speed * jnp.sin(angle), jnp.zeros(())])


def pushed(qvel: jax.Array, velocity: jax.Array, block_qvel: np.ndarray) -> jax.Array:
    """``qvel`` with ``velocity`` added to both blocks' linear velocities (their free joints' first 3 dofs)."""
    dofs = np.asarray(block_qvel)[:, None] + np.arange(3)[None, :]
    return qvel.at[dofs].add(velocity[None, :])


# ----- observation noise ------------------------------------------------------------------------
def noise_scales(labels: tuple[str, ...], config: ObservationNoiseConfig, tracked: bool = False) -> np.ndarray:
    """Each observation slot's noise amplitude (0 for slots outside every group, e.g. servo targets).
    ``tracked``: the position entries come from a tracker whose readings carry the position noise
    (``observation.velocity: differenced``), so that group adds none here."""
    scales = np.zeros(len(labels), np.float32)
    for group in NOISE_GROUPS:
        if tracked and group == "position":
            continue
        hit = [i for i, label in enumerate(labels) if label.startswith(NOISE_LABELS[group])]
        scales[hit] = getattr(config, group)
    return scales


def add_noise(obs: jax.Array, key: jax.Array, scales: np.ndarray) -> jax.Array:
    """``obs`` plus uniform noise of +-scale per slot."""
    return obs + jnp.asarray(scales) * jax.random.uniform(key, obs.shape, jnp.float32, -1.0, 1.0)
