"""The original hsa_gym HSAEnv arguments: each one's config value, the refusals, warnings and conflicts."""

import warnings
from pathlib import Path

import gymnasium
import pytest

import hsa_mjx
from hsa_mjx import build_config
from hsa_mjx.adapters.original_args import ORIGINAL_ARGS, RENDER_ARGS, OriginalArgumentWarning
from hsa_mjx.adapters.rendering import check_camera

# The original HSAEnv's keyword arguments (hsa_gym API reference) and the viewer arguments its base
# class took through **kwargs.
ORIGINAL_SIGNATURE = (
    "xml_file",
    "frame_skip",
    "default_camera_config",
    "forward_reward_weight",
    "ctrl_cost_weight",
    "actuator_group",
    "action_group",
    "smooth_positions",
    "clip_actions",
    "contact_cost_weight",
    "yvel_cost_weight",
    "constraint_cost_weight",
    "acc_cost_weight",
    "distance_reward_weight",
    "early_termination_penalty",
    "joint_vel_cost_weight",
    "stagnation_penalty_weight",
    "alive_bonus",
    "max_increment",
    "enable_terrain",
    "terrain_type",
    "goal_position",
    "num_checkpoints",
    "checkpoint_reward",
    "checkpoint_radius",
    "start_radius",
    "end_radius",
    "num_turns",
    "max_episode_steps",
    "ensure_flat_spawn",
)
BASE_CLASS_VIEWER = ("render_mode", "width", "height", "camera_id", "camera_name", "max_geom", "visual_options")

# argument -> (value, {dotted config key: expected value}); values differ from the flat preset's
MAPPED = {
    "xml_file": ("hsaLooseModel.xml", {"control.servo_target_limit": 6.28}),
    "frame_skip": (10, {"control.frame_skip": 10}),
    "max_increment": (0.3, {"control.max_increment": 0.3}),
    "smooth_positions": (False, {"control.smooth_positions": False}),
    "forward_reward_weight": (3.0, {"reward.forward": 3.0}),
    "ctrl_cost_weight": (0.01, {"reward.ctrl_cost": 0.01}),
    "contact_cost_weight": (0.002, {"reward.contact_cost": 0.002}),
    "yvel_cost_weight": (0.5, {"reward.lateral_cost": 0.5}),
    "constraint_cost_weight": (0.2, {"reward.constraint_cost": 0.2}),
    "acc_cost_weight": (0.01, {"reward.acceleration_cost": 0.01}),
    "joint_vel_cost_weight": (0.002, {"reward.joint_velocity_cost": 0.002}),
    "distance_reward_weight": (20.0, {"reward.distance": 20.0}),
    "early_termination_penalty": (50.0, {"reward.termination": 50.0}),
    "stagnation_penalty_weight": (0.1, {"reward.stagnation_cost": 0.1}),
    "alive_bonus": (0.1, {"reward.alive": 0.1}),
    "checkpoint_reward": (40.0, {"reward.checkpoint": 40.0}),
    "num_checkpoints": (20, {"goal.num_checkpoints": 20}),
    "checkpoint_radius": (0.5, {"goal.checkpoint_radius": 0.5}),
    "start_radius": (0.7, {"terrain.spiral.start_radius": 0.7}),
    "end_radius": (3.0, {"terrain.spiral.end_radius": 3.0}),
    "num_turns": (3, {"terrain.spiral.turns": 3.0}),
    "max_episode_steps": (8000, {"termination.max_episode_steps": 8000}),
    "ensure_flat_spawn": (False, {"terrain.flat_spawn.enabled": False}),
    "enable_terrain": (True, {"scene": "terrain", "terrain_type": "flat"}),
    "terrain_type": ("spiral", {"goal.mode": "spiral", "scene": "flat", "terrain_type": "flat"}),
    "goal_position": ([2.0, -1.0, 0.1], {"goal.mode": "fixed", "goal.position": (2.0, -1.0)}),
}
UNCHANGED = {"actuator_group": [1], "action_group": [1], "clip_actions": 1.0}  # the meaningful value: no effect
IGNORED = {"clip_actions": 0.5, "default_camera_config": {"distance": 4.0}, "max_geom": 2000, "visual_options": {}}


def _get(config, dotted: str):
    for part in dotted.split("."):
        config = getattr(config, part)
    return config


def test_every_original_argument_is_in_the_table_and_tested():
    assert set(ORIGINAL_ARGS) == set(ORIGINAL_SIGNATURE) | set(BASE_CLASS_VIEWER)
    assert set(MAPPED) | set(UNCHANGED) | set(IGNORED) | set(RENDER_ARGS) == set(ORIGINAL_ARGS)
    docs = (Path(__file__).parents[1] / "docs" / "environment.md").read_text()
    assert all(f"| `{name}` |" in docs for name in ORIGINAL_ARGS)  # the documented table


@pytest.mark.parametrize("name", sorted(MAPPED))
def test_original_argument_sets_its_config_keys(name):
    value, expected = MAPPED[name]
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a mapped argument acts: no warning
        config = build_config("flat", **{name: value})
    for key, want in expected.items():
        assert _get(config, key) == pytest.approx(want) if isinstance(want, float) else _get(config, key) == want


@pytest.mark.parametrize("name", sorted(UNCHANGED))
def test_meaningful_value_is_accepted_silently(name):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert build_config("flat", **{name: UNCHANGED[name]}) == hsa_mjx.PRESETS["flat"]


@pytest.mark.parametrize("name", sorted(IGNORED) + list(RENDER_ARGS))
def test_argument_without_meaning_warns(name):
    value = IGNORED.get(name, {"render_mode": "rgb_array", "camera_name": "track"}.get(name, 1))
    with pytest.warns(OriginalArgumentWarning, match=f"{name}.* ignored"):
        assert build_config("flat", **{name: value}) == hsa_mjx.PRESETS["flat"]


def test_the_issue_example_and_coupled_terrain_arguments():
    config = build_config("flat", frame_skip=20, max_increment=0.1785, enable_terrain=True, terrain_type="craters")
    assert (config.scene, config.terrain_type, config.terrain.types) == ("terrain", "craters", ("craters",))
    with pytest.warns(OriginalArgumentWarning, match="goal_position is ignored"):
        spiral = build_config("flat", enable_terrain=True, terrain_type="spiral", goal_position=[1.5, 0.0, 0.1])
    assert (spiral.scene, spiral.terrain_type, spiral.goal.mode) == ("terrain", "spiral", "spiral")
    plain = build_config("craters", enable_terrain=False)  # a terrain preset without its terrain
    assert (plain.scene, plain.terrain_type) == ("flat", "flat")
    with pytest.warns(OriginalArgumentWarning, match="draws no terrain"):
        assert build_config("flat", enable_terrain=False, terrain_type="poles").scene == "flat"


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"frame_skp": 3}, r"unknown argument\(s\) \['frame_skp'\].*'frame_skip'.*'control__frame_skip'"),
        ({"frame_skip": 5, "control__frame_skip": 4}, "frame_skip and the config key control__frame_skip both set"),
        ({"goal_position": [1, 0], "goal": {"mode": "radial"}}, "goal_position and the config key goal__mode"),
        ({"enable_terrain": True, "scene": "terrain"}, "enable_terrain and the config key scene"),
        ({"frame_skip": 0}, "'control.frame_skip' must be > 0.*original argument frame_skip=0"),
        ({"terrain_type": "craters"}, "needs the heightfield scene: pass enable_terrain=True"),
        ({"terrain_type": "lava", "enable_terrain": True}, "not a terrain type"),
        ({"enable_terrain": "yes"}, "enable_terrain must be True or False"),
        ({"actuator_group": [0, 1]}, r"actuator_group=\[0, 1\] is not supported: only \[1\]"),
        ({"action_group": [2]}, "action_group"),
        ({"xml_file": "hsaModel.xml"}, "could not load it either"),
        ({"xml_file": "robot.xml"}, "hsaLooseModel.xml"),
        ({"goal_position": [1.0]}, r"goal_position must be a list \[x, y\]"),
        ({"goal_position": ["a", "b"]}, "goal_position must be a list"),
    ],
)
def test_bad_original_arguments(kwargs, match):
    with pytest.raises(ValueError, match=match):
        build_config("flat", **kwargs)


def test_original_arguments_through_gymnasium_make_and_make_vec(env):
    single = gymnasium.make(
        "hsa_mjx/HSA-v0",
        frame_skip=10,
        max_increment=0.2,
        yvel_cost_weight=0.5,
        render_mode="rgb_array",
        camera_name="overview",
    )
    config = single.unwrapped.env.config
    assert (config.control.frame_skip, config.control.max_increment, config.reward.lateral_cost) == (10, 0.2, 0.5)
    assert single.unwrapped._camera == "overview" and single.metadata["render_fps"] == 100  # dt = 10 ms
    single.close()
    envs = gymnasium.make_vec(
        "hsa_mjx/HSA-v0", num_envs=2, vectorization_mode="vector_entry_point", num_checkpoints=5, camera_id=-1
    )
    assert envs.unwrapped.env.config.goal.num_checkpoints == 5 and envs.unwrapped._camera == -1
    envs.close()
    with pytest.raises(ValueError, match="pass one camera argument"):
        gymnasium.make("hsa_mjx/HSA-v0", camera="track", camera_name="overview")
    with pytest.raises(ValueError, match=r"unknown camera 'front'; cameras of the robot asset: \['overview', 'track'"):
        check_camera(env.robot.mj_model, "front")
