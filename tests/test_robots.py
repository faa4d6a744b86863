"""Robot profiles: shipped by name with a source for every figure, one key to choose one, explicit keys
winning over it, older servo keys mapped (config only: no MJX)."""

from __future__ import annotations

import dataclasses

import pytest
import yaml

import hsa_mjx
from hsa_mjx.config import EnvConfig, from_dict, load_config, to_dict, with_overrides
from hsa_mjx.robots import ROBOT_KEYS, load_profile, profile_names, profile_servo, robot_env

HARDWARE = ("dfr05sr", "xl330_m288", "st3215")  # a continuous hobby, a Dynamixel and a strong hobby servo


def test_the_shipped_profiles_and_a_source_for_each_figure():
    assert set(profile_names()) == {"original", *HARDWARE}
    assert with_overrides(hsa_mjx.get_preset("flat"), robot="original") == hsa_mjx.get_preset("flat")
    models = set()
    for name in HARDWARE:
        profile = load_profile(name)
        servo = profile.env["servo"]
        models.add(servo["model"])
        figures = [key for key in servo if key not in ("model", "voltage")]
        assert not [key for key in figures if f"servo.{key}" not in profile.sources], name
        assert "control.max_increment" in profile.sources and {"control", "randomization"} <= set(profile.env)
        assert profile.description and profile.hardware["angle sensor"]
    assert models == {"position", "continuous"}


def test_a_key_given_explicitly_wins_over_the_profile_and_switching_leaves_nothing_behind(tmp_path):
    flat = hsa_mjx.get_preset("flat")
    chosen = with_overrides(flat, robot="dfr05sr", control__max_increment=0.05, **{"servo.friction": 0.04})
    assert chosen.servo.model == "continuous" and chosen.randomization.latency_steps == (1, 1)
    assert chosen.control.max_increment == 0.05 and chosen.servo.friction == 0.04  # the keys given beside it
    assert chosen.goal == flat.goal and chosen.reward == flat.reward  # the task is the preset's
    back = with_overrides(chosen, robot="original")
    for section in ROBOT_KEYS:  # every robot key the original's again
        assert to_dict(back)[section] == to_dict(flat)[section], section
    # a YAML config: the profile, then the file's own keys; a saved config loads as itself
    path = tmp_path / "robot.yaml"
    path.write_text(yaml.safe_dump({"env": {"robot": "xl330_m288", "servo": {"damping": 0.05}}}))
    loaded = load_config(path)
    assert loaded.servo.damping == 0.05 and loaded.servo.stall_torque == 0.52 and loaded.robot == "xl330_m288"
    assert from_dict(to_dict(loaded)) == loaded
    # a profile of one's own, by path (what python -m hsa_mjx.sysid fit writes)
    own = tmp_path / "mine.yaml"
    own.write_text(yaml.safe_dump({"description": "mine", "env": {"servo": {**to_dict(loaded)["servo"], "kp": 3.0}}}))
    mine = with_overrides(flat, robot=str(own))
    assert mine.servo.kp == 3.0 and mine.control == flat.control  # the keys it leaves out: the original's
    assert robot_env(str(own), to_dict(EnvConfig()))["servo"]["kp"] == 3.0


@pytest.mark.parametrize(
    ("profile", "error", "message"),
    [
        ({"env": {"reward": {"forward": 1.0}}}, ValueError, "env section 'reward' is not the robot's"),
        ({"env": {"control": {"frame_skip": 10, "smooth_positions": False}}}, ValueError, "control.smooth_positions"),
        ({"env": {"observation": {"noise": {"position": 0.1}}}}, ValueError, "not the robot's sensors'"),
        ({"speed": 1.0}, ValueError, "unknown section"),
        ({"env": {"servo": {"model": "stepper"}}}, ValueError, "servo.model"),
    ],
)
def test_bad_profiles_are_refused(tmp_path, profile, error, message):
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(profile))
    with pytest.raises(error, match=message):
        with_overrides(hsa_mjx.get_preset("flat"), robot=str(path))


def test_unknown_profiles_and_older_servo_keys():
    with pytest.raises(FileNotFoundError, match="robot profile not found: sg90.*dfr05sr"):
        with_overrides(hsa_mjx.get_preset("flat"), robot="sg90")
    with pytest.raises(ValueError, match="config key 'robot' must be"):
        from_dict({"robot": 3})
    # servo.preset named a servo class: the profile of that name; an empty one is dropped
    assert from_dict({"servo": {"preset": "xl330_m288"}}).robot == "xl330_m288"
    assert from_dict({"servo": {"preset": "", "model": "spring"}}) == EnvConfig()
    with pytest.raises(ValueError, match="servo classes are robot profiles now.*none is named 'mg995'"):
        from_dict({"servo": {"preset": "mg995"}})
    moved = from_dict({"robot": "xl330_m288", "randomization": {"servo_presets": ["dfr05sr"]}})
    assert moved.randomization.robots == ("dfr05sr",)
    assert dataclasses.asdict(profile_servo("dfr05sr"))["encoder_resolution"] > 0


def test_the_task_rule_and_each_profiles_config_follow_the_measured_speeds():
    """benchmarks.robots.speed's rule, and configs/train_flat_<profile>.yaml set to the task it gave."""
    import json
    from pathlib import Path

    from benchmarks.robots.speed import DEFAULT_OUT, scaled_task
    from train import config as train_config
    from train.episodes.policy_sources import default_goal_range

    assert scaled_task(0.234, 0.234).farthest_m == 4.5  # the reference scales to itself
    slow = scaled_task(0.01, 0.234)
    assert (slow.nearest_m, slow.farthest_m) == (0.5, 0.5) and slow.min_episode_s == 150.0  # floored; 3 x 50 s
    rows = {row["robot"]: row for row in json.loads((Path(__file__).parents[1] / DEFAULT_OUT).read_text())["rows"]}
    for name in HARDWARE:
        task = rows[name]["task"]
        config = train_config.load(Path(__file__).parents[1] / "configs" / f"train_flat_{name}.yaml", [])
        assert config.env.robot == name and config.env.randomization.servo_figures == (0.8, 1.2)
        assert default_goal_range(config) == (task["nearest_m"], task["farthest_m"]), name
        assert config.env.termination.max_episode_steps * config.env.dt >= task["min_episode_s"], name
