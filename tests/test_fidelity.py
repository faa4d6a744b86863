"""Fidelity guard, small: the shipped fast physics setting against C MuJoCo at the original settings.

The full comparison (10 s, three gaits, every candidate setting) is ``python -m benchmarks.fidelity.guard``;
its CPU results are in ``benchmarks/results/fidelity/`` and ``docs/speed.md``.
"""

import jax.numpy as jnp
import numpy as np
import pytest

from benchmarks.fidelity import gaits
from benchmarks.fidelity import guard as fidelity
from hsa_mjx.config import EnvConfig
from hsa_mjx.sim.model import load_mj_model

# 3 s of the crawl gait (150 control steps; the robot moves 0.40 m). Same bounds as the 10 s guard:
# displacement within 10 % of the reference (vector error), final yaw within 10 degrees. Measured
# on the CPU for newton4_ls4: 1.8 % and 0.15 degrees (about 50 s here, most of it compiling).
SHORT_DURATION_S = 3.0


@pytest.fixture(scope="module")
def layout():
    return gaits.gait_layout(load_mj_model(EnvConfig()))


def test_gait_layout_is_resolved_by_name(layout):
    # Action slots 1A, 2A, 3A, 4A, 1C, 2C, 3C, 4C: cylinders 1a, 3a, 2c, 4c hang on block A.
    np.testing.assert_array_equal(layout.on_block_a, [1, 0, 1, 0, 0, 1, 0, 1])
    np.testing.assert_array_equal(layout.unit, [1, 2, 3, 4, 1, 2, 3, 4])
    np.testing.assert_array_equal(layout.contracting, [1, 1, 1, 1, 0, 0, 0, 0])


@pytest.mark.parametrize("name", sorted(gaits.GAITS))
def test_gaits_are_bounded_pure_functions_of_time(name, layout):
    actions = gaits.gait_actions(name, layout, 400, 0.02)
    assert actions.shape == (400, 8) and actions.dtype == np.float32
    assert np.all(np.abs(actions) <= 1.0) and np.abs(actions).max() > 0.99
    np.testing.assert_array_equal(actions, gaits.gait_actions(name, layout, 400, 0.02))
    one = np.asarray(gaits.GAITS[name](jnp.float32(1.3), layout))
    np.testing.assert_allclose(one, actions[65], atol=1e-6)  # t = 65 x 0.02 s


def test_crawl_block_a_leads_block_b_by_a_quarter_period(layout):
    actions = gaits.gait_actions("crawl", layout, 200, 0.02)
    a_side, b_side = actions[:, layout.on_block_a == 1], actions[:, layout.on_block_a == 0]
    assert np.all(a_side == a_side[:, :1]) and np.all(b_side == b_side[:, :1])
    quarter = int(gaits.PERIOD_S / 4 / 0.02)
    same = b_side[quarter:, 0] == a_side[:-quarter, 0]
    assert same.mean() > 0.97  # equal except possibly on the switching steps (float rounding)
    assert not np.array_equal(a_side[:, 0], b_side[:, 0])


def test_compare_wraps_heading_and_measures_vector_error():
    path = np.array([[0.0, 0.0], [1.0, 0.0]])
    ref = fidelity.Run(path, 179.0, {})
    cand = fidelity.Run(np.array([[0.0, 0.0], [1.0, 0.05]]), -179.0, {})
    out = fidelity.compare(ref, cand)
    assert out["heading_error_deg"] == pytest.approx(2.0)
    assert out["displacement_error_pct"] == pytest.approx(5.0)
    assert out["pass"]
    assert not fidelity.compare(ref, fidelity.Run(path * 1.2, 179.0, {}))["pass"]
    assert not fidelity.compare(ref, fidelity.Run(path, 179.0, {"non_finite": 1}))["pass"]


@pytest.mark.slow
def test_shipped_setting_tracks_c_mujoco_reference(env):
    """Crawl for 3 s through the env at the shipped setting; compare with C MuJoCo (original settings)."""
    actions = fidelity.gait_matrix(["crawl"], SHORT_DURATION_S)
    start = fidelity.plane_start(env.robot.mj_model, env.index, env.config)  # the env's reset pose
    reference = fidelity.reference_run(actions[0], start=(env.index, start))
    runs, _, _ = fidelity.mjx_runs(fidelity.SETTINGS[fidelity.SHIPPED], actions)
    result = fidelity.compare(reference, runs[0])
    assert result["reference_distance_m"] > 0.05  # the gait really moves the robot
    assert result["displacement_error_pct"] <= 100 * fidelity.DISPLACEMENT_TOL, result
    assert result["heading_error_deg"] <= fidelity.HEADING_TOL_DEG, result
    assert not result["failures"], result


def test_robot_self_collision_changes_nothing_in_c_mujoco(env):
    """Contact pruning (docs/model.md 4): with every robot geom colliding, the crawl is bit-identical."""
    actions = fidelity.gait_matrix(["crawl"], SHORT_DURATION_S)[0]
    start = (env.index, fidelity.plane_start(env.robot.mj_model, env.index, env.config))
    pruned = fidelity.reference_run(actions, start=start)
    original = fidelity.reference_run(actions, all_contacts=True, start=start)
    np.testing.assert_array_equal(pruned.path, original.path)
    assert np.linalg.norm(pruned.displacement) > 0.05
