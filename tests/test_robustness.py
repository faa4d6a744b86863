"""benchmarks.robustness.score: the grids, one model per cell, the intervals, sim-to-sim, the written results."""

from __future__ import annotations

import dataclasses
import json
import shlex
from pathlib import Path

import jax
import jax.numpy as jnp
import pytest

from benchmarks import stats
from benchmarks.robustness import compare as robustness_compare
from benchmarks.robustness import grids as robustness_grids
from benchmarks.robustness import merge as robustness_merge
from benchmarks.robustness import score as robustness
from benchmarks.robustness import sim_to_sim
from hsa_mjx.deploy import policy_file
from hsa_mjx.robots import profile_servo


def test_wilson_interval_matches_known_values_and_stays_in_range():
    # reference values (Wilson 1927; e.g. statsmodels' proportion_confint(method="wilson"))
    assert stats.wilson_interval(8, 8) == pytest.approx((0.6756, 1.0), abs=1e-4)
    assert stats.wilson_interval(32, 32)[0] == pytest.approx(0.8928, abs=1e-4)
    assert stats.wilson_interval(5, 8) == pytest.approx((0.3057, 0.8632), abs=1e-4)
    assert stats.wilson_interval(0, 10) == pytest.approx((0.0, 0.2775), abs=1e-4)
    low, high = stats.wilson_interval(50, 100)
    assert low == pytest.approx(1 - high) and low < 0.5 < high  # symmetric about one half
    for bad in ((3, 2), (-1, 4), (0, 0)):
        with pytest.raises(ValueError, match="successes <= trials"):
            stats.wilson_interval(*bad)


def test_paired_interval_narrows_where_the_pairs_agree_and_is_newcombes_where_they_are_independent():
    # independent pairs (both * neither == first_only * second_only): the unpaired interval of the margins
    d, low, high = stats.paired_difference_interval(12, 18, 8, 12)
    assert (d, low, high) == pytest.approx(stats.difference_interval((30, 20), (50, 50)))
    # the same margins (30 and 20 of 50) from pairs that mostly agree: the same difference, a narrower interval
    paired = stats.paired_difference_interval(20, 10, 0, 20)
    assert paired[0] == pytest.approx(d) and low < paired[1] < d < paired[2] < high
    # no discordant pair: a gap of zero, within 1.5 points (unpaired: -19 to +19 points)
    assert stats.paired_difference_interval(30, 0, 0, 20) == pytest.approx((0.0, -0.0143, 0.0143), abs=1e-4)
    # the ends stay inside [-1, 1]; bad counts are refused
    assert stats.paired_difference_interval(0, 40, 0, 0)[1:] == pytest.approx((0.8761, 1.0), abs=1e-4)
    with pytest.raises(ValueError, match="at least one pair"):
        stats.paired_difference_interval(0, 0, 0, 0)


def test_the_grids_cells():
    nominal, stress = robustness_grids.grid("nominal"), robustness_grids.grid("stress")
    assert len(nominal) == 3 * 2 * 2 * 3 * 2 == len({tuple(c.values()) for c in nominal})
    assert {c["latency_ms"] for c in nominal} == {0, 20, 40} and not any(c["pushes"] for c in nominal)
    assert len(stress) == 24 == len({tuple(c.values()) for c in stress}) and stress[0] == robustness_grids.TRAINING
    feet = [c for c in stress if c["foot_friction"] != (1,) * 4 or c["foot_anisotropy"] != (1,) * 4]
    assert [robustness_grids.label(c) for c in feet] == ["foot_friction x0.3/1/1/1", "foot_anisotropy x2.1/2.1/2.1/2.1"]
    # the hardware profiles' servos: one compiled env for the three (either servo model, drawn per env),
    # each cell's profile drawn into its episodes, the first profile's servo the env's own
    groups = robustness_grids.rollout_groups(stress)
    servos = [[c["servo"] for c in g] for g in groups if g[0]["servo"]]
    assert servos == [list(robustness_grids.STRESS_SERVOS)] and sum(map(len, groups)) == len(stress)
    servo_group = next(g for g in groups if g[0]["servo"])
    overrides = robustness.env_overrides(servo_group, 0.02, qacc_rule=False)
    assert 'env.servo.model="continuous"' in overrides and "env.servo.stall_torque=0.4707" in overrides
    assert 'env.randomization.robots=["dfr05sr", "xl330_m288", "st3215"]' in overrides
    drawn = robustness.cell_randomization(servo_group, 2, 0.02)["physics"].robot
    assert drawn.tolist() == [0, 0, 1, 1, 2, 2]
    for name, ends in robustness_grids.STRESS_ENDS.items():  # each end alone, every other factor as trained
        for value in ends:
            assert robustness_grids.cell(**{name: value}) in stress
    assert min(c["friction"] for c in stress) == 0.3 and max(c["latency_ms"] for c in stress) == 60
    assert {robustness_grids.label(c) for c in stress} >= {"training model", "friction x0.3", "60 ms", "pushes"}
    with pytest.raises(ValueError, match="grids: nominal, stress"):
        robustness_grids.grid("hard")


def test_a_dc_motor_policy_meets_the_gain_and_torque_cells_as_its_motors_figures():
    """The spring's gain and torque-limit cells, for a policy whose own servos are DC motors (st3215's):
    stall torque and no-load speed scaled, the stall capped; on MJX as per-env servo figures, on C MuJoCo
    as the motor's config, the loop gains held at the nominal motor's."""
    from hsa_mjx.servo_config import resolve_servo
    from train import config as train_config

    own = profile_servo("st3215")
    cells = [
        robustness_grids.cell(servo_gain=0.6),
        robustness_grids.cell(servo_torque_limit=0.5),
        robustness_grids.cell(servo_gain=0.6, servo_torque_limit=0.5, latency_ms=60),
    ]
    played, figures = zip(*(robustness_grids.dc_motor_cell(c, own.stall_torque) for c in cells))
    assert figures[0] == (0.6, 0.6, 1.0, 1.0, 1.0) and figures[1] == pytest.approx((0.5 / 1.9123, 1, 1, 1, 1))
    assert figures[2] == pytest.approx((0.5 / 1.9123, 0.6, 1, 1, 1)) and played[2]["latency_ms"] == 60
    assert all(c["servo_gain"] == 1.0 and c["servo_torque_limit"] is None for c in played)
    overrides = robustness.env_overrides(list(played), 0.02, False, list(figures))
    config = train_config.load(Path(__file__).parents[1] / "configs" / "train_flat_st3215.yaml", list(overrides))
    assert config.env.randomization.servo_figures == pytest.approx((0.5 / 1.9123, 1.0))  # the DC env accepts them
    rows = robustness.cell_randomization(list(played), 2, 0.02, list(figures))["physics"].servo_figures
    assert rows.shape == (6, 5) and float(rows[2, 0]) == pytest.approx(0.5 / 1.9123)
    scaled, nominal = resolve_servo(sim_to_sim.scaled_motor(own, *figures[2][:2])), resolve_servo(own)
    assert scaled.stall_torque == pytest.approx(0.5) and scaled.no_load_speed == pytest.approx(
        0.6 * nominal.no_load_speed
    )
    assert (scaled.kp, scaled.speed_gain) == (nominal.kp, nominal.speed_gain)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"friction": 0.05}, r"friction must be in \[0.1, 3\]"),
        ({"block_mass": 2.5}, r"block_mass must be in \[0.5, 2\]"),
        ({"hsa_stiffness": 0.0}, r"hsa_stiffness must be in \[0.25, 2\]"),
        ({"servo_gain": -1.0}, r"servo_gain must be in"),
        ({"servo_torque_limit": 0.0}, r"servo_torque_limit must be in \[0.05, 5\]"),
        ({"latency_ms": 500}, r"latency_ms must be in \[0, 200\]"),
        ({"pushes": "yes"}, "pushes must be true or false"),
        ({"foot_friction": (0.3, 1.0)}, "foot_friction takes 4 values"),
        ({"servo": "sg90000"}, "servo must be None or a robot profile with DC-motor servos"),
        ({"servo": "original"}, "servo must be None or a robot profile with DC-motor servos"),
        ({"servo": "xl330_m288", "servo_torque_limit": 0.5}, "act on the asset's springs"),
        ({"foot_anisotropy": (1.0, 1.0, 1.0, 5.0)}, r"foot_anisotropy must be in \[0.1, 3\]"),
        ({"gravity": 2.0}, "unknown factors"),
    ],
)
def test_invalid_stress_values_are_refused(change, message):
    with pytest.raises(ValueError, match=message):
        robustness_grids.cell(**change)


def test_where_keeps_the_matching_cells_and_refuses_unknown_factors_and_values():
    nominal = robustness_grids.grid("nominal")
    chosen = robustness_grids.select(nominal, ["hsa_stiffness=1.3", "block_mass=0.8", "noise=off"])
    assert len(chosen) == 9
    assert all((c["hsa_stiffness"], c["block_mass"], c["noise"]) == (1.3, 0.8, False) for c in chosen)
    assert robustness_grids.select(nominal, ["latency_ms=20.0"]) == [c for c in nominal if c["latency_ms"] == 20]
    stress = robustness_grids.grid("stress")
    assert len(robustness_grids.select(stress, ["servo_torque_limit=none", "pushes=off"])) == 19
    assert [c["servo"] for c in robustness_grids.select(stress, ["servo=st3215"])] == ["st3215"]
    # a factor given twice: either value; with the others pinned, the training model and the torque cell
    pinned = [f"{name}=1" for name in ("friction", "block_mass", "hsa_stiffness", "hsa_damping", "servo_gain")]
    pinned += ["latency_ms=0", "pushes=off", "noise=off", "servo=none"]
    pinned += ["foot_friction=1/1/1/1", "foot_anisotropy=1/1/1/1"]
    both = robustness_grids.select(stress, [*pinned, "servo_torque_limit=none", "servo_torque_limit=0.5"])
    assert [robustness_grids.label(c) for c in both] == ["training model", "torque <= 0.5 N m"]
    slick = robustness_grids.cell(foot_friction=(0.3, 1, 1, 1))
    assert robustness_grids.select(stress, ["foot_friction=0.3/1/1/1"]) == [slick]
    with pytest.raises(ValueError, match="four numbers"):
        robustness_grids.select(stress, ["foot_friction=slick"])
    with pytest.raises(ValueError, match="factors: friction"):
        robustness_grids.select(nominal, ["mass=0.8"])
    with pytest.raises(ValueError, match="values here: 0.5, 1.0, 1.5"):
        robustness_grids.select(nominal, ["friction=2"])
    assert robustness.main(["flat", "--where", "noise=maybe"]) == 2
    assert robustness.main(["flat", "--grid", "hard"]) == 2


def test_every_documented_robustness_command_parses_and_selects_cells():
    """The commands the docs give (``python -m benchmarks.robustness.score ...``) name a grid and ``--where`` cells
    that exist: a broken example is caught here, not by a reader."""
    docs = Path(__file__).resolve().parents[1] / "docs"
    commands = [
        line.split("python -m benchmarks.robustness.score", 1)[1].split("#")[0].split("`")[0]
        for page in sorted(docs.glob("*.md"))
        for line in page.read_text().splitlines()
        if "python -m benchmarks.robustness.score " in line
    ]
    assert len(commands) >= 3
    for command in commands:
        args = robustness.parse_args(shlex.split(command))
        assert robustness_grids.select(robustness_grids.grid(args.grid), args.where), command


def test_every_stress_cell_runs_its_own_model_and_sim_to_sim_replays_it(tmp_path):
    args = ["flat", "--grid", "stress", "--episodes", "1", "--steps", "30", "--backend", "c", "--sim-to-sim"]
    assert robustness.main([*args, "--workers", "1", "--out-dir", str(tmp_path), "--tag", "smoke"]) == 0
    result = json.loads((tmp_path / "robustness_smoke.json").read_text())
    rows = result["cells"]
    assert result["grid"] == "stress" and result["physics_backend"] == "c" and result["qacc_rule"] == "off"
    assert result["seed"] == 1  # the episodes' starts and goals, as given (the default)
    assert not Path(result["policy"]).is_absolute() and Path(result["policy"]).name == "flat"
    assert len(rows) == 24 and all(r["episodes"] == 1 and len(r["ci95"]) == 2 for r in rows)
    assert [r["label"] for r in rows] == [robustness_grids.label(c) for c in robustness_grids.grid("stress")]
    assert {p.name for p in tmp_path.iterdir()} == {f"robustness_smoke.{ext}" for ext in ("json", "md", "png")}
    # the same episode (start, goal, policy) on every model: each factor alone moves the robot elsewhere
    trained = rows[0]["mean_final_distance"]
    alone = [*rows[1:11], *rows[15:20]]  # the five scales at both ends, the feet's two cells, the profiles' servos
    assert all(round(r["mean_final_distance"], 6) != round(trained, 6) for r in alone), [r["label"] for r in alone]
    # every episode reached its goal or ended one way: the failure shares and the success rate add up to 1
    assert all(abs(r["success_rate"] + sum(r["failures"].values()) - 1) < 1e-6 for r in rows)
    assert "1 episodes a cell" in result["note"]  # too few episodes: the minimum is noise
    sim = result["sim_to_sim"]
    assert len(sim) == sum(not r["pushes"] for r in rows) and all(r["physics"] == "c_mujoco" for r in sim)
    assert all(r["gap"] == r["success_rate"] - r["mjx_success_rate"] for r in sim)
    for r in sim:  # the paired table of the cell's episode and the gap's interval around the gap
        assert sum(r["pairs"].values()) == 1 and r["gap_ci95"][0] <= r["gap"] <= r["gap_ci95"][1]
        assert r["gap"] == (r["pairs"]["c_only"] - r["pairs"]["mjx_only"])
    assert "## Sim-to-sim" in (tmp_path / "robustness_smoke.md").read_text()
    check_parts_join_into_the_whole(result, tmp_path)


def check_parts_join_into_the_whole(result: dict, tmp_path) -> None:
    """Parts (``--part K/N``) cover the grid once; ``benchmarks.robustness.merge`` joins them into the whole."""
    cells = robustness_grids.grid("stress")
    shares = [robustness_grids.part(cells, f"{k}/3") for k in (1, 2, 3)]
    assert sorted(len(s) for s in shares) == [8, 8, 8] and sum(shares, []) != cells
    assert sorted(map(robustness_grids.label, sum(shares, []))) == sorted(map(robustness_grids.label, cells))
    for spec in ("0/2", "3/2", "a/b", "2"):
        with pytest.raises(ValueError, match="--part"):
            robustness_grids.part(cells, spec)
    labels = [[robustness_grids.label(c) for c in share] for share in shares]
    for k, share in enumerate(labels):  # the parts as three runs would have written them
        part = {**result, "part": f"{k + 1}/3", "cells": [r for r in result["cells"] if r["label"] in share]}
        part["sim_to_sim"] = [r for r in result["sim_to_sim"] if r["label"] in share]
        (tmp_path / f"part{k}.json").write_text(json.dumps(part))
    files = [str(tmp_path / f"part{k}.json") for k in (2, 0, 1)]
    assert robustness_merge.main([*files, "--tag", "joined"]) == 0
    joined = json.loads((tmp_path / "robustness_joined.json").read_text())
    assert joined["cells"] == result["cells"] and joined["sim_to_sim"] == result["sim_to_sim"]
    assert all(joined[k] == result[k] for k in ("mean_success_rate", "min_success_cell", "cell_count", "note"))
    assert [p["part"] for p in joined["parts"]] == ["3/3", "1/3", "2/3"]
    assert robustness_merge.main([files[0], files[0], "--tag", "twice"]) == 2  # a cell played twice
    check_a_part_played_again_replaces_its_cells(joined, files, tmp_path)
    other = {**json.loads(Path(files[1]).read_text()), "seed": 2}
    (tmp_path / "other.json").write_text(json.dumps(other))
    with pytest.raises(ValueError, match="differs from part 1 in seed"):
        robustness_merge.merge([json.loads(Path(files[0]).read_text()), other])
    assert robustness_merge.main([str(tmp_path / "missing.json"), "--tag", "x"]) == 2


def check_a_part_played_again_replaces_its_cells(joined: dict, files: list[str], tmp_path) -> None:
    """A joined result splits back into its parts; with ``--replace`` a part played again (here the
    first part's cells with other counts and without sim-to-sim rows) replaces those cells alone."""
    again = json.loads(Path(files[1]).read_text())  # part 1/3
    again.update(command="played again", sim_to_sim=[])
    again["cells"] = [{**r, "successes": 0, "success_rate": 0.0} for r in again["cells"]]
    (tmp_path / "again.json").write_text(json.dumps(again))
    whole = str(tmp_path / "robustness_joined.json")
    assert robustness_merge.merge(robustness_merge.split(joined)) == joined  # split and joined again: the same
    assert robustness_merge.main([whole, str(tmp_path / "again.json"), "--tag", "clash"]) == 2
    assert robustness_merge.main([whole, str(tmp_path / "again.json"), "--tag", "replaced", "--replace"]) == 0
    replaced = json.loads((tmp_path / "robustness_replaced.json").read_text())
    mine = {r["label"] for r in again["cells"]}
    assert [r["label"] for r in replaced["cells"]] == [r["label"] for r in joined["cells"]]
    assert [r for r in replaced["cells"] if r["label"] not in mine] == [
        r for r in joined["cells"] if r["label"] not in mine
    ]
    assert [r for r in replaced["cells"] if r["label"] in mine] == again["cells"]
    assert {r["label"] for r in replaced["sim_to_sim"]} == {r["label"] for r in joined["sim_to_sim"]} - mine
    # the replaced part's provenance dropped (none of its cells left), the new one's kept
    assert [p["command"] for p in replaced["parts"]][-1] == "played again" and len(replaced["parts"]) == 3
    assert "1/3" not in [p["part"] for p in replaced["parts"][:2]]


def test_overrides_score_a_randomised_policy_on_the_cells_model_alone():
    from hsa_mjx.deploy import policy_file
    from hsa_mjx.randomization_config import RandomizationConfig
    from train import config as train_config
    from train.episodes import policy_sources

    trained = policy_file.load_policy(policy_file.locate("flat_dr")).meta["config"]
    assert trained["env"]["randomization"]["push_speed"] > 0  # it trained with pushes and noise
    nominal = robustness_grids.grid("nominal")
    overrides = robustness.env_overrides(nominal[:36], 0.02, qacc_rule=False)
    overridden = {o.split("=")[0].rsplit(".", 1)[1] for o in overrides if ".randomization." in o}
    assert overridden == {f.name for f in dataclasses.fields(RandomizationConfig)}  # no training range leaks in
    env = train_config.from_dict(policy_sources.env_overrides(trained, overrides)).env
    assert env.randomization.push_speed == 0 and env.randomization.hsa_damping == env.randomization.servo_gain == (1, 1)
    assert env.randomization.hsa_stiffness == (0.7, 1.3) and env.randomization.latency_steps == (0, 2)
    assert not env.termination.qacc_termination  # simulator health and task failure only
    assert not any(dataclasses.asdict(env.observation.noise).values())
    stress = [c for c in robustness_grids.grid("stress") if c["noise"]]
    env = train_config.from_dict(
        policy_sources.env_overrides(trained, robustness.env_overrides(stress, 0.02, qacc_rule=True))
    ).env
    assert dataclasses.asdict(env.observation.noise) == robustness_grids.NOISE and env.termination.qacc_termination
    assert env.randomization.push_speed == robustness_grids.PUSH_SPEED  # the corner with pushes


def test_a_cell_without_pushes_is_never_pushed():
    import hsa_mjx
    from hsa_mjx.task.randomization import NEVER
    from train.episodes.rollout import with_randomization

    env = hsa_mjx.make_env("flat", randomization__push_speed=0.3, randomization__push_interval_s=[2.0, 4.0])
    state = env.reset(jax.random.PRNGKey(0))
    drawn = state.pipeline_state.task.randomization
    assert 100 <= int(drawn.next_push) <= 200  # 2-4 s of 20 ms steps
    physics, latency = drawn.physics, jnp.zeros((), jnp.int32)
    pushed = with_randomization(state, physics, latency, jnp.asarray(True)).pipeline_state.task.randomization
    assert int(pushed.next_push) == int(drawn.next_push)
    kept = with_randomization(state, physics, latency, jnp.asarray(False)).pipeline_state.task.randomization
    assert int(kept.next_push) == NEVER


def test_sim_to_sim_feeds_a_history_policy_with_noisy_readings():
    """The shipped randomised policy reads a history: the deployment loop's noise goes on this tick's
    readings only, and the episode runs."""
    from benchmarks.robustness import sim_to_sim
    from hsa_mjx.deploy import policy_file

    directory = policy_file.locate("flat_dr")
    assert policy_file.load_policy(directory).meta["config"]["env"]["observation"]["history_steps"] > 0
    cell = robustness_grids.cell(noise=True, latency_ms=60, servo_torque_limit=0.5)
    assert sim_to_sim.play_episode(str(directory), cell, [2.0, 0.0], 5, 0) is False  # 5 ticks: not there yet


def test_the_stability_check_runs_every_env_on_one_stress_corner():
    """``benchmarks.speed.throughput --observations stress_cornerN``: each corner of the stress grid as one fixed
    model (ranges collapsed to its values), without the qacc rule, so the NaN check alone guards the state."""
    import hsa_mjx
    from benchmarks.speed import cases

    corners = robustness_grids.stress_grid()[-4:]
    for number, corner in enumerate(corners, start=1):
        overrides = cases.OBSERVATIONS[f"stress_corner{number}"]()
        config = hsa_mjx.build_config("flat", **{k.replace(".", "__"): v for k, v in overrides.items()})
        drawn = config.randomization
        assert all(getattr(drawn, k) == (corner[k], corner[k]) for k in robustness_grids.SCALES)
        limit = corner["servo_torque_limit"]
        assert drawn.servo_force_limit == ((limit, limit) if limit else (0.0, 0.0))
        assert drawn.latency_steps == (corner["latency_ms"] // 20,) * 2 and drawn.pushes == corner["pushes"]
        assert config.observation.noise.enabled == corner["noise"] and not config.termination.qacc_termination


def test_a_stability_run_without_the_ceiling_is_reported_with_empty_ceiling_cells(tmp_path):
    """``--no-ceiling`` (long random-action runs at the corners): the row's ceiling fields are None and the
    table, the plot and a later ``--append`` run still work."""
    from benchmarks.speed import loops as throughput_loops
    from benchmarks.speed import report as throughput_report
    from benchmarks.speed import throughput

    assert throughput.parse_args(["--no-ceiling"]).ceiling is False and throughput.parse_args([]).ceiling is True
    assert throughput.parse_args(["--episode-steps", "10"]).episode_steps == 10
    with pytest.raises(SystemExit):
        throughput.parse_args(["--episode-steps", "0"])
    row = {
        "physics_backend": "jax",
        "terrain": "flat",
        "settings": "s",
        "observation": "stress_corner1",
        "batch": 8,
        "full_step": True,
        "env_steps_per_s": 100.0,
        "compile_s_env": 1.0,
        "nan_terminations_per_million_env_steps": 0.0,
        "obs_non_finite_seen": False,
        **dict.fromkeys(throughput_loops.CEILING_FIELDS),
    }
    paths = throughput_report.write_all(tmp_path, "t", [row], {"device": "cpu"})
    line = [r for r in paths[1].read_text().splitlines() if "stress_corner1" in r][0]
    assert "| 100 | - | - |" in line and paths[2].is_file()
    later = {**row, "observation": "stress_corner2"}
    rows = throughput_report.upsert(throughput_report.load_rows(paths[0]), later)
    assert [r["observation"] for r in rows] == ["stress_corner1", "stress_corner2"]


def test_the_randomised_config_trains_over_the_stress_grid_it_is_scored_on():
    """configs/train_flat_dr.yaml's ranges are the stress grid's (stated there as data, checked here, not
    restated): each scale spans its stress ends, latency, pushes and noise reach the grid's hardest cell."""
    from train import config as train_config

    env = train_config.load("configs/train_flat_dr.yaml").env
    for name, ends in robustness_grids.STRESS_ENDS.items():
        assert tuple(getattr(env.randomization, name)) == ends, name
    stress = robustness_grids.grid("stress")
    worst_latency_steps = max(c["latency_ms"] for c in stress) / 1000.0 / env.dt
    assert env.randomization.latency_steps[1] == pytest.approx(worst_latency_steps)
    assert env.randomization.servo_force_limit[0] == robustness_grids.STRESS_TORQUE_LIMIT
    assert env.randomization.push_speed == robustness_grids.PUSH_SPEED
    assert tuple(env.randomization.push_interval_s) == robustness_grids.PUSH_INTERVAL_S
    assert dataclasses.asdict(env.observation.noise) == robustness_grids.NOISE


def test_sim_to_sim_plays_a_profiles_servos_under_a_policy_trained_with_randomised_spring_servos():
    """flat_dr trained over spring-servo gains and torque limits, which a DC-motor servo refuses: the
    deployment loop plays the profile's cell on the cell's model alone, as the MJX rollout does."""
    directory = str(policy_file.locate("flat_dr"))
    for name in ("xl330_m288", "dfr05sr"):
        reached = sim_to_sim.play_episode(directory, robustness_grids.cell(servo=name), [1.5, 0.0], 5, 0)
        assert reached is False  # 5 steps: not at a goal 1.5 m away, but played
        assert sim_to_sim._loaded(directory, name)[1].servo == profile_servo(name)


def _scored(label: str, successes: int, episodes: int) -> dict:
    return {"label": label, **robustness.score(successes, episodes)}


def test_compare_matches_cells_by_label_and_calls_a_difference_only_outside_its_interval(tmp_path):
    head = {"physics_backend": "warp", "cells": [], "sim_to_sim": []}
    a = {**head, "policy": "policies/flat_dr", "episodes_per_cell": 256}
    b = {**head, "policy": "policies/flat", "episodes_per_cell": 32}
    a["cells"] = [_scored("training model", 250, 256), _scored("torque <= 0.5 N m", 80, 256), _scored("noise", 1, 256)]
    b["cells"] = [_scored("torque <= 0.5 N m", 10, 32), _scored("training model", 20, 32)]
    rows = robustness_compare.compare(a, b)
    assert [r["label"] for r in rows] == ["training model", "torque <= 0.5 N m"]  # A's order; "noise" unshared
    assert [r["verdict"] for r in rows] == ["A better", "not separated"]
    assert rows[1]["ci95"][0] < rows[1]["difference"] < rows[1]["ci95"][1]
    with pytest.raises(ValueError, match="share no cell"):
        robustness_compare.compare(a, {**b, "cells": [_scored("pushes", 1, 2)]})
    files = [tmp_path / "a.json", tmp_path / "b.json"]
    for path, result in zip(files, (a, b)):
        path.write_text(json.dumps(result))
    out = tmp_path / "versus.md"
    assert robustness_compare.main([*map(str, files), "--out", str(out)]) == 0
    assert "| training model | 98% (95%-99%, 256) | 62% (45%-77%, 32) |" in out.read_text()
    assert robustness_compare.main([str(files[0]), str(tmp_path / "none.json")]) == 2
