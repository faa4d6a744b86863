"""Reward terms on synthetic inputs (pure functions, no MJX)."""

import jax.numpy as jnp
import numpy as np
import pytest

import hsa_mjx.task.reward
from hsa_mjx.config import RewardConfig

W = hsa_mjx.task.reward.RewardWeights.from_config(RewardConfig())


def inputs(**kw):
    base = dict(
        velocity=jnp.zeros(2),
        goal_direction=jnp.array([1.0, 0.0]),
        action=jnp.zeros(8),
        prev_action=jnp.zeros(8),
        joint_pos=jnp.zeros(8),
        joint_vel=jnp.zeros(8),
        prev_joint_vel=jnp.zeros(8),
        foot_force=jnp.zeros(4),
        distance=jnp.array(2.0),
        prev_distance=jnp.array(2.0),
        stagnation_progress=jnp.array(1.0),
        history_full=jnp.array(True),
        checkpoint_collected=jnp.array(False),
        spiral_complete=jnp.array(False),
        goal_reached=jnp.array(False),
        failed=jnp.array(False),
        terminated=jnp.array(False),
        heading_before=jnp.array([1.0, 0.0]),
        heading_after=jnp.array([1.0, 0.0]),
        dt=0.02,
    )
    base.update(kw)
    return hsa_mjx.task.reward.RewardInputs(**base)


def test_forward_is_signed_unless_rectified():
    back = inputs(velocity=jnp.array([-0.5, 0.0]))
    assert float(hsa_mjx.task.reward.forward(back, W)) == pytest.approx(-3.0)
    assert float(hsa_mjx.task.reward.forward(back.replace(rectified_forward=True), W)) == 0.0
    assert float(hsa_mjx.task.reward.forward(inputs(velocity=jnp.array([0.5, 0.2])), W)) == pytest.approx(3.0)


def test_lateral_is_a_cost():
    w = W.with_weights(lateral_cost=jnp.float32(1.0))
    assert float(hsa_mjx.task.reward.lateral_cost(inputs(velocity=jnp.array([0.0, -0.3])), w)) == pytest.approx(-0.3)


def test_ctrl_cost_and_cap():
    x = inputs(action=jnp.ones(8), prev_action=-jnp.ones(8))
    assert float(hsa_mjx.task.reward.ctrl_cost(x, W)) == pytest.approx(-0.001 * 32)
    assert float(hsa_mjx.task.reward.ctrl_cost(x, W.with_weights(ctrl_cost=jnp.float32(10.0)))) == -20.0


def test_caps_and_clips_are_weights_of_the_table():
    """Each cost's cap and each clip is a RewardConfig field, read per env like a weight."""
    big = inputs(action=jnp.ones(8), prev_action=-jnp.ones(8), velocity=jnp.array([9.0, -9.0]))
    heavy = W.with_weights(ctrl_cost=jnp.float32(10.0), ctrl_cost_cap=jnp.float32(3.0), lateral_cost=jnp.float32(1.0))
    assert float(hsa_mjx.task.reward.ctrl_cost(big, heavy)) == -3.0
    assert float(hsa_mjx.task.reward.forward(big, W)) == pytest.approx(6.0 * 5.0)  # clipped at 5 m/s
    assert float(hsa_mjx.task.reward.lateral_cost(big, heavy.with_weights(velocity_clip=2.0))) == pytest.approx(-2.0)
    fast = inputs(joint_vel=jnp.full(8, 100.0))
    assert float(
        hsa_mjx.task.reward.joint_velocity_cost(fast, W.with_weights(joint_velocity_clip=1.0))
    ) == pytest.approx(-5e-4 * 8)


def test_contact_cost_uses_force_above_threshold():
    x = inputs(foot_force=jnp.array([14.7, 49.0, 60.0, 0.0]))
    assert float(hsa_mjx.task.reward.contact_cost(x, W)) == pytest.approx(-0.0005 * 100.0)
    huge = inputs(foot_force=jnp.full(4, 1e4))
    assert float(hsa_mjx.task.reward.contact_cost(huge, W)) == -30.0


def test_constraint_cost_and_bonus():
    q = jnp.zeros(8).at[0].set(1.6).at[4].set(-1.6)  # pair 1: |A - C| = 3.2 > pi
    x = inputs(joint_pos=q)
    assert float(hsa_mjx.task.reward.constraint_cost(x, W)) == pytest.approx(-0.05)
    assert float(hsa_mjx.task.reward.constraint_bonus(x, W)) == pytest.approx(0.075)
    mid = jnp.zeros(8).at[0].set((np.pi - 0.005) / 2).at[4].set(-(np.pi - 0.005) / 2)  # half the ramp
    assert float(hsa_mjx.task.reward.constraint_cost(inputs(joint_pos=mid), W)) == pytest.approx(-0.05 * 0.25, rel=1e-2)
    assert float(hsa_mjx.task.reward.constraint_bonus(inputs(), W)) == pytest.approx(0.1)


def test_acceleration_and_joint_velocity_clips_and_caps():
    x = inputs(joint_vel=jnp.full(8, 0.1))  # (0.1 - 0) / 0.02 = 5 rad/s^2
    assert float(hsa_mjx.task.reward.acceleration_cost(x, W)) == pytest.approx(-1e-5 * 8 * 25)
    fast = inputs(joint_vel=jnp.full(8, 1e3))
    assert float(hsa_mjx.task.reward.acceleration_cost(fast, W)) == pytest.approx(-1e-5 * 8 * 2500)
    assert float(hsa_mjx.task.reward.joint_velocity_cost(fast, W)) == pytest.approx(-5e-4 * 8 * 2500)
    one = W.with_weights(acceleration_cost=jnp.float32(1.0))
    assert float(hsa_mjx.task.reward.acceleration_cost(fast, one)) == -20.0


def test_distance_progress_and_stagnation():
    assert float(
        hsa_mjx.task.reward.distance(inputs(prev_distance=jnp.array(2.0), distance=jnp.array(1.9)), W)
    ) == pytest.approx(1.0)
    assert float(hsa_mjx.task.reward.stagnation_cost(inputs(stagnation_progress=jnp.array(0.01)), W)) == pytest.approx(
        -0.15 * 0.8
    )
    assert (
        float(
            hsa_mjx.task.reward.stagnation_cost(
                inputs(stagnation_progress=jnp.array(0.0), history_full=jnp.array(False)), W
            )
        )
        == 0.0
    )


def test_bonuses_alive_and_termination():
    assert float(hsa_mjx.task.reward.goal_bonus(inputs(goal_reached=jnp.array(True)), W)) == 40.0
    assert float(hsa_mjx.task.reward.checkpoint(inputs(checkpoint_collected=jnp.array(True)), W)) == 200.0
    assert float(hsa_mjx.task.reward.spiral_completion(inputs(spiral_complete=jnp.array(True)), W)) == 100.0
    assert float(hsa_mjx.task.reward.alive(inputs(), W)) == pytest.approx(0.03)
    assert float(hsa_mjx.task.reward.alive(inputs(terminated=jnp.array(True)), W)) == 0.0
    failed = inputs(failed=jnp.array(True), terminated=jnp.array(True))
    assert float(hsa_mjx.task.reward.termination(failed, W.with_weights(termination=jnp.float32(7.0)))) == -7.0


def test_components_are_named_and_sum_to_total():
    x = inputs(velocity=jnp.array([0.3, 0.1]), action=jnp.ones(8), distance=jnp.array(1.95))
    comps = hsa_mjx.task.reward.compute_rewards(x, W)
    assert tuple(comps) == hsa_mjx.task.reward.TERM_NAMES and len(comps) == 16
    assert float(hsa_mjx.task.reward.total_reward(comps)) == pytest.approx(
        sum(float(v) for v in comps.values()), rel=1e-6
    )


def _unit(deg):
    return jnp.array([np.cos(np.radians(deg)), np.sin(np.radians(deg))], jnp.float32)


def test_heading_alignment_pays_turning_towards_the_goal_either_end():
    w = W.with_weights(heading_alignment=jnp.float32(100.0))
    assert (
        float(hsa_mjx.task.reward.heading_alignment(inputs(heading_before=_unit(30), heading_after=_unit(60)), W))
        == 0.0
    )
    side = dict(goal_direction=_unit(90))  # goal to the left of a robot facing +x
    towards = inputs(heading_before=_unit(0), heading_after=_unit(30), **side)
    assert float(hsa_mjx.task.reward.heading_alignment(towards, w)) == pytest.approx(50.0, rel=1e-5)
    away = inputs(heading_before=_unit(30), heading_after=_unit(0), **side)
    assert float(hsa_mjx.task.reward.heading_alignment(away, w)) == pytest.approx(-50.0, rel=1e-5)
    backwards = inputs(heading_before=_unit(0), heading_after=_unit(-30), **side)  # tail swings to the goal
    assert float(hsa_mjx.task.reward.heading_alignment(backwards, w)) == pytest.approx(50.0, rel=1e-5)


def test_heading_alignment_telescopes_over_a_full_spin():
    w = W.with_weights(heading_alignment=jnp.float32(100.0))
    angles = np.arange(0, 361, 15)
    total = sum(
        float(
            hsa_mjx.task.reward.heading_alignment(
                inputs(heading_before=_unit(a), heading_after=_unit(b), goal_direction=_unit(70)), w
            )
        )
        for a, b in zip(angles[:-1], angles[1:])
    )
    assert abs(total) < 1e-3


def test_the_weights_are_one_table_the_config():
    """The traced weights are RewardConfig's float fields under their names; every one is read by a term
    (or, the termination penalty, by the env's non-finite guard) and no term reads another."""
    import ast
    import dataclasses
    import inspect

    floats = tuple(f.name for f in dataclasses.fields(RewardConfig) if f.type in (float, "float"))
    assert hsa_mjx.task.reward.WEIGHT_NAMES == floats and set(W.values) == set(floats)
    assert set(hsa_mjx.task.reward.TERM_NAMES) <= set(floats)  # every term's weight has the term's name
    tree = ast.parse(inspect.getsource(hsa_mjx.task.reward))
    read = {n.attr for n in ast.walk(tree) if isinstance(n, ast.Attribute) and getattr(n.value, "id", None) == "w"}
    assert read <= set(floats) and set(floats) <= read | {"termination"}
    assert float(W.with_weights(forward=2.0).forward) == 2.0 and float(W.forward) == RewardConfig().forward
    with pytest.raises(ValueError, match=r"unknown reward weight\(s\) \['speed'\]"):
        W.with_weights(speed=1.0)
    with pytest.raises(AttributeError, match="no weight 'speed'"):
        _ = W.speed


def test_older_reward_weight_names_load_as_the_terms_names():
    from hsa_mjx.config import from_dict

    old = from_dict({"reward": {"ctrl": 0.5, "stagnation": 0.2, "lateral": 0.1}}).reward
    assert (old.ctrl_cost, old.stagnation_cost, old.lateral_cost) == (0.5, 0.2, 0.1)
    assert from_dict({"reward": {"ctrl": 0.5, "ctrl_cost": 0.5}}).reward.ctrl_cost == 0.5  # the same value twice
    with pytest.raises(ValueError, match="'reward.ctrl' = 1.0 differs from 'reward.ctrl_cost' = 2.0"):
        from_dict({"reward": {"ctrl": 1.0, "ctrl_cost": 2.0}})
