"""Config loading, presets and the errors bad input gets (no MJX needed)."""

from pathlib import Path

import pytest
import yaml

import hsa_mjx.config

ROOT = Path(__file__).resolve().parent.parent


def test_defaults_reproduce_original_flat_config():
    """Weights of the original flat_config.yaml (ORIGINAL_FACTS 6.6)."""
    c = hsa_mjx.config.EnvConfig()
    r = c.reward
    costs = (r.ctrl_cost, r.contact_cost, r.lateral_cost, r.constraint_cost)
    assert (r.forward, *costs) == (6.0, 0.001, 0.0005, 0.0, 0.05)
    assert (r.acceleration_cost, r.joint_velocity_cost, r.distance, r.alive) == (1e-5, 5e-4, 10.0, 0.03)
    assert r.stagnation_cost == 0.15 and r.termination == 100.0
    assert c.control.frame_skip == 20 and c.control.max_increment == 0.1785
    assert c.control.smooth_positions and c.termination.max_episode_steps == 4000
    assert c.control.servo_target_limit == 3141.5 and c.physics.timestep == 0.001
    assert c.dt == pytest.approx(0.02)


def test_shipped_flat_yaml_equals_preset():
    assert hsa_mjx.config.load_config(ROOT / "configs" / "flat.yaml") == hsa_mjx.config.get_preset("flat")


def test_yaml_under_env_section(tmp_path):
    path = tmp_path / "c.yaml"
    path.write_text(yaml.safe_dump({"env": {"reward": {"forward": 3.0}}, "ppo": {"lr": 1}}))
    assert hsa_mjx.config.load_config(path).reward.forward == 3.0


def test_unknown_key_names_key_and_valid_options(tmp_path):
    path = tmp_path / "c.yaml"
    path.write_text("reward:\n  forwrd: 1.0\n")
    with pytest.raises(ValueError, match=r"forwrd.*valid keys.*'forward'"):
        hsa_mjx.config.load_config(path)


def test_wrong_type_and_bad_choice_and_range():
    with pytest.raises(ValueError, match="control.frame_skip.*integer"):
        hsa_mjx.config.from_dict({"control": {"frame_skip": 2.5}})
    with pytest.raises(ValueError, match="reward.forward.*number"):
        hsa_mjx.config.from_dict({"reward": {"forward": "fast"}})
    with pytest.raises(ValueError, match=r"physics.integrator.*\['euler', 'implicitfast', 'rk4'\]"):
        hsa_mjx.config.from_dict({"physics": {"integrator": "verlet"}})
    with pytest.raises(ValueError, match="terrain_type.*'flat'"):
        hsa_mjx.config.from_dict({"terrain_type": "lava"})
    with pytest.raises(ValueError, match="frame_skip.*> 0"):
        hsa_mjx.config.from_dict({"control": {"frame_skip": 0}})
    with pytest.raises(ValueError, match="radial_range"):
        hsa_mjx.config.from_dict({"goal": {"radial_range": [3.0, 1.0]}})
    with pytest.raises(ValueError, match=r"radial_bearing_deg.*<= 180"):
        hsa_mjx.config.from_dict({"goal": {"radial_bearing_deg": [60.0, 200.0]}})


def test_missing_file_and_unknown_preset(tmp_path):
    with pytest.raises(FileNotFoundError, match="nope.yaml"):
        hsa_mjx.config.load_config(tmp_path / "nope.yaml")
    with pytest.raises(ValueError, match="available presets.*flat"):
        hsa_mjx.config.get_preset("mountain")


def test_overrides_with_dotted_keys():
    c = hsa_mjx.config.with_overrides(hsa_mjx.config.get_preset("flat"), reward__forward=2.0, **{"goal.mode": "fixed"})
    assert c.reward.forward == 2.0 and c.goal.mode == "fixed"
    with pytest.raises(ValueError, match="unknown config key"):
        hsa_mjx.config.with_overrides(c, reward__nope=1.0)


def test_round_trip_to_dict():
    c = hsa_mjx.config.get_preset("flat_radial")
    assert hsa_mjx.config.from_dict(hsa_mjx.config.to_dict(c)) == c


def test_observation_section_is_opt_in_and_checked():
    assert hsa_mjx.config.EnvConfig().observation.heading is False  # the original's 24 values by default
    assert all(not preset.observation.heading for preset in hsa_mjx.config.PRESETS.values())
    on = hsa_mjx.config.from_dict({"observation": {"heading": True}})
    assert on.observation.heading and hsa_mjx.config.from_dict(hsa_mjx.config.to_dict(on)) == on
    section = hsa_mjx.config.to_dict(on)["observation"]
    assert section == {
        "heading": True,
        "servo_targets": False,
        "clock_period_s": 0.0,
        "path_direction": False,
        "hinge_angles": "raw",
        "history_steps": 0,
        "velocity": "simulated",
        "height_scan": section["height_scan"],
        "noise": section["noise"],
    }
    assert section["height_scan"]["enabled"] is False and not any(section["noise"].values())  # off by default
    assert hsa_mjx.config.with_overrides(hsa_mjx.config.get_preset("flat"), observation__heading=True) == on
    with pytest.raises(ValueError, match=r"\['headng'\].*section 'observation'.*valid keys.*'heading'"):
        hsa_mjx.config.from_dict({"observation": {"headng": True}})
    with pytest.raises(ValueError, match="observation.heading.*true or false"):
        hsa_mjx.config.from_dict({"observation": {"heading": "yes"}})
    assert all(
        not p.observation.servo_targets and p.observation.clock_period_s == 0 for p in hsa_mjx.config.PRESETS.values()
    )
    with pytest.raises(ValueError, match="observation.servo_targets.*true or false"):
        hsa_mjx.config.from_dict({"observation": {"servo_targets": 1}})
    with pytest.raises(ValueError, match=r"observation.clock_period_s.*>= 0.*-4.0"):
        hsa_mjx.config.from_dict({"observation": {"clock_period_s": -4}})
    for steps in (-1, 17):
        with pytest.raises(ValueError, match=r"observation.history_steps' must be an integer in 0..16"):
            hsa_mjx.config.from_dict({"observation": {"history_steps": steps}})
    assert all(p.observation.hinge_angles == "raw" for p in hsa_mjx.config.PRESETS.values())  # the original's angles
    with pytest.raises(ValueError, match=r"observation.hinge_angles.*'wrap'.*\['raw', 'wrapped', 'sincos'\]"):
        hsa_mjx.config.from_dict({"observation": {"hinge_angles": "wrap"}})


@pytest.mark.parametrize("key", ["reward.forward", "termination.z_max", "goal.radial_range"])
def test_non_finite_numbers_are_refused_naming_the_key(key):
    value = [1.5, float("inf")] if key == "goal.radial_range" else float("nan")
    with pytest.raises(ValueError, match=f"finite.*{key}"):
        hsa_mjx.config.with_overrides(hsa_mjx.config.get_preset("flat"), **{key: value})


# ----- YAML files: base configs ----------------------------------------------------------------
def _leaves(data: dict, prefix: str = "") -> dict:
    """Every non-mapping value of nested dicts by its dotted key."""
    out = {}
    for key, value in data.items():
        out.update(_leaves(value, f"{prefix}{key}.") if isinstance(value, dict) else {f"{prefix}{key}": value})
    return out


def _without(data: dict, dotted: str) -> dict:
    """A copy of nested dicts with one dotted key removed (and its section, when it empties)."""
    head, _, rest = dotted.partition(".")
    out = dict(data)
    if not rest:
        del out[head]
    else:
        out[head] = _without(data[head], rest)
        if not out[head]:
            del out[head]
    return out


SHIPPED = sorted(p.name for p in (Path(__file__).resolve().parents[1] / "configs").glob("*.yaml"))


@pytest.mark.parametrize("name", SHIPPED)
def test_each_shipped_config_states_only_what_differs(name, tmp_path):
    """Each fact once: drop any one key of a shipped config and the config it builds changes (a key equal
    to the dataclass default, the preset's value or the base file's would change nothing)."""
    import yaml

    from hsa_mjx import resources
    from train import config as train_config

    path = resources.data_dir("configs") / name
    raw = yaml.safe_load(path.read_text()) or {}
    if name.startswith("train_"):
        build = lambda p: train_config.to_dict(train_config.load(p))  # noqa: E731
    else:
        build = lambda p: hsa_mjx.config.to_dict(hsa_mjx.config.load_config(p))  # noqa: E731
    if "base" in raw:
        raw["base"] = str(path.parent / raw["base"])  # the copies below live elsewhere
    full, copy, restated = build(path), tmp_path / name, []
    for key in _leaves(raw):
        if key in ("base", "env.preset"):
            continue
        copy.write_text(yaml.safe_dump(_without(raw, key)))
        try:
            if build(copy) == full:
                restated.append(key)
        except ValueError:  # without it the config is invalid: needed
            continue
    assert restated == [], f"{name} states what it would be anyway: {restated}"
    assert name == "flat.yaml" or _leaves(raw)  # the flat task is the defaults: its file states nothing


def test_base_configs_merge_and_refuse_a_cycle(tmp_path):
    from hsa_mjx import resources

    (tmp_path / "a.yaml").write_text("base: b.yaml\nppo: {learning_rate: 1.0e-4}\n")
    (tmp_path / "b.yaml").write_text("ppo: {learning_rate: 3.0e-4, unroll_length: 20}\nrun: {num_envs: 8}\n")
    assert resources.read_yaml(tmp_path / "a.yaml") == {
        "ppo": {"learning_rate": 1.0e-4, "unroll_length": 20},
        "run": {"num_envs": 8},
    }
    (tmp_path / "b.yaml").write_text("base: a.yaml\n")
    with pytest.raises(ValueError, match="comes back to itself"):
        resources.read_yaml(tmp_path / "a.yaml")
    (tmp_path / "c.yaml").write_text("base: missing.yaml\n")
    with pytest.raises(FileNotFoundError, match="missing.yaml"):
        resources.read_yaml(tmp_path / "c.yaml")
