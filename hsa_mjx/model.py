"""The robot model: load the MuJoCo asset once, apply physics settings, resolve every name.

Everything index-like the env needs (actuated joints, servos, blocks, foot contacts, the goal
marker) is resolved here by name, once, into a static :class:`RobotIndex` of numpy arrays.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import jax
import mujoco
import numpy as np
from mujoco import mjx

from hsa_mjx.config import EnvConfig
from hsa_mjx.cpu_linalg import use_xla_linalg_on_cpu

use_xla_linalg_on_cpu()  # large vmapped batches would deadlock in jaxlib's CPU LAPACK calls

ASSET_DIR = Path(__file__).resolve().parent.parent / "assets"
SCENE_FILES = {"flat": "scene_flat.xml", "terrain": "scene_terrain.xml"}

# Action / observation slot order of the original (1A, 2A, 3A, 4A, 1C, 2C, 3C, 4C).
ACTUATED_JOINTS = (
    "cw_cont_1a_top", "cw_cont_2a_top", "cw_cont_3a_btm", "cw_cont_4a_btm",
    "cw_ext_1c_top", "cw_ext_2c_top", "cw_ext_3c_btm", "cw_ext_4c_btm",
)
SERVOS = (
    "spring1a_motor", "spring2a_motor", "spring3a_motor", "spring4a_motor",
    "spring1c_motor", "spring2c_motor", "spring3c_motor", "spring4c_motor",
)
DISC_JOINTS = ("disc1b_hinge", "disc2b_hinge", "disc3b_hinge", "disc4b_hinge")
FOOT_GEOMS = ("cylinder3a_con", "cylinder3c_con", "cylinder4a_con", "cylinder4c_con")
BLOCKS = ("block_a", "block_b")
BLOCK_JOINTS = ("block_a_root", "block_b_root")
GOAL_BODY = "goal_marker"

_INTEGRATORS = {
    "euler": mujoco.mjtIntegrator.mjINT_EULER,
    "implicitfast": mujoco.mjtIntegrator.mjINT_IMPLICITFAST,
    "rk4": mujoco.mjtIntegrator.mjINT_RK4,
}
_SOLVERS = {"newton": mujoco.mjtSolver.mjSOL_NEWTON, "cg": mujoco.mjtSolver.mjSOL_CG}
_CONES = {"pyramidal": mujoco.mjtCone.mjCONE_PYRAMIDAL, "elliptic": mujoco.mjtCone.mjCONE_ELLIPTIC}

# mjx.forward compiled once per model layout and shared by the index and the env's reset state
# (eager op-by-op dispatch takes minutes on a CPU for the heightfield scene).
compiled_forward = jax.jit(mjx.forward)


@dataclasses.dataclass(frozen=True)
class RobotIndex:
    """Static ids and addresses resolved by name (numpy, never traced)."""

    joint_qpos: np.ndarray  # (8,) qpos address of each actuated hinge, action-slot order
    joint_qvel: np.ndarray  # (8,) dof address of each actuated hinge
    servo_ids: np.ndarray  # (8,) actuator id of each servo, action-slot order
    block_body: np.ndarray  # (2,) body ids of block_a, block_b
    block_qpos: np.ndarray  # (2,) qpos address of each block's free joint
    block_qvel: np.ndarray  # (2,) dof address of each block's free joint
    constraint_pairs: np.ndarray  # (4, 2) action slots of (kA, kC) for units 1..4
    foot_contacts: np.ndarray  # (4, n) contact slots of each foot's pair in MJX Data
    goal_mocap: int  # mocap index of the goal marker


def scene_path(scene: str, asset_dir: Path | None = None) -> Path:
    """Path of the scene XML for ``scene`` ("flat" or "terrain"), checked to exist."""
    if scene not in SCENE_FILES:
        raise ValueError(f"unknown scene {scene!r}; valid scenes: {sorted(SCENE_FILES)}")
    path = Path(asset_dir or ASSET_DIR) / SCENE_FILES[scene]
    if not path.is_file():
        raise FileNotFoundError(
            f"robot asset not found: {path}. The assets ship in the repository's assets/ folder; "
            "install with `pip install -e .` from a checkout."
        )
    return path


def load_mj_model(config: EnvConfig, asset_dir: Path | None = None) -> mujoco.MjModel:
    """Load the scene for ``config`` as a C MuJoCo model with the configured physics."""
    model = mujoco.MjModel.from_xml_path(str(scene_path(config.scene, asset_dir)))
    phys = config.physics
    model.opt.timestep = phys.timestep
    model.opt.integrator = _INTEGRATORS[phys.integrator]
    model.opt.solver = _SOLVERS[phys.solver]
    model.opt.iterations = phys.iterations
    model.opt.ls_iterations = phys.ls_iterations
    model.opt.tolerance = phys.tolerance
    model.opt.cone = _CONES[phys.cone]
    limit = config.control.servo_target_limit
    model.actuator_ctrlrange[:] = np.array([-limit, limit])
    return model


def _ids(model: mujoco.MjModel, kind: mujoco.mjtObj, names: tuple[str, ...]) -> np.ndarray:
    out = []
    for name in names:
        idx = mujoco.mj_name2id(model, kind, name)
        if idx < 0:
            raise ValueError(f"the robot asset has no {kind.name[6:].lower()} named {name!r}")
        out.append(idx)
    return np.asarray(out, dtype=np.int32)


def _foot_contact_slots(model: mujoco.MjModel, mjx_model: mjx.Model) -> np.ndarray:
    """MJX allocates contacts statically: find the slots that belong to each foot pair."""
    data = compiled_forward(mjx_model, mjx.make_data(mjx_model, device=local_device()))
    geoms = np.asarray(data._impl.contact.geom)
    foot_ids = _ids(model, mujoco.mjtObj.mjOBJ_GEOM, FOOT_GEOMS)
    slots = [np.flatnonzero((geoms == g).any(axis=1)) for g in foot_ids]
    if len({len(s) for s in slots}) != 1 or len(slots[0]) == 0:
        raise ValueError(f"unexpected foot contact layout: {[len(s) for s in slots]} slots per foot")
    return np.stack(slots).astype(np.int32)


def build_index(model: mujoco.MjModel, mjx_model: mjx.Model) -> RobotIndex:
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
        block_body=_ids(model, mujoco.mjtObj.mjOBJ_BODY, BLOCKS),
        block_qpos=model.jnt_qposadr[block_joints].astype(np.int32),
        block_qvel=model.jnt_dofadr[block_joints].astype(np.int32),
        constraint_pairs=np.asarray(pairs, dtype=np.int32),
        foot_contacts=_foot_contact_slots(model, mjx_model),
        goal_mocap=int(model.body_mocapid[goal_body]),
    )


@dataclasses.dataclass(frozen=True)
class RobotModel:
    """The loaded robot: C model (for rendering and oracles), MJX model and name index."""

    mj_model: mujoco.MjModel
    mjx_model: mjx.Model
    index: RobotIndex


def local_device() -> jax.Device:
    """Where MJX model and data go: ``jax.default_device`` when set, else this process's first device.

    MJX's own default (``jax.devices()[0]``) belongs to process 0 on several hosts; the per-device
    training path builds one env per GPU inside ``jax.default_device(gpu)``.
    """
    default = jax.config.jax_default_device
    return default if isinstance(default, jax.Device) else jax.local_devices()[0]


def load_robot(config: EnvConfig, asset_dir: Path | None = None) -> RobotModel:
    """Load the asset for ``config`` once and resolve every name."""
    mj_model = load_mj_model(config, asset_dir)
    mjx_model = mjx.put_model(mj_model, device=local_device())
    return RobotModel(mj_model, mjx_model, build_index(mj_model, mjx_model))
