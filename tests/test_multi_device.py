"""Several devices on the CPU: training, resume, the curricula and envs over devices, the per-device
learner, two processes and their preemption (and the scenario of tests/test_backend.py's per-device
Warp run).

The work runs in fresh interpreters (tests/multi_device_scenarios.py: fake CPU devices exist only when
set before JAX starts), each printing one JSON line of facts; the tests assert on those facts.
"""

from __future__ import annotations

import dataclasses
import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from multi_device_scenarios import FACTS, PROCESSES_CONFIG, ROOT, TWO_DEVICE_CONFIG

SCENARIOS = Path(__file__).with_name("multi_device_scenarios.py")
FAKE_DEVICES = 2
SUBPROCESS_TIMEOUT_S = 480  # cold compiles on a 2-core CPU take minutes; a hang fails instead of stalling CI
# Largest leaf difference, relative to max(1, |leaf|), between the pmap and per-device runs (and the
# tolerance of their episode totals): float rounding gives ~3e-6 on the leaves and 1.3e-5 on a summed
# reward term after 2 epochs, while the diverged 4-iteration runs differed by 2e-2.
SAME_RUN_TOLERANCE = 1e-4
# What the per-device learner's log must share with pmap's: everything but speed and wall-clock.
LEARNING_PREFIXES = ("episode", "curriculum/", "loss/", "step/", "termination/", "terrain", "reward", "nonfinite/")
COMPARED_METRICS = (
    "episode/return",
    "episode/final_distance",
    "loss/total_loss",
    "loss/policy_loss",
    "curriculum/max_distance",
    "curriculum/episode_count",
)
# How long the survivor of a SIGKILL may take to stop: Gloo sees the closed connection at its next
# collective, long before the coordination service's heartbeat (100 s) would give up on the peer.
SURVIVOR_S = 60


def _free_port() -> int:
    """A TCP port on localhost that nothing listens on now (for the coordinator)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _subprocess_env(devices: int | None) -> dict:
    """The test environment (conftest's XLA flags) plus the fake device count and the persistent compile cache.

    The device count goes through JAX (``JAX_NUM_CPU_DEVICES``), not ``XLA_FLAGS``: the cache keys on
    the XLA flags, so every process of the suite keeps the same ones and shares its entries."""
    import jax

    env = {**os.environ, "JAX_PLATFORMS": "cpu"}
    # the scripts run from tests/: the checkout on the path gives them its train/
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(ROOT), os.environ.get("PYTHONPATH")) if p)
    env.pop("JAX_NUM_CPU_DEVICES", None)
    if jax.config.jax_compilation_cache_dir:
        env["JAX_COMPILATION_CACHE_DIR"] = str(jax.config.jax_compilation_cache_dir)
        env["JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"] = str(jax.config.jax_persistent_cache_min_compile_time_secs)
    if devices:
        env["JAX_NUM_CPU_DEVICES"] = str(devices)
    return env


def write_config(path: Path, data: dict) -> str:
    """Write a training config as YAML; its path."""
    path.write_text(yaml.safe_dump(data))
    return str(path)


def _facts(stdout: str) -> dict:
    """The JSON a scenario printed."""
    return json.loads([ln for ln in stdout.splitlines() if ln.startswith(FACTS)][-1][len(FACTS) :])


@dataclasses.dataclass
class Runs:
    """What the module's tests read: the two-device scenario's facts and run dir, and the two processes'
    launches (``launches[name]``: each process's facts or exit status) and run dir."""

    facts: dict
    run_dir: Path
    launches: dict
    process_run_dir: Path

    def __iter__(self):  # facts, run_dir = two_devices
        return iter((self.facts, self.run_dir))


@pytest.fixture(scope="module")
def two_devices(tmp_path_factory):
    """The two-device scenario in one subprocess and, beside it, two launches of two processes of one
    device each: a run whose process 1 comes late to the loop and whose process 0 is killed (SIGKILL),
    then its resume, stopped by SIGTERM to process 1. The processes start first: process 1's deliberate
    wait overlaps the scenario's compiles."""
    tmp = tmp_path_factory.mktemp("two_devices")
    config = write_config(tmp / "tiny.yaml", TWO_DEVICE_CONFIG)
    processes = write_config(tmp / "processes.yaml", PROCESSES_CONFIG)
    killed = _launch_processes(processes, tmp / "processes", "160", ("kill@2", "late"), tmp / "kill")
    command = [sys.executable, str(SCENARIOS), "two_devices", config, str(tmp / "run"), processes]
    scenario = _start([command], tmp / "scenario")
    try:
        _wait(killed[:1], SUBPROCESS_TIMEOUT_S)  # process 0 dies at its second epoch...
        launches = {"kill": {"survivor_s": _wait(killed[1:], SURVIVOR_S)}}  # ...process 1 must follow, not hang
        launches["kill"].update(returncodes=[p.returncode for p, _ in killed], steps=_steps(tmp / "processes"))
        resumed = _launch_processes(processes, tmp / "processes", "320", ("none", "term@2"), tmp / "resume")
        launches["resume"] = _finish_processes(resumed)
        launches["resume"][0]["summary"] = json.loads((tmp / "processes" / "summary.json").read_text())
    finally:
        facts = _finish_processes(scenario)[0]
    return Runs(facts, tmp / "run", launches, tmp / "processes")


def _launch_processes(config: str, run_dir: Path, steps: str, actions: tuple[str, str], logs: Path) -> list:
    """Start both processes of one launch of a two-process run, process i with ``actions[i]``."""
    base = [sys.executable, str(SCENARIOS), "process", config, str(run_dir), str(_free_port()), steps]
    return _start([base + [action, str(i)] for i, action in enumerate(actions)], logs, devices=None)


def _start(
    commands: list[list[str]], logs: Path, devices: int | None = FAKE_DEVICES
) -> list[tuple[subprocess.Popen, Path]]:
    """Start each command at once, the i-th writing its output to ``logs/process_i.{out,err}`` (pipes read
    one process at a time could fill up and stall the others); ``devices`` fake CPU devices each."""
    logs.mkdir(exist_ok=True)
    started = []
    for i, command in enumerate(commands):
        out = logs / f"process_{i}"
        with open(f"{out}.out", "w") as stdout, open(f"{out}.err", "w") as stderr:
            env = _subprocess_env(devices)
            started.append((subprocess.Popen(command, cwd=ROOT, env=env, stdout=stdout, stderr=stderr, text=True), out))
    return started


def _wait(started: list[tuple[subprocess.Popen, Path]], timeout: float) -> float:
    """Seconds until every process has exited (each one still running past ``timeout`` killed)."""
    start = time.perf_counter()
    try:
        for proc, _ in started:
            proc.wait(timeout=max(1.0, timeout - (time.perf_counter() - start)))
    except subprocess.TimeoutExpired:
        pass
    finally:
        for proc, _ in started:
            if proc.poll() is None:
                proc.kill()
    return time.perf_counter() - start


def _finish_processes(started: list[tuple[subprocess.Popen, Path]]) -> list[dict]:
    """The facts of processes started by ``_start`` (every failed one's output on failure)."""
    _wait(started, SUBPROCESS_TIMEOUT_S)
    outs = [(Path(f"{out}.out").read_text(), Path(f"{out}.err").read_text()) for _, out in started]
    failed = [
        f"process {i}: exit {proc.returncode}\n{out[0][-3000:]}\n{out[1][-3000:]}"
        for i, ((proc, _), out) in enumerate(zip(started, outs))
        if proc.returncode != 0
    ]
    assert not failed, "\n\n".join(failed)  # every failed process's output: the first to fail may be another
    return [_facts(out[0]) for out in outs]


def _steps(run_dir: Path) -> list[int]:
    """The steps of the run's metrics records, in file order."""
    return [r["step"] for r in _records(run_dir)]


def _records(run_dir: Path) -> list[dict]:
    """The run's metrics records."""
    from train.run.logger import read_jsonl

    return read_jsonl(run_dir / "metrics.jsonl")


def test_two_devices_train_resume_and_write_each_checkpoint_once(two_devices):
    from train.run import checkpoint

    facts, run_dir = two_devices
    assert facts["rc_train"] == 0 and facts["rc_resume"] == 0
    assert facts["saved_first"] == [80, 160] and facts["saved_resume"] == [240]
    assert [p.name for p in checkpoint.list_checkpoints(run_dir)] == [  # the one-device resume's 280 pruned 80
        "step_000000000160",
        "step_000000000240",
        "step_000000000280",
    ]
    assert not [p for p in checkpoint.checkpoint_dir(run_dir).iterdir() if p.name.startswith(".tmp")]
    assert [r["step"] for r in _records(run_dir)] == [80, 160, 240, 280]  # one log record per epoch, not per device


def test_curriculum_counts_the_episodes_of_both_devices(two_devices):
    facts, run_dir = two_devices
    first_run = [r for r in _records(run_dir) if r["step"] == 160][0]
    assert first_run["episodes"] == 8  # 20 steps per env, one 15-step episode for each of the 8 envs
    assert first_run["curriculum/episode_count"] == 8  # not 4: both devices' episodes reach the curriculum
    assert first_run["curriculum/max_distance"] > 1.8 + 1e-6  # a full window of 4 widened it
    assert facts["episodes_seen"] == 8  # two epochs of 80 steps from fresh envs: again all 8 episodes
    assert facts["leaves"] > 10 and facts["replicas_differing"] == []  # one learner and curriculum, copied


def test_curriculum_update_gathers_outcomes_of_all_devices(two_devices):
    facts, _ = two_devices
    pmapped, reference = facts["curriculum_pmapped"], facts["curriculum_reference"]
    for key, value in reference.items():
        per_device = np.asarray(pmapped[key])
        assert per_device.shape[0] == FAKE_DEVICES
        for copy in per_device:  # identical on every device and equal to one update over all outcomes
            np.testing.assert_array_equal(copy, value, err_msg=key)
    assert reference["max_distance"] > 1.8 + 1e-6  # the gathered window widened the range...
    assert all(a["max_distance"] == pytest.approx(1.8) for a in facts["curriculum_alone"])  # ...no device alone did


def _saved_levels(run_dir: Path, step: int) -> np.ndarray:
    """The per-env terrain levels a checkpoint of the run holds."""
    from train.run import checkpoint

    path = checkpoint.checkpoint_dir(run_dir) / f"step_{step:012d}"
    count = checkpoint.read_meta(path)["terrain_envs"]
    template = {"terrain_levels": {"row": np.zeros(count, np.int32), "level": np.zeros(count, np.int32)}}
    return checkpoint.load(path, template)["terrain_levels"]["level"]


def test_terrain_levels_move_on_every_device_and_survive_resume(two_devices):
    facts, run_dir = two_devices
    rows, start, after = (np.asarray(facts[k]) for k in ("terrain_rows", "terrain_start", "terrain_after"))
    assert rows.shape == start.shape == (FAKE_DEVICES, 4)
    assert all(sorted(r) == [0, 0, 1, 1] for r in rows.tolist())  # each device's envs split over both types
    assert set(start.reshape(-1).tolist()) == {0, 1, 2}  # spread over all three levels at the start
    np.testing.assert_array_equal(after, np.maximum(start - 1, 0))  # one short episode each: one level down
    totals = facts["terrain_totals"]  # summed over both devices
    assert totals["terrain_envs/flat"][0] == totals["terrain_envs/stairs"][0] == 4
    assert sum(v[0] for k, v in totals.items() if k.startswith("terrain_level_sum/")) == after.sum()
    first, resumed = _saved_levels(run_dir, 160), _saved_levels(run_dir, 240)
    assert first.shape == (8,)
    # 160 -> 240 steps is 10 steps per env: no episode ends, so a resume that restored the levels keeps them
    np.testing.assert_array_equal(resumed, first)
    record = [r for r in _records(run_dir) if r["step"] == 160][0]
    assert record["terrain/levels"] == 3 and record["terrain/mean_level/flat"] + record[
        "terrain/mean_level/stairs"
    ] == pytest.approx(first.mean() * 2)


def test_envs_differ_across_devices(two_devices):
    facts, _ = two_devices
    goals = np.asarray(facts["goals"])  # (devices, envs per device, 2)
    assert goals.shape == (FAKE_DEVICES, 4, 2)
    flat = goals.reshape(-1, 2)
    assert len({tuple(np.round(g, 6)) for g in flat}) == len(flat)  # every env of every device its own goal


def test_per_device_learner_trains_exactly_like_pmap(two_devices):
    """One jitted collection per device (train/per_device.py) gives the pmap epoch's results (to float rounding)."""
    facts, _ = two_devices
    assert facts["rc_per_device"] == 0
    assert facts["same_run_leaves"] > 10  # parameters, optimiser and normaliser after 2 epochs...
    assert facts["same_run_param_gap"] < SAME_RUN_TOLERANCE  # ...within float rounding of pmap's
    assert facts["same_run_rest_equal"]  # the same curriculum, PRNG key and terrain levels
    compiles = facts["per_device_epoch_compiles"]
    assert len(compiles) == 2 and compiles[1] == 0  # the second epoch compiles nothing


def test_trainer_with_per_device_learner_logs_what_pmap_logged(two_devices):
    from train.run import checkpoint

    facts, run_dir = two_devices
    assert facts["rc_per_device"] == 0
    per_device_dir = Path(facts["per_device_run_dir"])
    assert [p.name for p in checkpoint.list_checkpoints(per_device_dir)] == ["step_000000000080", "step_000000000160"]
    pmap_records = [r for r in _records(run_dir) if r["step"] <= 160]
    records = _records(per_device_dir)
    assert [r["step"] for r in records] == [r["step"] for r in pmap_records] == [80, 160]
    for mine, theirs in zip(records, pmap_records):
        assert set(mine) == set(theirs)
        for key in (k for k in theirs if k.startswith(LEARNING_PREFIXES)):  # every figure but the timings
            assert mine[key] == pytest.approx(theirs[key], rel=SAME_RUN_TOLERANCE, abs=1e-6), (mine["step"], key)
    assert "episode/return" in records[-1] and records[-1]["curriculum/episode_count"] == 8  # both devices' episodes


def test_thread_per_device_trains_on_the_warp_backend(two_devices):
    """The multi-GPU path on MuJoCo Warp, over the two fake CPU devices (last in the scenario: by then
    tests/test_backend.py's rollouts, on the other worker, have compiled Warp's CPU kernels into its cache)."""
    from train.run.logger import read_jsonl

    assert two_devices.facts["rc_warp"] == 0
    run_dir = two_devices.run_dir.parent / "run_warp"
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["physics_backend"] == "warp" and summary["env_steps"] == 80
    assert (summary["collection"], summary["devices"], summary["processes"]) == ("thread_per_device", 2, 1)
    last = read_jsonl(run_dir / "metrics.jsonl")[-1]
    assert last["episodes"] == 8 and last["curriculum/episode_count"] == 8  # both devices' envs, as on JAX
    assert last["terrain/levels"] == 3 and last["nonfinite/states"] == 0


def test_no_recompile_at_the_second_epoch(two_devices):
    compiles = two_devices.facts["epoch_compiles"]  # the pmap learner's epochs in the first run
    assert len(compiles) == 2 and compiles[0] > 0 and compiles[1] == 0


def test_bad_device_split_refused_before_compile(two_devices):
    facts, _ = two_devices
    assert "run.num_envs = 3 must be divisible by the 2 devices" in facts["refusals"]["indivisible"]
    assert "only 2 local devices" in facts["refusals"]["too_many"]
    assert facts["refusal_compiles"] == 0 and facts["refusal_dirs"] == []


def test_two_processes_train_like_two_devices(two_devices):
    """Process 1 comes 40 s late to the loop (more than Gloo's 30 s wait): the first epoch is what one
    process with two devices logged for the same config."""
    assert two_devices.facts["rc_processes_config"] == 0
    mine = _records(two_devices.process_run_dir)[0]
    theirs = _records(two_devices.run_dir.parent / "run_flat")[0]
    assert mine["step"] == theirs["step"] == 80 and set(mine) == set(theirs)
    # The same global env and epoch keys, the same reductions over the processes as over the devices.
    for key in COMPARED_METRICS:
        assert mine[key] == pytest.approx(theirs[key], rel=1e-4, abs=1e-6), key
    assert mine["episodes"] == 8  # every env's first episode (10 steps) ended in the epoch: compared


def test_a_killed_process_takes_the_other_down_and_leaves_its_checkpoint(two_devices):
    """Process 0 of a run is killed (SIGKILL) at its second epoch: process 1 stops at once with an error,
    and the run dir holds the first epoch, logged and checkpointed."""
    kill = two_devices.launches["kill"]
    assert kill["returncodes"][0] == -signal.SIGKILL
    assert kill["returncodes"][1] != 0 and kill["survivor_s"] < SURVIVOR_S
    assert kill["steps"] == [80]


def test_every_process_resumes_after_a_kill_and_a_sigterm_stops_both(two_devices):
    """The killed run resumed on both processes; process 1 gets SIGTERM at its second epoch: both stop
    there, process 0 alone writes, and the log holds each epoch once."""
    from train.run import checkpoint

    facts, run_dir = two_devices.launches["resume"], two_devices.process_run_dir
    assert [f["rc"] for f in facts] == [0, 0]
    assert facts[0]["saved"] == [160, 240] and facts[1]["saved"] == []  # process 0 alone writes
    summary = facts[0]["summary"]
    assert summary["interrupted"] is True and summary["env_steps"] == 240
    assert (summary["collection"], summary["devices"], summary["processes"]) == ("pmap", 2, 2)  # auto resolved
    assert [p.name for p in checkpoint.list_checkpoints(run_dir)] == [f"step_{s:012d}" for s in (80, 160, 240)]
    assert not [p for p in checkpoint.checkpoint_dir(run_dir).iterdir() if p.name.startswith(".tmp")]
    lines = (run_dir / "metrics.jsonl").read_text().splitlines()
    assert [json.loads(line)["step"] for line in lines] == [80, 160, 240]  # each line whole, none twice
    logs = run_dir.parent / "resume"
    assert "resumed from" in (logs / "process_0.out").read_text()
    assert "signal 15: finishing this epoch" in (logs / "process_1.out").read_text()
    for i in (0, 1):  # the resumed launch's error streams hold no traceback
        assert "Traceback" not in (logs / f"process_{i}.err").read_text()


def test_two_device_checkpoint_resumes_and_evaluates_on_one_device(two_devices):
    from train.evaluate import main as evaluate
    from train.run import checkpoint

    facts, run_dir = two_devices
    assert facts["rc_one_device"] == 0 and facts["saved_one_device"] == [280]
    meta = checkpoint.read_meta(checkpoint.latest(run_dir))
    assert meta["step"] == 280 and meta["config"]["run"]["num_devices"] == 1
    assert meta["config"]["run"]["collection"] == "thread_per_device"
    last = _records(run_dir)[-1]
    assert last["step"] == 280 and last["curriculum/episode_count"] >= 8  # the curriculum came along
    assert (
        evaluate([str(run_dir), "--episodes", "2", "--steps", "12", "--backend", "c"]) == 0
    )  # C MuJoCo: a short compile
    assert json.loads((run_dir / "eval" / "eval.json").read_text())["step"] == 280
    # the table by terrain type and difficulty (one atlas of both types at 0, 0.5 and 1)
    assert (
        evaluate(
            [
                str(run_dir),
                "--terrain-types",
                "all",
                "--levels",
                "0,0.5,1",
                "--episodes",
                "2",
                "--steps",
                "5",
                "--tiles",
                "2",
                "--backend",
                "c",
                "--video",
                "--video-cell",
                "stairs:0.5",
            ]
        )
        == 0
    )
    table = json.loads((run_dir / "eval" / "terrain_eval.json").read_text())
    assert (run_dir / "eval" / "episode_stairs_0.5.gif").stat().st_size > 1_000  # the chosen cell, rendered
    assert [(r["type"], r["difficulty"], r["episodes"]) for r in table["rows"]] == [
        (t, d, 2) for t in ("flat", "stairs") for d in (0.0, 0.5, 1.0)
    ]
    assert all(0.0 <= r["success_rate"] <= 1.0 and np.isfinite(r["mean_progress_m"]) for r in table["rows"])
    assert all((r["success_speed_m_s"] is None) == (r["success_rate"] == 0.0) for r in table["rows"])
    assert (run_dir / "eval" / "terrain_eval.png").stat().st_size > 5_000
    assert (run_dir / "eval" / "failure_modes.png").stat().st_size > 5_000  # how each cell's episodes ended
    assert all(sum(r["modes"].values()) == pytest.approx(1.0) for r in table["rows"])
    assert table["failure_rule"] == {"window_s": 20.0, "stuck_m": 0.1}
    # evaluated on tiles the run's pool was not drawn from, both seeds recorded
    assert table["terrain_seed"] != table["training_terrain_seed"] and "training_seed" in table
    assert table["tiles_per_cell"] == 2


def test_td3_trains_on_two_devices_with_a_buffer_on_each(two_devices):
    facts, _ = two_devices
    td3 = facts["td3"]
    assert td3["rc"] == 0 and td3["collection"] == "pmap"  # auto: pmap for TD3
    assert td3["loss/buffer_size"] == 64  # each device: 4 envs, rings of 32 / 4 = 8 rows, full after 10 steps; summed
    assert all(v == v and abs(v) < 1e6 for v in (td3["loss/critic_loss"], td3["loss/q_mean"]))
    assert td3["loss/skipped_updates"] == 0
