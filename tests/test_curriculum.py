"""The vectorised goal curriculum against the original's rule (pure JAX, no MJX)."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from hsa_mjx.curricula import goal as cur

CFG = cur.CurriculumConfig()  # the original's shipped values


class ReferenceCurriculum:
    """The original manager's update rule, one episode at a time, in plain Python."""

    def __init__(self, c: cur.CurriculumConfig):
        self.c, self.max, self.window, self.count, self.since = c, c.initial_range[1], [], 0, 0

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
            new = max(self.max - c.expansion_step, c.initial_range[1])
        if new != self.max:
            self.max, self.window, self.since = new, [], 0


update = jax.jit(cur.update, static_argnums=3)


def record_all(state, outcomes, config=CFG):
    for o in outcomes:
        state = update(state, jnp.asarray([o]), jnp.asarray([True]), config)
    return state


def test_initial_state_and_range():
    state = cur.init(CFG)
    np.testing.assert_allclose(cur.goal_range(state, CFG), [1.5, 1.8])
    assert float(cur.success_rate(state)) == 0.0
    config = dataclasses.replace(CFG, dead_zone_radius=1.6)
    np.testing.assert_allclose(cur.goal_range(cur.init(config), config), [1.6, 1.8])


def test_no_change_until_window_full_then_expand_and_clear():
    state = record_all(cur.init(CFG), [True] * 99)
    assert float(state.max_distance) == pytest.approx(1.8)
    state = record_all(state, [True])
    assert float(state.max_distance) == pytest.approx(1.95)
    assert int(state.filled) == 0 and int(state.episodes_since_change) == 0
    assert int(state.episode_count) == 100


def test_contraction_stops_at_initial_max():
    state = record_all(cur.init(CFG), [True] * 100)
    state = record_all(state, [False] * 100)
    assert float(state.max_distance) == pytest.approx(1.8)
    state = record_all(state, [False] * 150)  # at the floor: no change, window keeps rolling
    assert float(state.max_distance) == pytest.approx(1.8)
    assert int(state.filled) == 150  # cleared by the contraction, then never again


def test_ceiling_keeps_rolling_window():
    config = dataclasses.replace(CFG, initial_range=(1.5, 4.4), window_size=10, min_episodes=10)
    state = record_all(cur.init(config), [True] * 10, config)
    assert float(state.max_distance) == pytest.approx(4.5)
    state = record_all(state, [True] * 25, config)
    assert float(state.max_distance) == pytest.approx(4.5)
    assert int(state.filled) == 25  # never cleared at the ceiling


def test_matches_reference_one_episode_per_step():
    config = dataclasses.replace(CFG, window_size=20, min_episodes=25)
    rng = np.random.default_rng(3)
    # phases of good and bad performance so the range moves both ways
    probs = np.repeat([0.9, 0.9, 0.1, 0.95, 0.5, 0.05], 60)
    outcomes = rng.random(probs.size) < probs
    ref, state, maxima = ReferenceCurriculum(config), cur.init(config), []
    for o in outcomes:
        ref.record(bool(o))
        state = update(state, jnp.asarray([o]), jnp.asarray([True]), config)
        maxima.append((ref.max, float(state.max_distance)))
    ref_max, ours = np.array(maxima).T
    np.testing.assert_allclose(ours, ref_max, atol=1e-5)
    assert len(set(np.round(ref_max, 3))) >= 3  # the sequence really exercised the rule


def test_batch_only_counts_done_and_keeps_last_window():
    config = dataclasses.replace(CFG, window_size=4, min_episodes=100)
    state = cur.init(config)
    success = jnp.asarray([False] * 6 + [True] * 4 + [True] * 5)
    done = jnp.asarray([True] * 10 + [False] * 5)
    state = update(state, success, done, config)
    assert int(state.episode_count) == 10
    assert float(cur.success_rate(state)) == 1.0  # only the last 4 of the 10 finished episodes


def test_batch_update_expands_once_per_step():
    state = cur.init(CFG)
    state = update(state, jnp.ones(256, bool), jnp.ones(256, bool), CFG)
    assert float(state.max_distance) == pytest.approx(1.95)


def test_disabled_is_identity():
    config = dataclasses.replace(CFG, enabled=False)
    state = cur.init(config)
    new = update(state, jnp.ones(300, bool), jnp.ones(300, bool), config)
    assert jax.tree.all(jax.tree.map(lambda a, b: bool(jnp.all(a == b)), state, new))


def test_metrics_keys_and_progress():
    state = record_all(cur.init(CFG), [True] * 100)
    m = cur.metrics(state, CFG)
    assert set(m) == {
        "curriculum/max_distance",
        "curriculum/success_rate",
        "curriculum/episode_count",
        "curriculum/episodes_since_change",
        "curriculum/progress",
    }
    assert float(m["curriculum/progress"]) == pytest.approx(0.15 / 2.7, rel=1e-5)
    same = dataclasses.replace(CFG, target_range=(1.5, 1.8))
    assert float(cur.metrics(cur.init(same), same)["curriculum/progress"]) == 1.0  # no division by zero


@pytest.mark.parametrize(
    "change, match",
    [
        ({"initial_range": (2.0, 1.0)}, "initial_range"),
        ({"target_range": (1.5, 1.0)}, "target_range"),
        ({"success_threshold": 0.2, "failure_threshold": 0.5}, "threshold"),
        ({"window_size": 0}, "window_size"),
        ({"expansion_step": 0.0}, "expansion_step"),
        ({"dead_zone_radius": 2.0}, "dead_zone"),
    ],
)
def test_validate_rejects_bad_settings(change, match):
    with pytest.raises(ValueError, match=match):
        cur.validate(dataclasses.replace(CFG, **change))
