"""The vectorised goal curriculum against the original's rule (pure JAX, no MJX)."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from hsa_mjx.curricula import goal_curriculum

CFG = goal_curriculum.GoalCurriculumConfig()  # the original's shipped values
START = (1.5, 1.8)  # where the range starts (env.goal.radial_range): the original's initial range


class ReferenceCurriculum:
    """The original manager's update rule, one episode at a time, in plain Python."""

    def __init__(self, c: goal_curriculum.GoalCurriculumConfig, start: tuple[float, float] = START):
        self.c, self.start, self.max, self.window, self.count, self.since = c, start, start[1], [], 0, 0

    def record(self, success: bool) -> None:
        c = self.c
        self.window.append(success)
        self.count += 1
        self.since += 1
        if len(self.window) > c.window_size:
            self.window.pop(0)
        if self.since < c.min_episodes or len(self.window) < c.window_size:
            return
        rate = sum(self.window) / len(self.window)
        new = self.max
        if rate >= c.success_threshold:
            new = min(self.max + c.expansion_step, c.target_range[1])
        elif rate < c.failure_threshold:
            new = max(self.max - c.expansion_step, self.start[1])
        if new != self.max:
            self.max, self.window, self.since = new, [], 0


update = jax.jit(goal_curriculum.update, static_argnums=(3, 4))


def record_all(state, outcomes, config=CFG, start=START):
    for o in outcomes:
        state = update(state, jnp.asarray([o]), jnp.asarray([True]), config, start)
    return state


def test_initial_state_and_range():
    state = goal_curriculum.init(CFG, START)
    np.testing.assert_allclose(goal_curriculum.goal_range(state, CFG, START), [1.5, 1.8])
    assert float(goal_curriculum.success_rate(state)) == 0.0
    config = dataclasses.replace(CFG, dead_zone_radius=1.6)
    np.testing.assert_allclose(
        goal_curriculum.goal_range(goal_curriculum.init(config, START), config, START), [1.6, 1.8]
    )


def test_no_change_until_window_full_then_expand_and_clear():
    state = record_all(goal_curriculum.init(CFG, START), [True] * 99)
    assert float(state.max_distance) == pytest.approx(1.8)
    state = record_all(state, [True])
    assert float(state.max_distance) == pytest.approx(1.95)
    assert int(state.filled) == 0 and int(state.episodes_since_change) == 0
    assert int(state.episode_count) == 100


def test_contraction_stops_at_the_start_max():
    state = record_all(goal_curriculum.init(CFG, START), [True] * 100)
    state = record_all(state, [False] * 100)
    assert float(state.max_distance) == pytest.approx(1.8)
    state = record_all(state, [False] * 150)  # at the floor: no change, window keeps rolling
    assert float(state.max_distance) == pytest.approx(1.8)
    assert int(state.filled) == 150  # cleared by the contraction, then never again


def test_ceiling_keeps_rolling_window():
    config, start = dataclasses.replace(CFG, window_size=10, min_episodes=10), (1.5, 4.4)
    state = record_all(goal_curriculum.init(config, start), [True] * 10, config, start)
    assert float(state.max_distance) == pytest.approx(4.5)
    state = record_all(state, [True] * 25, config, start)
    assert float(state.max_distance) == pytest.approx(4.5)
    assert int(state.filled) == 25  # never cleared at the ceiling


def test_matches_reference_one_episode_per_step():
    config = dataclasses.replace(CFG, window_size=20, min_episodes=25)
    rng = np.random.default_rng(3)
    # phases of good and bad performance so the range moves both ways
    probs = np.repeat([0.9, 0.9, 0.1, 0.95, 0.5, 0.05], 60)
    outcomes = rng.random(probs.size) < probs
    ref, state, maxima = ReferenceCurriculum(config), goal_curriculum.init(config, START), []
    for o in outcomes:
        ref.record(bool(o))
        state = update(state, jnp.asarray([o]), jnp.asarray([True]), config, START)
        maxima.append((ref.max, float(state.max_distance)))
    ref_max, ours = np.array(maxima).T
    np.testing.assert_allclose(ours, ref_max, atol=1e-5)
    assert len(set(np.round(ref_max, 3))) >= 3  # the sequence really exercised the rule


def test_batch_only_counts_done_and_keeps_last_window():
    config = dataclasses.replace(CFG, window_size=4, min_episodes=100)
    state = goal_curriculum.init(config, START)
    success = jnp.asarray([False] * 6 + [True] * 4 + [True] * 5)
    done = jnp.asarray([True] * 10 + [False] * 5)
    state = update(state, success, done, config, START)
    assert int(state.episode_count) == 10
    assert float(goal_curriculum.success_rate(state)) == 1.0  # only the last 4 of the 10 finished episodes


def test_batch_update_expands_once_per_step():
    state = goal_curriculum.init(CFG, START)
    state = update(state, jnp.ones(256, bool), jnp.ones(256, bool), CFG, START)
    assert float(state.max_distance) == pytest.approx(1.95)


def test_disabled_is_identity():
    config = dataclasses.replace(CFG, enabled=False)
    state = goal_curriculum.init(config, START)
    new = update(state, jnp.ones(300, bool), jnp.ones(300, bool), config, START)
    assert jax.tree.all(jax.tree.map(lambda a, b: bool(jnp.all(a == b)), state, new))


def test_metrics_keys_and_progress():
    state = record_all(goal_curriculum.init(CFG, START), [True] * 100)
    m = goal_curriculum.metrics(state, CFG, START)
    assert set(m) == {
        "curriculum/max_distance",
        "curriculum/success_rate",
        "curriculum/episode_count",
        "curriculum/episodes_since_change",
        "curriculum/progress",
    }
    assert float(m["curriculum/progress"]) == pytest.approx(0.15 / 2.7, rel=1e-5)
    same = dataclasses.replace(CFG, target_range=(1.5, 1.8))
    start_state = goal_curriculum.init(same, START)
    assert float(goal_curriculum.metrics(start_state, same, START)["curriculum/progress"]) == 1.0  # no division by zero


@pytest.mark.parametrize(
    "change, start, match",
    [
        ({}, (2.0, 1.0), r"start \(env.goal.radial_range\)"),
        ({"target_range": (1.5, 1.0)}, START, "target_range"),
        ({"success_threshold": 0.2, "failure_threshold": 0.5}, START, "threshold"),
        ({"window_size": 0}, START, "window_size"),
        ({"expansion_step": 0.0}, START, "expansion_step"),
        ({"dead_zone_radius": 2.0}, START, "dead_zone"),
    ],
)
def test_validate_rejects_bad_settings(change, start, match):
    with pytest.raises(ValueError, match=match):
        goal_curriculum.validate(dataclasses.replace(CFG, **change), start)
