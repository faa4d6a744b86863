"""benchmarks.robots.policies: which runs play which profile, and the report's pooling and checks."""

from __future__ import annotations

import json

import pytest

from benchmarks.robots import policies as profile_policies
from benchmarks.sweeps import run as sweep


@pytest.fixture(scope="module")
def hardware():
    return sweep.load(profile_policies.SWEEP)


def test_the_family_plays_each_profile_alone_in_its_latency(hardware):
    profiles, families = profile_policies.roles(hardware)
    assert profiles == ["dfr05sr", "xl330_m288", "st3215"] and families == ["family"]
    assert profile_policies.profile_overrides(hardware, "family", "xl330_m288") == [
        "env.randomization.robot_weights=[0,1,0]",
        "env.randomization.latency_steps=[0,0]",
    ]
    assert profile_policies.task(hardware, "dfr05sr")["latency_steps"] == [1, 1]
    with pytest.raises(ValueError, match="draws"):
        profile_policies.profile_overrides(hardware, "family", "original")


def test_seeds_pool_and_checks_pass_on_the_difference(tmp_path):
    folders = []
    for seed, rate in ((0, 0.5), (1, 0.75)):
        folder = tmp_path / str(seed)
        folder.mkdir()
        (folder / "eval.json").write_text(json.dumps({"success_rate": rate, "episodes": 4, "physics": "c_mujoco"}))
        folders.append((seed, folder))
    both = profile_policies.pooled(folders + [(2, tmp_path / "missing")])
    assert both["successes"] == 5 and both["episodes"] == 8 and both["seeds"] == [0, 1]
    assert both["ci95"][0] < 5 / 8 < both["ci95"][1]
    one = profile_policies.pooled(folders[1:])
    assert profile_policies.check(one, both, 0.2)["passed"] and not profile_policies.check(one, both, 0.1)["passed"]
    assert profile_policies.check(None, both, 0.1) is None
