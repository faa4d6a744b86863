"""benchmarks.robustness: the grid, one model per cell, the written table and heat map."""

from __future__ import annotations

import json

import pytest

from benchmarks import robustness


def test_the_grid_crosses_every_factor():
    cells = robustness.cells()
    assert len(cells) == 3 * 2 * 2 * 3 * 2 == len({tuple(c.values()) for c in cells})
    assert {c["latency_ms"] for c in cells} == {0, 20, 40} and {c["noise"] for c in cells} == {False, True}


def test_every_cell_runs_its_own_model_and_the_results_are_written(tmp_path):
    assert (
        robustness.main(
            ["flat", "--episodes", "1", "--steps", "25", "--backend", "c", "--out-dir", str(tmp_path), "--tag", "smoke"]
        )
        == 0
    )
    result = json.loads((tmp_path / "robustness_smoke.json").read_text())
    rows = result["cells"]
    assert len(rows) == 72 and all(r["episodes"] == 1 for r in rows)
    assert {p.name for p in tmp_path.iterdir()} == {f"robustness_smoke.{ext}" for ext in ("json", "md", "png")}
    # the same episode (start, goal, policy) on each friction, all else alike: three different outcomes
    same = [
        r for r in rows if (r["block_mass"], r["hsa_stiffness"], r["latency_ms"], r["noise"]) == (0.8, 0.7, 0, False)
    ]
    assert len({round(r["mean_final_distance"], 6) for r in same}) == 3
    lagged = [
        r for r in rows if (r["friction"], r["block_mass"], r["hsa_stiffness"], r["noise"]) == (1.0, 0.8, 0.7, False)
    ]
    assert len({round(r["mean_final_distance"], 6) for r in lagged}) == 3  # latency 0, 20, 40 ms differ too
    assert "| x0.5 | x0.8 | x0.7 | 0 | off |" in (tmp_path / "robustness_smoke.md").read_text()
    # every episode reached its goal or ended one way: the failure shares and the success rate add up to 1
    assert all(abs(r["success_rate"] + sum(r["failures"].values()) - 1) < 1e-6 for r in rows)
    assert any(r["failures"].get("not_finished") for r in rows)  # 25 steps end most episodes short


def test_where_keeps_the_matching_cells_and_refuses_unknown_factors_and_values():
    chosen = robustness.select(["hsa_stiffness=1.3", "block_mass=0.8", "noise=off"])
    assert len(chosen) == 9 and all(
        (c["hsa_stiffness"], c["block_mass"], c["noise"]) == (1.3, 0.8, False) for c in chosen
    )
    assert robustness.select(["latency_ms=20.0"]) == [c for c in robustness.cells() if c["latency_ms"] == 20]
    with pytest.raises(ValueError, match="factors: friction"):
        robustness.select(["mass=0.8"])
    with pytest.raises(ValueError, match="0.5, 1, 1.5"):
        robustness.select(["friction=2"])
    assert robustness.main(["flat", "--where", "noise=maybe"]) == 2


def test_the_randomised_training_config_covers_the_grid():
    import hsa_mjx_train.config

    dr, flat = (
        hsa_mjx_train.config.to_dict(hsa_mjx_train.config.load("configs/train_flat_dr.yaml")),
        hsa_mjx_train.config.to_dict(hsa_mjx_train.config.load("configs/train_flat.yaml")),
    )
    ranges = dr["env"].pop("randomization")
    assert dr["env"]["observation"].pop("noise") == robustness.NOISE_ON
    flat["env"].pop("randomization"), flat["env"]["observation"].pop("noise")
    # the flat task at its final goal range, continued from the shipped flat policy
    assert dr["env"]["goal"].pop("radial_range") == flat["goal_curriculum"]["target_range"]
    flat["env"]["goal"].pop("radial_range")
    assert dr["env"] == flat["env"] and dr["run"]["init_from"] == "flat" and not dr["goal_curriculum"]["enabled"]
    for name in ("friction", "block_mass", "hsa_stiffness"):
        assert ranges[name] == [min(robustness.GRID[name]), max(robustness.GRID[name])]
    assert ranges["latency_steps"] == [0, max(robustness.GRID["latency_ms"]) // 20]


def test_a_randomised_policy_is_scored_on_the_cells_model_alone():
    import dataclasses

    import hsa_mjx_train.config
    from hsa_mjx.deploy import policy_file
    from hsa_mjx.randomization_config import RandomizationConfig
    from hsa_mjx_train import policy_sources

    trained = policy_file.load_policy(policy_file.locate("flat_dr")).meta["config"]
    assert trained["env"]["randomization"]["push_speed"] > 0  # it trained with pushes and noise
    overridden = {
        o.split("=")[0].rsplit(".", 1)[1] for o in robustness.env_overrides(False, 2) if ".randomization." in o
    }
    assert overridden == {f.name for f in dataclasses.fields(RandomizationConfig)}  # no training range leaks in
    for noise in (False, True):
        env = hsa_mjx_train.config.from_dict(
            policy_sources.env_overrides(trained, robustness.env_overrides(noise, 2))
        ).env
        assert env.randomization.push_speed == 0 and env.randomization.hsa_damping == env.randomization.servo_gain == (
            1,
            1,
        )
        assert env.randomization.hsa_stiffness == (0.7, 1.3) and env.randomization.latency_steps == (0, 2)
        assert dataclasses.asdict(env.observation.noise) == {
            k: (v if noise else 0) for k, v in robustness.NOISE_ON.items()
        }
