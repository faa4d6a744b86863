"""Config loading, presets and the errors bad input gets (no MJX needed)."""

from pathlib import Path

import pytest
import yaml

from hsa_mjx import config as cfg

ROOT = Path(__file__).resolve().parent.parent


def test_defaults_reproduce_original_flat_config():
    """Weights of the original flat_config.yaml (ORIGINAL_FACTS 6.6)."""
    c = cfg.EnvConfig()
    r = c.reward
    assert (r.forward, r.ctrl, r.contact, r.lateral, r.constraint) == (6.0, 0.001, 0.0005, 0.0, 0.05)
    assert (r.acceleration, r.joint_velocity, r.distance, r.alive) == (1e-5, 5e-4, 10.0, 0.03)
    assert r.stagnation == 0.15 and r.termination == 100.0
    assert c.control.frame_skip == 20 and c.control.max_increment == 0.1785
    assert c.control.smooth_positions and c.termination.max_episode_steps == 4000
    assert c.control.servo_target_limit == 3141.5 and c.physics.timestep == 0.001
    assert c.dt == pytest.approx(0.02)


def test_shipped_flat_yaml_equals_preset():
    assert cfg.load_config(ROOT / "configs" / "flat.yaml") == cfg.get_preset("flat")


def test_yaml_under_env_section(tmp_path):
    path = tmp_path / "c.yaml"
    path.write_text(yaml.safe_dump({"env": {"reward": {"forward": 3.0}}, "ppo": {"lr": 1}}))
    assert cfg.load_config(path).reward.forward == 3.0


def test_unknown_key_names_key_and_valid_options(tmp_path):
    path = tmp_path / "c.yaml"
    path.write_text("reward:\n  forwrd: 1.0\n")
    with pytest.raises(ValueError, match=r"forwrd.*valid keys.*'forward'"):
        cfg.load_config(path)


def test_wrong_type_and_bad_choice_and_range():
    with pytest.raises(ValueError, match="control.frame_skip.*integer"):
        cfg.from_dict({"control": {"frame_skip": 2.5}})
    with pytest.raises(ValueError, match="reward.forward.*number"):
        cfg.from_dict({"reward": {"forward": "fast"}})
    with pytest.raises(ValueError, match=r"physics.integrator.*\['euler', 'implicitfast', 'rk4'\]"):
        cfg.from_dict({"physics": {"integrator": "verlet"}})
    with pytest.raises(ValueError, match="terrain_type.*'flat'"):
        cfg.from_dict({"terrain_type": "lava"})
    with pytest.raises(ValueError, match="frame_skip.*> 0"):
        cfg.from_dict({"control": {"frame_skip": 0}})
    with pytest.raises(ValueError, match="radial_range"):
        cfg.from_dict({"goal": {"radial_range": [3.0, 1.0]}})
    with pytest.raises(ValueError, match=r"radial_bearing_deg.*<= 180"):
        cfg.from_dict({"goal": {"radial_bearing_deg": [60.0, 200.0]}})


def test_missing_file_and_unknown_preset(tmp_path):
    with pytest.raises(FileNotFoundError, match="nope.yaml"):
        cfg.load_config(tmp_path / "nope.yaml")
    with pytest.raises(ValueError, match="available presets.*flat"):
        cfg.get_preset("mountain")


def test_overrides_with_dotted_keys():
    c = cfg.with_overrides(cfg.get_preset("flat"), reward__forward=2.0, **{"goal.mode": "fixed"})
    assert c.reward.forward == 2.0 and c.goal.mode == "fixed"
    with pytest.raises(ValueError, match="unknown config key"):
        cfg.with_overrides(c, reward__nope=1.0)


def test_round_trip_to_dict():
    c = cfg.get_preset("flat_radial")
    assert cfg.from_dict(cfg.to_dict(c)) == c


def test_observation_section_is_opt_in_and_checked():
    assert cfg.EnvConfig().observation.heading is False  # the original's 24 values by default
    assert all(not preset.observation.heading for preset in cfg.PRESETS.values())
    on = cfg.from_dict({"observation": {"heading": True}})
    assert on.observation.heading and cfg.from_dict(cfg.to_dict(on)) == on
    section = cfg.to_dict(on)["observation"]
    assert section == {
        "heading": True,
        "servo_targets": False,
        "clock_period_s": 0.0,
        "hinge_angles": "raw",
        "height_scan": section["height_scan"],
        "noise": section["noise"],
    }
    assert section["height_scan"]["enabled"] is False and not any(section["noise"].values())  # off by default
    assert cfg.with_overrides(cfg.get_preset("flat"), observation__heading=True) == on
    with pytest.raises(ValueError, match=r"\['headng'\].*section 'observation'.*valid keys.*'heading'"):
        cfg.from_dict({"observation": {"headng": True}})
    with pytest.raises(ValueError, match="observation.heading.*true or false"):
        cfg.from_dict({"observation": {"heading": "yes"}})
    assert all(not p.observation.servo_targets and p.observation.clock_period_s == 0 for p in cfg.PRESETS.values())
    with pytest.raises(ValueError, match="observation.servo_targets.*true or false"):
        cfg.from_dict({"observation": {"servo_targets": 1}})
    with pytest.raises(ValueError, match=r"observation.clock_period_s.*>= 0.*-4.0"):
        cfg.from_dict({"observation": {"clock_period_s": -4}})
    assert all(p.observation.hinge_angles == "raw" for p in cfg.PRESETS.values())  # the original's angles
    with pytest.raises(ValueError, match=r"observation.hinge_angles.*'wrap'.*\['raw', 'wrapped', 'sincos'\]"):
        cfg.from_dict({"observation": {"hinge_angles": "wrap"}})


@pytest.mark.parametrize("key", ["reward.forward", "termination.z_max", "goal.radial_range"])
def test_non_finite_numbers_are_refused_naming_the_key(key):
    value = [1.5, float("inf")] if key == "goal.radial_range" else float("nan")
    with pytest.raises(ValueError, match=f"finite.*{key}"):
        cfg.with_overrides(cfg.get_preset("flat"), **{key: value})


# ----- YAML files: base configs ----------------------------------------------------------------
def _leaves(data: dict, prefix: str = "") -> dict:
    """Every non-mapping value of nested dicts by its dotted key."""
    out = {}
    for key, value in data.items():
        out.update(_leaves(value, f"{prefix}{key}.") if isinstance(value, dict) else {f"{prefix}{key}": value})
    return out


def test_no_training_yaml_restates_its_base():
    import yaml

    from hsa_mjx import resources

    derived = 0
    for path in sorted(resources.data_dir("configs").glob("train_*.yaml")):
        raw = yaml.safe_load(path.read_text())
        if "base" not in raw:
            continue
        derived += 1
        base = _leaves(resources.read_yaml(path.parent / raw.pop("base")))
        restated = {k: v for k, v in _leaves(raw).items() if k in base and base[k] == v}
        assert not restated, f"{path.name} restates its base's values: {restated}"
    assert derived >= 4  # corridor, spiral, rough and the CPU quickstart derive from the flat task


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
