"""The scaling benchmark (``python -m benchmarks.scaling.devices``): end to end on this machine's one CPU device,
with the tiny training config (its epoch is the shared tiny run's program), and its arithmetic over
device counts. Its multi-device rows come from GPU runs (docs/scaling.md)."""

from __future__ import annotations

import json

import pytest
import yaml
from conftest import TINY_RUN


def test_scaling_benchmark_runs_end_to_end(tmp_path):
    from benchmarks.scaling import devices as scaling

    config = tmp_path / "tiny.yaml"
    config.write_text(yaml.safe_dump(TINY_RUN))
    args = ["--config", str(config), "--envs-per-device", "4", "--devices", "1", "--steps", "2", "--repeats", "1"]
    assert scaling.main([*args, "--epochs", "1", "--no-split", "--tag", "smoke", "--out-dir", str(tmp_path)]) == 0
    rows = json.loads((tmp_path / "scaling_smoke.json").read_text())["rows"]
    assert [(r["devices"], r["num_envs"], r["batch_size"]) for r in rows] == [(1, 4, 4)]
    row = rows[0]
    for key in ("env_steps_per_s", "ppo_env_steps_per_s"):
        assert row[key] > 0, key
    assert row["gpu"] == "cpu" and row["versions"]["jax"]
    assert row["collection"] == "one_device" and row["physics_backend"] == "jax"  # auto on one CPU device
    assert row["speedup_ppo_env_steps_per_s"] == 1.0  # the fewest devices measured are the base
    assert (tmp_path / "scaling_smoke.md").is_file()


def test_scaling_speedups_are_relative_to_the_fewest_devices():
    from benchmarks.scaling.report import with_speedups

    rows = with_speedups(
        [
            {"devices": 1, "ppo_env_steps_per_s": 100.0, "env_steps_per_s": 50.0},
            {"devices": 2, "ppo_env_steps_per_s": 180.0, "env_steps_per_s": None},
            {"devices": 4, "ppo_env_steps_per_s": 300.0, "env_steps_per_s": 150.0},
        ]
    )
    assert [r["speedup_ppo_env_steps_per_s"] for r in rows] == [1.0, 1.8, 3.0]
    assert [r["efficiency_ppo_env_steps_per_s"] for r in rows] == [1.0, 0.9, 0.75]
    assert "speedup_env_steps_per_s" not in rows[1]  # not measured there: no speed-up
    assert rows[2]["speedup_env_steps_per_s"] == 3.0 and rows[2]["efficiency_env_steps_per_s"] == 0.75


def test_scaling_device_counts_and_config():
    from benchmarks.scaling.devices import device_counts, scaled_config
    from train import config as train_config

    assert [device_counts(n) for n in (1, 2, 6, 8)] == [[1], [1, 2], [1, 2, 4, 6], [1, 2, 4, 8]]
    flat = train_config.load("configs/train_flat.yaml")  # 4,096 envs, minibatch 256 x 32, unroll 20
    four = scaled_config(flat, 8192, 4, iterations=1)
    assert (four.run.num_envs, four.run.num_devices, four.ppo.batch_size) == (32768, 4, 2048)
    assert four.run.steps_per_epoch == 2048 * 32 * 20 and four.ppo.num_minibatches == 32
    with pytest.raises(ValueError, match="not a whole number"):
        scaled_config(flat, 100, 2, iterations=1)
    with pytest.raises(ValueError, match="at least one device"):
        device_counts(0)


def test_same_run_names_the_metric_that_differs_and_ignores_the_clock(tmp_path):
    from benchmarks.scaling import same_run

    base = {"step": 10, "loss/v_loss": 2.0, "episode/return": -5.0, "time": 1.0, "training/env_steps_per_s": 100.0}
    runs = {
        "a": [base],
        "b": [{**base, "time": 9.0, "training/env_steps_per_s": 90.0}],
        "c": [{**base, "loss/v_loss": 2.5}],
    }
    for name, records in runs.items():
        (tmp_path / name).mkdir()
        (tmp_path / name / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records))
    assert same_run.main([str(tmp_path / "a"), str(tmp_path / "b"), "--out", str(tmp_path / "ab")]) == 0
    written = json.loads((tmp_path / "ab.json").read_text())
    assert written["same"] and written["steps"][0]["speeds"] == [100.0, 90.0]
    assert written["steps"][0]["metrics"] == {
        "episode/return": [-5.0, -5.0],
        "loss/v_loss": [2.0, 2.0],
        "step": [10, 10],
    }
    assert same_run.main([str(tmp_path / "a"), str(tmp_path / "c")]) == 1
    row = same_run.compare([runs["a"], runs["c"]])[0]
    assert row["largest_gap_metric"] == "loss/v_loss" and row["equal"] == row["compared"] - 1
    assert same_run.main([str(tmp_path / "a"), str(tmp_path / "c"), "--tolerance", "0.2"]) == 0
    # --append keeps the earlier comparison and adds this one after it, in both files
    assert same_run.main([str(tmp_path / "a"), str(tmp_path / "c"), "--out", str(tmp_path / "ab"), "--append"]) == 1
    both = json.loads((tmp_path / "ab.json").read_text())["results"]
    assert [r["same"] for r in both] == [True, False] and both[0] == written
    assert (tmp_path / "ab.md").read_text().count("# Same run?") == 2
    with pytest.raises(FileNotFoundError, match="no metrics log"):
        same_run.read_records(tmp_path / "missing")


def test_network_cost_counts_each_collective_as_often_as_it_runs_and_projects_the_ring():
    import jax
    import jax.numpy as jnp

    from benchmarks.scaling import network_cost

    def fn(x):  # 3 trips of two all-reduces (one round), then one all-gather of 4 float32
        def body(c, _):
            return jax.lax.psum(c, "d") + jax.lax.pmax(c, "d"), None

        c, _ = jax.lax.scan(body, x, None, length=3)
        return jax.lax.all_gather(c, "d")

    traced = jax.make_jaxpr(fn, axis_env=[("d", 2)])(jnp.zeros(4))
    counted = network_cost.count_collectives(traced.jaxpr)
    assert counted["all-reduce"] == {"calls": 6.0, "rounds": 3.0, "bytes": 6 * 16.0}
    assert counted["all-gather"] == {"calls": 1.0, "rounds": 1.0, "bytes": 16.0}
    seconds = network_cost.project(counted, gpus=4, gbps=8e-9, latency_s=1.0)  # 1 byte/s, 1 s a hop
    assert seconds == pytest.approx(2 * 3 / 4 * 96 + 2 * 3 * 3 + 3 * 16 + 3 * 1)


def test_allreduce_times_the_iterations_rounds_and_appends_results(tmp_path):
    """On one CPU device (no process flags): the iteration's rounds as network_cost counts them, each timed."""
    from benchmarks.scaling import allreduce

    config = tmp_path / "tiny.yaml"
    config.write_text(yaml.safe_dump(TINY_RUN))
    out = tmp_path / "allreduce"
    for note in ("first", "second"):
        assert (
            allreduce.main(["--config", str(config), "--repeats", "1", "--out", str(out), "--append", "--note", note])
            == 0
        )
    first, second = json.loads(out.with_suffix(".json").read_text())["results"]
    rounds, per_round = first["iteration"]["rounds"], first["iteration"]["bytes_per_round"]
    assert rounds > 1 and 0 <= first["one_round"]["bytes"] - rounds * per_round < 4 * rounds  # float32 rounds
    assert first["iteration"]["seconds"] > 0 and first["latency_s_per_round"] > 0
    assert (first["note"], second["note"], first["devices"], first["processes"]) == ("first", "second", 1, 1)
    with pytest.raises(ValueError, match="--repeats must be >= 1"):
        allreduce.main(["--config", str(config), "--repeats", "0"])
    with pytest.raises(FileNotFoundError, match="no config"):
        allreduce.main(["--config", str(tmp_path / "missing.yaml")])
