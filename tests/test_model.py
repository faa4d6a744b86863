"""The shipped asset against the original's facts, and MJX-vs-C MuJoCo parity."""

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from hsa_mjx.config import EnvConfig
from hsa_mjx.resources import scene_path
from hsa_mjx.sim import physics
from hsa_mjx.sim.backend import mjx
from hsa_mjx.sim.model import FOOT_GEOMS, load_mj_model, load_robot

# Parity bound over 100 env steps (2000 physics steps, float32 MJX vs float64 C MuJoCo) under the
# same random servo increments: measured max |dqpos| ~1e-3 rad and block error ~1.5e-4 m (CPU).
PARITY_QPOS_TOL = 1e-2
PARITY_BLOCK_POS_TOL = 2e-3


@pytest.fixture(scope="module")
def robot():
    return load_robot(EnvConfig())


def test_masses_tendons_and_servos_match_the_original(robot):
    m = robot.mj_model
    assert m.body_subtreemass[0] == pytest.approx(6.0)
    assert m.body_subtreemass[m.body("block_a").id] == pytest.approx(3.0)
    assert (m.nq, m.nv, m.nu, m.ntendon, m.npair) == (26, 24, 8, 16, 4)
    rest = sorted(set(np.round(m.tendon_lengthspring[:, 0], 6)))
    assert rest == [0.228364, 0.244847]
    assert np.all(m.tendon_stiffness == 1500) and np.all(m.tendon_damping == 25)
    np.testing.assert_allclose(m.tendon_range, np.tile([0.21, 0.26], (16, 1)))
    np.testing.assert_allclose(m.actuator_gainprm[:, 0], 1.0)
    np.testing.assert_allclose(m.actuator_biasprm[:, :3], np.tile([0, -1, -0.1], (8, 1)))
    np.testing.assert_allclose(m.pair_friction[:, :2], np.tile([0.21, 0.1], (4, 1)))


def test_index_matches_the_original_hard_coded_addresses(robot):
    idx = robot.index
    np.testing.assert_array_equal(idx.joint_qpos, [7, 22, 10, 24, 20, 9, 21, 12])
    np.testing.assert_array_equal(idx.joint_qvel, [6, 20, 9, 22, 18, 8, 19, 11])
    np.testing.assert_array_equal(idx.block_qvel, [0, 12])
    assert idx.foot_sensors.shape == (4, 4, 3)  # 4 feet, up to 4 contacts each, 3 force values
    assert len(set(idx.foot_sensors.ravel().tolist())) == 48 and idx.terrain_mocap == -1  # the plane is static


def test_robot_collides_with_the_floor_only(robot):
    m = robot.mj_model
    floor = m.geom("floor").id
    for g1 in range(m.ngeom):
        for g2 in range(g1 + 1, m.ngeom):
            if floor in (g1, g2):
                continue
            assert not (m.geom_contype[g1] & m.geom_conaffinity[g2] or m.geom_contype[g2] & m.geom_conaffinity[g1])


def test_terrain_scene_uses_world_fixed_friction_order():
    m = load_mj_model(EnvConfig(scene="terrain"))  # one flat tile: the atlas is the asset's field itself
    assert m.nhfield == 1 and tuple(m.hfield_size[0]) == (5, 5, 1.5, 0.01)  # 1.5 m: inclines climb
    assert m.body_mocapid[m.body("terrain_frame").id] >= 0  # the floor moves with its mocap body
    np.testing.assert_allclose(m.pair_friction[:, :2], np.tile([0.1, 0.21], (4, 1)))


def _c_foot_forces(m: mujoco.MjModel, data: mujoco.MjData) -> np.ndarray:
    """|sum of contact-frame forces| of each foot's contacts with the floor, from mj_contactForce."""
    feet, floor, out = [m.geom(name).id for name in FOOT_GEOMS], m.geom("floor").id, np.zeros(4)
    force = np.zeros(6)
    for f, geom in enumerate(feet):
        total = np.zeros(3)
        for i in range(data.ncon):
            if set(data.contact[i].geom) == {geom, floor}:
                mujoco.mj_contactForce(m, data, i, force)
                total += force[:3]
        out[f] = np.linalg.norm(total)
    return out


def test_foot_force_sensors_match_c_contact_forces(robot):
    """The contact sensors give each foot's summed contact force: in C MuJoCo exactly, in MJX from the same state."""
    m, idx = robot.mj_model, robot.index
    data = mujoco.MjData(m)
    data.qpos[idx.block_z] = 0.2
    rng, seen = np.random.default_rng(1), []
    for t in range(600):
        if t % 20 == 0:
            data.ctrl[:] = np.clip(data.ctrl + 0.1785 * rng.uniform(-1, 1, 8), -3141.5, 3141.5)
        mujoco.mj_step(m, data)
        if t % 100 == 99:
            mujoco.mj_forward(m, data)
            oracle = _c_foot_forces(m, data)
            np.testing.assert_allclose(physics.foot_forces(data, idx.foot_sensors), oracle, rtol=1e-6, atol=1e-6)
            dx = jax.jit(mjx.forward)(robot.mjx_model, mjx.put_data(m, data))
            np.testing.assert_allclose(physics.foot_forces(dx, idx.foot_sensors), oracle, rtol=2e-2, atol=0.2)
            seen.append(oracle)
    assert np.count_nonzero(np.asarray(seen) > 1.0) >= 4  # the feet carried load while compared


def test_missing_asset_and_unknown_scene(tmp_path):
    with pytest.raises(FileNotFoundError, match="scene_flat.xml"):
        scene_path("flat", tmp_path)
    with pytest.raises(ValueError, match=r"valid scenes: \['flat', 'terrain'\]"):
        scene_path("moon")


def test_mjx_matches_c_mujoco_for_100_env_steps(robot):
    """Same controls into C MuJoCo and MJX; the trajectories must stay within the stated bound."""
    m, mx, idx = robot.mj_model, robot.mjx_model, robot.index
    data = mujoco.MjData(m)
    data.qpos[idx.block_z] = 0.2
    mujoco.mj_forward(m, data)
    dx = mjx.put_data(m, data)
    step = jax.jit(mjx.step)
    rng = np.random.default_rng(0)
    worst_q = worst_p = 0.0
    for _ in range(100):
        data.ctrl[:] = np.clip(data.ctrl + 0.1785 * rng.uniform(-1, 1, 8), -3141.5, 3141.5)
        dx = dx.replace(ctrl=jnp.asarray(data.ctrl, jnp.float32))
        for _ in range(20):
            mujoco.mj_step(m, data)
            dx = step(mx, dx)
        worst_q = max(worst_q, float(np.abs(np.asarray(dx.qpos) - data.qpos).max()))
        block = np.asarray(dx.xpos)[idx.block_body] - data.xpos[idx.block_body]
        worst_p = max(worst_p, float(np.abs(block).max()))
    assert np.isfinite(worst_q) and worst_q < PARITY_QPOS_TOL, worst_q
    assert worst_p < PARITY_BLOCK_POS_TOL, worst_p
    assert 0.12 < data.xpos[idx.block_body[0], 2] < 0.16  # resting on its feet, as in the original
