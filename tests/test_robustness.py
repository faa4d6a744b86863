"""benchmarks.robustness: the grid, one model per cell, the written table and heat map."""

from __future__ import annotations

import json

from benchmarks import robustness


def test_the_grid_crosses_every_factor():
    cells = robustness.cells()
    assert len(cells) == 3 * 2 * 2 * 3 * 2 == len({tuple(c.values()) for c in cells})
    assert {c["latency_ms"] for c in cells} == {0, 20, 40} and {c["noise"] for c in cells} == {False, True}


def test_every_cell_runs_its_own_model_and_the_results_are_written(tmp_path):
    assert robustness.main(["flat", "--episodes", "1", "--steps", "25", "--backend", "c",
                            "--out-dir", str(tmp_path), "--tag", "smoke"]) == 0
    result = json.loads((tmp_path / "robustness_smoke.json").read_text())
    rows = result["cells"]
    assert len(rows) == 72 and all(r["episodes"] == 1 for r in rows)
    assert {p.name for p in tmp_path.iterdir()} == {f"robustness_smoke.{ext}" for ext in ("json", "md", "png")}
    # the same episode (start, goal, policy) on each friction, all else alike: three different outcomes
    same = [r for r in rows if (r["block_mass"], r["hsa_stiffness"], r["latency_ms"], r["noise"]) == (0.8, 0.7, 0, False)]
    assert len({round(r["mean_final_distance"], 6) for r in same}) == 3
    lagged = [r for r in rows if (r["friction"], r["block_mass"], r["hsa_stiffness"], r["noise"]) == (1.0, 0.8, 0.7, False)]
    assert len({round(r["mean_final_distance"], 6) for r in lagged}) == 3  # latency 0, 20, 40 ms differ too
    assert "| x0.5 | x0.8 | x0.7 | 0 | off |" in (tmp_path / "robustness_smoke.md").read_text()


def test_the_randomised_training_config_covers_the_grid():
    from train import config as tcfg
    dr, flat = tcfg.to_dict(tcfg.load("configs/train_flat_dr.yaml")), tcfg.to_dict(tcfg.load("configs/train_flat.yaml"))
    ranges = dr["env"].pop("randomization")
    assert dr["env"]["observation"].pop("noise") == robustness.NOISE_ON
    flat["env"].pop("randomization"), flat["env"]["observation"].pop("noise")
    assert dr == flat  # the flat task otherwise
    for name in ("friction", "block_mass", "hsa_stiffness"):
        assert ranges[name] == [min(robustness.GRID[name]), max(robustness.GRID[name])]
    assert ranges["latency_steps"] == [0, max(robustness.GRID["latency_ms"]) // 20]
