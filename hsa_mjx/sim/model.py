"""The robot model: load the MuJoCo asset once, apply physics settings, resolve every name.

Everything index-like the env needs (actuated joints, servos, blocks, foot contact sensors, the
goal marker, the terrain's mocap body) is resolved here by name, once, into a static
:class:`RobotIndex` of numpy arrays. On the terrain scene the asset's heightfield (one tile) is grown
into the run's atlas of terrain tiles before compiling (``hsa_mjx.terrain.atlas``).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import jax
import mujoco
import numpy as np

from hsa_mjx.config import EnvConfig
from hsa_mjx.resources import scene_path
from hsa_mjx.servo_config import resolve_servo
from hsa_mjx.sim import backend, servo
from hsa_mjx.sim.backend import mjx
from hsa_mjx.sim.cpu_linalg import use_xla_linalg_on_cpu
from hsa_mjx.terrain.atlas import AtlasLayout, TerrainPool
from hsa_mjx.terrain.grid import HFIELD_NAME, Grid

# Action / observation slot order of the original (1A, 2A, 3A, 4A, 1C, 2C, 3C, 4C).
ACTUATED_JOINTS = (
    "cw_cont_1a_top",
    "cw_cont_2a_top",
    "cw_cont_3a_btm",
    "cw_cont_4a_btm",
    "cw_ext_1c_top",
    "cw_ext_2c_top",
    "cw_ext_3c_btm",
    "cw_ext_4c_btm",
)
SERVOS = (
    "spring1a_motor",
    "spring2a_motor",
    "spring3a_motor",
    "spring4a_motor",
    "spring1c_motor",
    "spring2c_motor",
    "spring3c_motor",
    "spring4c_motor",
)
DISC_JOINTS = ("disc1b_hinge", "disc2b_hinge", "disc3b_hinge", "disc4b_hinge")
FREE_JOINT_Z = 2  # a free joint's qpos: x, y, z, then the orientation quaternion
FOOT_GEOMS = ("cylinder3a_con", "cylinder3c_con", "cylinder4a_con", "cylinder4c_con")
FOOT_SENSORS = ("foot_3a_force", "foot_3c_force", "foot_4a_force", "foot_4c_force")
FOOT_PAIRS = ("cylinder3a_ground", "cylinder3c_ground", "cylinder4a_ground", "cylinder4c_ground")  # each scene's
BLOCKS = ("block_a", "block_b")
TERRAIN_BODY = "terrain_frame"  # mocap body carrying the heightfield (terrain scene only)
BLOCK_JOINTS = ("block_a_root", "block_b_root")
GOAL_BODY = "goal_marker"

_INTEGRATORS = {
    "euler": mujoco.mjtIntegrator.mjINT_EULER,
    "implicitfast": mujoco.mjtIntegrator.mjINT_IMPLICITFAST,
    "rk4": mujoco.mjtIntegrator.mjINT_RK4,
}
_SOLVERS = {"newton": mujoco.mjtSolver.mjSOL_NEWTON, "cg": mujoco.mjtSolver.mjSOL_CG}
_CONES = {"pyramidal": mujoco.mjtCone.mjCONE_PYRAMIDAL, "elliptic": mujoco.mjtCone.mjCONE_ELLIPTIC}

# The reset state's positions, compiled once per model layout. Kinematics, not the full mjx.forward:
# the observation reads only qpos, qvel, xpos and ctrl, and each step recomputes every derived field,
# so contacts and forces at the spawn pose would be unused (and mjx.forward's collision and solver
# cost 6-12 s of compile per model layout on a CPU, eager dispatch minutes).
compiled_kinematics = jax.jit(mjx.kinematics)


@dataclasses.dataclass(frozen=True)
class RobotIndex:
    """Static ids and addresses resolved by name (numpy, never traced)."""

    joint_qpos: np.ndarray  # (8,) qpos address of each actuated hinge, action-slot order
    joint_qvel: np.ndarray  # (8,) dof address of each actuated hinge
    servo_ids: np.ndarray  # (8,) actuator id of each servo, action-slot order
    drive_ids: np.ndarray  # (8,) actuator id of each servo's motor drive (hsa_mjx.sim.servo); (0,) for springs
    play_act: np.ndarray  # (8,) act address of each servo's gear-play state (hsa_mjx.sim.servo); (0,) without play
    block_body: np.ndarray  # (2,) body ids of block_a, block_b
    block_qpos: np.ndarray  # (2,) qpos address of each block's free joint
    block_z: np.ndarray  # (2,) qpos address of each block's height (its free joint's z)
    block_qvel: np.ndarray  # (2,) dof address of each block's free joint
    constraint_pairs: np.ndarray  # (4, 2) action slots of (kA, kC) for units 1..4
    foot_sensors: np.ndarray  # (4, contacts, 3) sensordata addresses of each foot's contact forces
    foot_pairs: np.ndarray  # (4,) contact pair id of each foot with the floor (its anisotropic friction)
    goal_mocap: int  # mocap index of the goal marker
    terrain_mocap: int  # mocap index of the heightfield's body; -1 on the plane scene


def robot_spec(config: EnvConfig, asset_dir: Path | None = None) -> mujoco.MjSpec:
    """The scene for ``config`` as a spec, its servos the configured ones (not yet compiled)."""
    spec = mujoco.MjSpec.from_file(str(scene_path(config.scene, asset_dir)))
    params = resolve_servo(config.servo)
    if params is not None:  # DC-motor servos: a drive actuator beside each (inert) position actuator
        servo.add_drives(spec, params, SERVOS, ACTUATED_JOINTS)
    return spec


def compile_robot(spec: mujoco.MjSpec, config: EnvConfig) -> mujoco.MjModel:
    """A spec of :func:`robot_spec` compiled, with the configured physics."""
    model = spec.compile()
    _apply_physics(model, config)
    return model


def load_scene(config: EnvConfig, asset_dir: Path | None = None) -> tuple[mujoco.MjModel, TerrainPool | None]:
    """The scene for ``config`` as a C MuJoCo model with the configured physics, and its terrain pool.

    On the terrain scene the asset's heightfield is one tile: it becomes an atlas of the run's
    terrain tiles (drawn from ``terrain.seed``), written into the model's ``hfield_data``.
    """
    spec = robot_spec(config, asset_dir)
    pool = None
    if config.scene == "terrain":
        field = spec.hfield(HFIELD_NAME)
        tile = Grid(int(field.nrow), int(field.ncol), *(float(v) for v in field.size))
        layout = AtlasLayout.from_config(config.terrain, tile)
        atlas = layout.grid
        field.nrow, field.ncol = atlas.nrow, atlas.ncol
        field.size = [atlas.half_x, atlas.half_y, atlas.z_scale, atlas.base]
        field.userdata = [0.0] * atlas.size
        pool = TerrainPool(config.terrain, layout)
    model = compile_robot(spec, config)
    if pool is not None:
        model.hfield_data[:] = pool.atlas
    return model, pool


def load_mj_model(config: EnvConfig, asset_dir: Path | None = None) -> mujoco.MjModel:
    """The scene for ``config`` as a C MuJoCo model (terrain atlas included) with the configured physics."""
    return load_scene(config, asset_dir)[0]


def _apply_physics(model: mujoco.MjModel, config: EnvConfig) -> None:
    """Write the ``physics`` section, the servo range and a randomised servo torque limit into ``model``."""
    phys = config.physics
    model.opt.timestep = phys.timestep
    model.opt.integrator = _INTEGRATORS[phys.integrator]
    model.opt.solver = _SOLVERS[phys.solver]
    model.opt.iterations = phys.iterations
    model.opt.ls_iterations = phys.ls_iterations
    model.opt.tolerance = phys.tolerance
    model.opt.cone = _CONES[phys.cone]
    limit, servos = config.control.servo_target_limit, _ids(model, mujoco.mjtObj.mjOBJ_ACTUATOR, SERVOS)
    model.actuator_ctrlrange[servos] = np.array([-limit, limit])
    if config.randomization.limits_force:  # each env's own limit goes into actuator_forcerange per step
        model.actuator_forcelimited[servos] = 1
        model.actuator_forcerange[servos] = np.array([-1.0, 1.0]) * config.randomization.servo_force_limit[1]


def _ids(model: mujoco.MjModel, kind: mujoco.mjtObj, names: tuple[str, ...]) -> np.ndarray:
    out = []
    for name in names:
        idx = mujoco.mj_name2id(model, kind, name)
        if idx < 0:
            raise ValueError(f"the robot asset has no {kind.name[6:].lower()} named {name!r}")
        out.append(idx)
    return np.asarray(out, dtype=np.int32)


def _foot_sensor_addresses(model: mujoco.MjModel) -> np.ndarray:
    """sensordata addresses of each foot's contact-force sensor, shaped (feet, contacts, 3)."""
    ids = _ids(model, mujoco.mjtObj.mjOBJ_SENSOR, FOOT_SENSORS)
    dims = set(model.sensor_dim[ids].tolist())
    if len(dims) != 1 or next(iter(dims)) % 3:
        raise ValueError(f"foot sensors must each give 3 force values per contact, got dims {sorted(dims)}")
    dim = dims.pop()
    return (model.sensor_adr[ids, None] + np.arange(dim)).reshape(len(ids), dim // 3, 3).astype(np.int32)


def _terrain_mocap(model: mujoco.MjModel) -> int:
    """Mocap index of the heightfield's body, -1 when the scene has none (the plane)."""
    body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, TERRAIN_BODY)
    return -1 if body < 0 else int(model.body_mocapid[body])


def _drive_ids(model: mujoco.MjModel) -> np.ndarray:
    """Actuator ids of the servos' motor drives in action-slot order, none when the servos are springs."""
    names = tuple(joint + servo.DRIVE_SUFFIX for joint in ACTUATED_JOINTS)
    if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, names[0]) < 0:
        return np.zeros((0,), np.int32)
    return _ids(model, mujoco.mjtObj.mjOBJ_ACTUATOR, names)


def _play_act(model: mujoco.MjModel) -> np.ndarray:
    """act addresses of the servos' gear-play states in action-slot order, none without gear play."""
    names = tuple(joint + servo.PLAY_SUFFIX for joint in ACTUATED_JOINTS)
    if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, names[0]) < 0:
        return np.zeros((0,), np.int32)
    return model.actuator_actadr[_ids(model, mujoco.mjtObj.mjOBJ_ACTUATOR, names)].astype(np.int32)


def build_index(model: mujoco.MjModel) -> RobotIndex:
    """Resolve every name the env uses into static ids."""
    joints = _ids(model, mujoco.mjtObj.mjOBJ_JOINT, ACTUATED_JOINTS)
    servos = _ids(model, mujoco.mjtObj.mjOBJ_ACTUATOR, SERVOS)
    if not np.array_equal(model.actuator_trnid[servos, 0], joints):
        raise ValueError("servo order does not match the actuated joint order in the asset")
    block_joints = _ids(model, mujoco.mjtObj.mjOBJ_JOINT, BLOCK_JOINTS)
    goal_body = _ids(model, mujoco.mjtObj.mjOBJ_BODY, (GOAL_BODY,))[0]
    slot = {name: i for i, name in enumerate(ACTUATED_JOINTS)}
    pairs = [(slot[a], slot[c]) for a, c in zip(ACTUATED_JOINTS[:4], ACTUATED_JOINTS[4:])]
    return RobotIndex(
        joint_qpos=model.jnt_qposadr[joints].astype(np.int32),
        joint_qvel=model.jnt_dofadr[joints].astype(np.int32),
        servo_ids=servos,
        drive_ids=_drive_ids(model),
        play_act=_play_act(model),
        block_body=_ids(model, mujoco.mjtObj.mjOBJ_BODY, BLOCKS),
        block_qpos=model.jnt_qposadr[block_joints].astype(np.int32),
        block_z=(model.jnt_qposadr[block_joints] + FREE_JOINT_Z).astype(np.int32),
        block_qvel=model.jnt_dofadr[block_joints].astype(np.int32),
        constraint_pairs=np.asarray(pairs, dtype=np.int32),
        foot_sensors=_foot_sensor_addresses(model),
        foot_pairs=_ids(model, mujoco.mjtObj.mjOBJ_PAIR, FOOT_PAIRS),
        goal_mocap=int(model.body_mocapid[goal_body]),
        terrain_mocap=_terrain_mocap(model),
    )


@dataclasses.dataclass(frozen=True)
class RobotModel:
    """The loaded robot: C model (for rendering and oracles), MJX model, name index, terrain pool
    (None on the plane) and the physics implementation the MJX model belongs to."""

    mj_model: mujoco.MjModel
    mjx_model: mjx.Model
    index: RobotIndex
    pool: TerrainPool | None
    backend: str


def local_device() -> jax.Device:
    """Where MJX model and data go: ``jax.default_device`` when set, else this process's first device.

    MJX's own default (``jax.devices()[0]``) belongs to process 0 on several hosts; the per-device
    training path builds one env per GPU inside ``jax.default_device(gpu)``.
    """
    default = jax.config.jax_default_device
    return default if isinstance(default, jax.Device) else jax.local_devices()[0]


def load_robot(config: EnvConfig, asset_dir: Path | None = None) -> RobotModel:
    """Load the asset for ``config`` once, resolve every name and put it on the configured backend.

    Every env is built through here, so this is where the CPU's large batched Cholesky and triangular
    solves are lowered to XLA's own ops (``hsa_mjx.sim.cpu_linalg``: jaxlib's LAPACK calls deadlock on a
    small thread pool); it changes JAX's CPU lowering for the whole process, once.
    """
    use_xla_linalg_on_cpu()
    device = local_device()
    impl = backend.resolve(config.physics.backend, device)
    mj_model, pool = load_scene(config, asset_dir)
    mjx_model = backend.put_model(mj_model, impl, device)
    return RobotModel(mj_model, mjx_model, build_index(mj_model), pool, impl)
