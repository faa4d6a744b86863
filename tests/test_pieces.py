"""Control, goals, observation and termination on synthetic inputs (no MJX compile)."""

from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from hsa_mjx.config import GoalConfig, ObservationConfig, TerminationConfig
from hsa_mjx.sim import physics
from hsa_mjx.task import control, goals, observation, termination


def test_targets_are_clipped_to_ctrlrange():
    out = control.next_targets(jnp.array([6.2, -6.2]), jnp.array([1.0, -1.0]), 0.1785, 6.28)
    np.testing.assert_allclose(out, [6.28, -6.28], rtol=1e-6)


def test_smooth_targets_ramp_and_end_exactly():
    ramp = control.substep_targets(jnp.zeros(8), jnp.ones(8), 20, True)
    assert ramp.shape == (20, 8)
    np.testing.assert_allclose(ramp[0], 0.05)
    np.testing.assert_allclose(ramp[-1], 1.0)
    hold = control.substep_targets(jnp.zeros(8), jnp.ones(8), 20, False)
    np.testing.assert_allclose(hold, 1.0)


def test_sanitize_action():
    clean, bad = control.sanitize_action(jnp.array([jnp.nan, 2.0, -jnp.inf, 0.5]))
    np.testing.assert_allclose(clean, [0.0, 1.0, 0.0, 0.5])
    assert bool(bad)
    assert not bool(control.sanitize_action(jnp.zeros(3))[1])


def test_spiral_checkpoints_match_the_original():
    pts = goals.spiral_checkpoints(GoalConfig(num_checkpoints=8))
    expected = [(0, 0.9375), (1.375, 0), (0, -1.8125), (-2.25, 0), (0, 2.6875), (3.125, 0), (0, -3.5625), (-4, 0)]
    np.testing.assert_allclose(pts, expected, atol=1e-5)


def test_original_random_goal_ranges():
    keys = jax.random.split(jax.random.PRNGKey(0), 512)
    flat = jax.vmap(lambda k: goals.original_random_goal(k, "flat"))(keys)
    assert np.all((np.abs(flat[:, 0]) >= 1.5) & (np.abs(flat[:, 0]) <= 4.5)) and np.all(np.abs(flat[:, 1]) <= 4)
    assert (flat[:, 0] > 0).mean() == pytest.approx(0.5, abs=0.1)
    other = jax.vmap(lambda k: goals.original_random_goal(k, "corridor"))(keys)
    assert np.all((np.abs(other[:, 0]) >= 1.5) & (np.abs(other[:, 0]) <= 2.0)) and np.all(other[:, 1] == 0)


def test_radial_goal_range_is_traced():
    keys = jax.random.split(jax.random.PRNGKey(1), 256)
    sample = jax.jit(jax.vmap(goals.radial_goal, in_axes=(0, None)))
    for lo, hi in ((1.5, 1.8), (2.0, 4.5)):
        r = np.linalg.norm(sample(keys, jnp.array([lo, hi])), axis=1)
        assert r.min() >= lo - 1e-5 and r.max() <= hi + 1e-5


def test_radial_goal_bearing_window():
    keys = jax.random.split(jax.random.PRNGKey(2), 512)
    side = jax.vmap(lambda k: goals.radial_goal(k, jnp.array([0.8, 1.2]), (60.0, 120.0)))(keys)
    bearing = np.degrees(np.arctan2(side[:, 1], side[:, 0]))
    assert np.all((np.abs(bearing) >= 60 - 1e-3) & (np.abs(bearing) <= 120 + 1e-3))
    assert (bearing > 0).mean() == pytest.approx(0.5, abs=0.1)  # left and right alike
    r = np.linalg.norm(side, axis=1)
    assert r.min() >= 0.8 - 1e-5 and r.max() <= 1.2 + 1e-5
    # the default window is the whole circle, drawn exactly as before the option existed
    full = jax.vmap(lambda k: goals.radial_goal(k, jnp.array([1.5, 1.8])))(keys)
    explicit = jax.vmap(lambda k: goals.radial_goal(k, jnp.array([1.5, 1.8]), goals.FULL_CIRCLE))(keys)
    np.testing.assert_array_equal(full, explicit)
    assert np.abs(np.degrees(np.arctan2(full[:, 1], full[:, 0]))).min() < 10  # goals ahead exist


def test_checkpoint_advance():
    pts = jnp.array([[1.0, 0.0], [2.0, 0.0]])
    got, done, idx = goals.advance_checkpoint(jnp.array([0.7, 0.0]), pts, jnp.array(0), 0.4)
    assert bool(got) and not bool(done) and int(idx) == 1
    got, done, idx = goals.advance_checkpoint(jnp.array([0.0, 0.0]), pts, jnp.array(1), 0.4)
    assert not bool(got) and int(idx) == 1
    got, done, idx = goals.advance_checkpoint(jnp.array([2.1, 0.0]), pts, jnp.array(1), 0.4)
    assert bool(got) and bool(done) and int(idx) == 1


def _stats(qvel=0.0, qacc=0.0, bad=False, final_qacc=None):
    final = qacc if final_qacc is None else final_qacc
    return physics.SubstepStats(jnp.array(qvel), jnp.array(qacc), jnp.array(bad), jnp.array(final))


def _reasons(z, stats, obs_finite=True, ground=0.0, config=TerminationConfig()):
    data = SimpleNamespace(xpos=jnp.zeros((3, 3)).at[1, 2].set(z[0]).at[2, 2].set(z[1]))
    index = SimpleNamespace(block_body=np.array([1, 2]))
    r = termination.failure_reasons(data, stats, jnp.array(obs_finite), jnp.array(ground), config, index)
    return {k: bool(v) for k, v in r.items() if bool(v)}


def test_termination_reasons_are_named():
    assert _reasons((0.14, 0.14), _stats()) == {}
    assert _reasons((0.6, 0.14), _stats()) == {"block_a_too_high": True}
    assert _reasons((0.14, -0.6), _stats()) == {"block_b_too_low": True}
    assert _reasons((0.9, 0.9), _stats(), ground=0.5) == {}  # heights count from the ground
    assert _reasons((0.14, 0.14), _stats(qvel=2001.0)) == {"qvel_limit": True}
    assert _reasons((0.14, 0.14), _stats(qacc=2e4)) == {"qacc_limit": True}
    assert _reasons((0.14, 0.14), _stats(bad=True)) == {"non_finite": True}
    assert _reasons((0.14, 0.14), _stats(), obs_finite=False) == {"non_finite": True}


def test_substep_stats_keep_the_worst():
    a, b = _stats(1.0, 5.0, False), _stats(3.0, 2.0, True)
    m = physics.merge_stats(a, b)
    assert float(m.max_abs_qvel) == 3.0 and float(m.max_abs_qacc) == 5.0 and bool(m.non_finite)
    assert float(m.final_abs_qacc) == 2.0  # the later substep's, not the worst


def test_qacc_limit_checks_the_last_substep_unless_asked_for_every_one():
    transient = _stats(qacc=5e4, final_qacc=100.0)  # a spike inside the step, gone at its end
    assert _reasons((0.14, 0.14), transient) == {}
    every = TerminationConfig(qacc_every_substep=True)
    assert _reasons((0.14, 0.14), transient, config=every) == {"qacc_limit": True}
    assert _reasons((0.14, 0.14), _stats(qacc=5e4, final_qacc=2e4)) == {"qacc_limit": True}


def _fake_robot(block_a_xy, block_b_xy):
    """Synthetic data and index for ``observation.observe``: two blocks, 8 hinges, rest elsewhere."""
    xpos = jnp.zeros((3, 3)).at[1, :2].set(jnp.array(block_a_xy)).at[2, :2].set(jnp.array(block_b_xy))
    data = SimpleNamespace(xpos=xpos, qpos=jnp.arange(30.0), qvel=jnp.arange(30.0) / 10, ctrl=-jnp.arange(12.0) / 4)
    index = SimpleNamespace(
        block_body=np.array([1, 2]),
        joint_qpos=np.arange(7, 15),
        joint_qvel=np.arange(6, 14),
        block_qvel=np.array([0, 14]),
        servo_ids=np.array([3, 1, 4, 1, 5, 9, 2, 6]),
    )
    return data, index


def test_optional_observation_entries_come_after_the_original_in_a_fixed_order():
    sizes = {
        (h, t, c): observation.observation_size(ObservationConfig(heading=h, servo_targets=t, clock_period_s=c))
        for h in (False, True)
        for t in (False, True)
        for c in (0.0, 4.0)
    }
    assert sizes == {(h, t, c): 24 + 4 * h + 8 * t + 2 * (c > 0) for h, t, c in sizes}
    data, index = _fake_robot((-0.2, 0.0), (0.2, 0.0))
    goal = jnp.array([0.0, 3.0])
    base = observation.observe(data, goal, index)
    full = observation.observe(
        data, goal, index, ObservationConfig(heading=True, servo_targets=True, clock_period_s=4.0), time_s=1.0
    )
    assert full.shape == (38,) and full.dtype == jnp.float32
    np.testing.assert_array_equal(full[:24], base)
    np.testing.assert_array_equal(full[28:36], -np.array([3, 1, 4, 1, 5, 9, 2, 6]) / 4)  # ctrl by servo id
    np.testing.assert_allclose(full[36:38], [1.0, 0.0], atol=1e-6)  # a quarter period: sin 1, cos 0
    no_heading = observation.observe(data, goal, index, ObservationConfig(servo_targets=True))
    np.testing.assert_array_equal(no_heading[24:], full[28:36])


def test_hinge_angle_modes_wrap_or_expand_only_the_first_eight_values():
    angles = jnp.array([0.0, 1.0, -1.0, 3.0, 4.0, -4.0, 601.0, -298.5])  # wound up, as in a long episode
    wrapped = np.asarray(observation.observed_hinge_angles(angles, "wrapped"))
    assert np.all((wrapped >= -np.pi) & (wrapped < np.pi))
    np.testing.assert_allclose(wrapped[:3], [0.0, 1.0, -1.0], atol=1e-6)  # already in range: unchanged
    np.testing.assert_allclose(np.cos(wrapped), np.cos(np.asarray(angles)), atol=1e-4)  # the same angle
    np.testing.assert_allclose(np.sin(wrapped), np.sin(np.asarray(angles)), atol=1e-4)
    sincos = np.asarray(observation.observed_hinge_angles(angles, "sincos"))
    np.testing.assert_allclose(sincos, np.concatenate([np.sin(angles), np.cos(angles)]), atol=1e-6)
    data, index = _fake_robot((-0.2, 0.0), (0.2, 0.0))
    data.qpos = data.qpos.at[index.joint_qpos].add(100.0)  # hinge angles 107..114 rad
    goal, raw_config = jnp.array([0.0, 3.0]), ObservationConfig(heading=True)
    raw = observation.observe(data, goal, index, raw_config)
    for mode, size in (("wrapped", 28), ("sincos", 36)):
        config = ObservationConfig(heading=True, hinge_angles=mode)
        obs = observation.observe(data, goal, index, config)
        assert obs.shape == (observation.observation_size(config),) == (size,)
        np.testing.assert_array_equal(obs[size - 20 :], raw[8:])  # everything after the angles is unchanged
        labels = observation.observation_labels(config)
        assert len(labels) == len(set(labels)) == size and labels[size - 20] == "hinge_velocity_0"
    np.testing.assert_allclose(
        observation.observe(data, goal, index, ObservationConfig(hinge_angles="wrapped"))[:8],
        np.mod(np.arange(107.0, 115.0) + np.pi, 2 * np.pi) - np.pi,
        atol=1e-4,
    )


def test_gait_clock_is_periodic_and_exact_late_in_long_episodes():
    period = 4.0
    times = jnp.array([0.0, 1.0, 2.0, 3.0, 4.0, 159.5, 160.0])  # up to the spiral's 8,000 steps x 0.02 s
    clock = np.asarray(jax.vmap(lambda t: observation.gait_clock(t, period))(times))
    phase = 2 * np.pi * np.asarray(times, np.float64) / period
    np.testing.assert_allclose(clock, np.stack([np.sin(phase), np.cos(phase)], 1), atol=1e-5)
    np.testing.assert_allclose(np.linalg.norm(clock, axis=1), 1.0, atol=1e-6)


def test_observation_size_follows_the_heading_option():
    assert observation.observation_size(ObservationConfig()) == observation.OBSERVATION_SIZE == 24
    assert observation.observation_size(ObservationConfig(heading=True)) == 28
    data, index = _fake_robot((-0.2, 0.0), (0.2, 0.0))
    goal = jnp.array([0.0, 3.0])
    base = observation.observe(data, goal, index)
    assert base.shape == (24,) and base.dtype == jnp.float32
    full = observation.observe(data, goal, index, ObservationConfig(heading=True))
    assert full.shape == (28,)
    np.testing.assert_array_equal(full[:24], base)  # the original's 24 values come first, unchanged
    labels = observation.observation_labels(ObservationConfig(heading=True, servo_targets=True, clock_period_s=4.0))
    assert (
        len(labels) == len(set(labels)) == 38
        and labels[24] == "heading_cos"
        and labels[-2:] == ("clock_sin", "clock_cos")
    )


def test_heading_frame_rotation_on_hand_made_vectors():
    along_y = jnp.array([0.0, 1.0])
    np.testing.assert_allclose(observation.to_heading_frame(jnp.array([0.0, 1.0]), along_y), [1.0, 0.0], atol=1e-7)
    np.testing.assert_allclose(observation.to_heading_frame(jnp.array([-1.0, 0.0]), along_y), [0.0, 1.0], atol=1e-7)
    np.testing.assert_allclose(observation.to_heading_frame(jnp.array([1.0, 0.0]), along_y), [0.0, -1.0], atol=1e-7)
    diagonal = jnp.array([np.sqrt(0.5), np.sqrt(0.5)])  # yaw 45 degrees
    np.testing.assert_allclose(
        observation.to_heading_frame(jnp.array([1.0, 0.0]), diagonal), [np.sqrt(0.5), -np.sqrt(0.5)], atol=1e-7
    )


def test_heading_points_from_block_a_to_block_b_and_stays_finite():
    data, index = _fake_robot((1.0, 1.0), (1.0, 1.5))  # block B north of block A: yaw 90 degrees
    np.testing.assert_allclose(observation.heading(data, index), [0.0, 1.0], atol=1e-6)
    full = observation.observe(data, jnp.array([-2.0, 1.25]), index, ObservationConfig(heading=True))
    np.testing.assert_allclose(full[24:26], [0.0, 1.0], atol=1e-6)
    np.testing.assert_allclose(full[26:28], [0.0, 1.0], atol=1e-6)  # goal due west: on the robot's left
    same, index = _fake_robot((0.5, 0.5), (0.5, 0.5))  # coincident origins: no direction, but finite
    assert np.all(np.isfinite(observation.heading(same, index)))
