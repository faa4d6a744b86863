"""Several devices on the CPU: training, resume, the curricula and envs over devices, the per-device
learner, two processes, scaling (and the scenario of tests/test_backend.py's per-device Warp run).

Fake CPU devices (``JAX_NUM_CPU_DEVICES``) exist only when set before JAX starts, so the multi-device
work runs this file as a script in fresh interpreters (``python tests/test_multi_device.py SCENARIO ...``)
that print one JSON line of facts; the tests assert on those facts. Compiles go through the persistent
cache configured in tests/conftest.py.
"""

from __future__ import annotations

import dataclasses
import faulthandler
import json
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from test_train_run import TINY

ROOT = Path(__file__).resolve().parents[1]
FAKE_DEVICES = 2
SUBPROCESS_TIMEOUT_S = 480  # cold compiles on a 2-core CPU take minutes; a hang fails instead of stalling CI
FACTS = "FACTS "
# 8 envs over 2 devices, one PPO iteration (80 env steps) per epoch: 160 steps = one 15-step episode per env.
# The solver runs to convergence (20 iterations, not TINY's 4): the pmap and per-device programs are
# compiled separately and may round differently (seen on an AVX2 CI CPU), and the under-converged
# 4-iteration solver turned a 6e-6 m difference into 5e-3 m in one step; converged, it stays ~1e-7.
# On terrain with the terrain curriculum: two types over 3 levels, start levels spread over all three;
# a random 15-step episode covers far less than demote_progress of its goal distance, so every episode
# end moves its env down one level (the facts below check it, and that a resume keeps the levels).
TERRAIN = {"types": ["flat", "stairs"], "proportions": [0.5, 0.5], "levels": 3, "tiles_per_type": 1}
TWO_DEVICE_CONFIG = {
    **TINY,
    "env": {**TINY["env"], "preset": "mixed", "terrain": TERRAIN, "physics": {"iterations": 20, "ls_iterations": 20}},
    "terrain_curriculum": {"enabled": True, "initial_spread": 1.0},
    "ppo": {**TINY["ppo"], "batch_size": 8},
    "run": {"num_timesteps": 160, "num_envs": 8, "checkpoint_every": 80, "seed": 1},
}
# Largest leaf difference, relative to max(1, |leaf|), between the pmap and per-device runs (and the
# tolerance of their episode totals): float rounding gives ~3e-6 on the leaves and 1.3e-5 on a summed
# reward term after 2 epochs, while the diverged 4-iteration runs differed by 2e-2.
SAME_RUN_TOLERANCE = 1e-4
# How late the second training process starts: more than Gloo's 30 s wait, which the barriers cover.
PROCESS_1_LATE_S = 40
# The resume on one device: 4 envs with TINY's minibatch, checkpoints every 40 steps, 240 -> 280 steps,
# by the thread-per-device strategy, whose collection on device 0 then has the geometry of the two-device
# run's (4 envs, 2 unrolls of 5): its compile is a cache hit. (A persistent cache entry of a process with
# two CPU devices does not serve one with one: JAX keys it on the device topology.)
ONE_DEVICE_RESUME = [
    f"--set={key}={value}"
    for key, value in (
        ("run.num_devices", 1),
        ("run.num_envs", 4),
        ("ppo.batch_size", TINY["ppo"]["batch_size"]),
        ("run.checkpoint_every", 40),
        ("run.num_timesteps", 280),
        ("run.collection", "thread_per_device"),
    )
]
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


# ----- run in the subprocess --------------------------------------------------------------------
def _compile_counter() -> list:
    """A list that gains one entry per XLA compile request from now on (cache hits included)."""
    import jax

    events: list = []
    jax.monitoring.register_event_duration_secs_listener(
        lambda name, secs, **_: events.append(name) if name == "/jax/core/compile/backend_compile_duration" else None
    )
    return events


def _fresh_traces() -> None:
    """Forget this process's traces before a phase, so that it compiles the same program text as the first.

    JAX shares private functions inside one lowered module through caches keyed by in-memory objects,
    so the same epoch traced again later in a process can lower to different (equivalent) text and
    miss the persistent compilation cache: a second 30-s compile per phase on a 2-core CPU."""
    import jax

    jax.clear_caches()


def _record_saves() -> list[int]:
    """Steps of every checkpoint written from now on (train.checkpoint.save wrapped)."""
    from train import checkpoint

    saved, save = [], checkpoint.save
    checkpoint.save = lambda run_dir, step, *a, **k: saved.append(step) or save(run_dir, step, *a, **k)
    return saved


def _refusals(config_path: str, tmp: Path, compiles: list) -> dict:
    """Messages of the configs refused on 2 devices, and whether anything compiled or was written first."""
    from train import config as train_config
    from train.trainer import train

    before, messages = len(compiles), {}
    bad = {"indivisible": ["run.num_envs=3", "ppo.batch_size=3"], "too_many": ["run.num_devices=3"]}
    for name, override in bad.items():
        try:
            train(train_config.load(config_path, override), tmp / name, quiet=True)
        except ValueError as err:
            messages[name] = str(err)
    made = [name for name in messages if (tmp / name).exists()]
    return {"refusals": messages, "refusal_compiles": len(compiles) - before, "refusal_dirs": made}


def _probe(cls: type, compiles: list) -> dict:
    """From now on, record each ``reset`` and ``epoch`` of the trainer's learner class ``cls``: what they
    return (copied to the host) and, per epoch, the compile requests it made."""
    import jax

    seen: dict = {"resets": [], "epochs": [], "epoch_compiles": []}
    reset, epoch = cls.reset, cls.epoch

    def probed_reset(self, *args, **kwargs):
        state = reset(self, *args, **kwargs)
        seen["resets"].append(jax.device_get(state))
        return state

    def probed_epoch(self, *args, **kwargs):
        before = len(compiles)
        out = epoch(self, *args, **kwargs)
        seen["epoch_compiles"].append(len(compiles) - before)
        seen["epochs"].append(jax.device_get(out))
        return out

    cls.reset, cls.epoch = probed_reset, probed_epoch
    return seen


def _checkpoint_gap(run_a: str, run_b: str, step: int) -> dict:
    """How far apart two runs' checkpoints at ``step`` are: the learner's largest leaf difference relative
    to max(1, |leaf|) (parameters, optimiser, normaliser), and whether the rest (curriculum, PRNG key,
    terrain levels) is equal."""
    from flax import serialization

    from train import checkpoint

    def load(run: str) -> dict:
        path = checkpoint.checkpoint_dir(run) / f"step_{step:012d}" / checkpoint.STATE_FILE
        return serialization.msgpack_restore(path.read_bytes())

    a, b = load(run_a), load(run_b)
    pairs = list(zip(_float_leaves(a.pop("training_state")), _float_leaves(b.pop("training_state"))))
    gap = max(float(np.max(np.abs(x - y)) / max(1.0, float(np.max(np.abs(x))))) for x, y in pairs)
    rest_equal = sorted(a) == sorted(b) and all(
        np.array_equal(x, y) for x, y in zip(_float_leaves(a), _float_leaves(b))
    )
    return {"same_run_param_gap": gap, "same_run_leaves": len(pairs), "same_run_rest_equal": rest_equal}


def _float_leaves(tree: dict) -> list[np.ndarray]:
    """The leaves of a restored checkpoint tree as float64 arrays, in key order."""
    import jax

    return [np.asarray(x, np.float64) for x in jax.tree.leaves(tree)]


def _learner_facts(seen: dict) -> dict:
    """From the probed pmap learner of a fresh two-epoch run: goals per device after the reset, terrain
    cells before and after, recompiles at the second epoch, replicas after it."""
    import jax

    start, (ts, state, out) = seen["resets"][0], seen["epochs"][1]
    terrain = {
        "terrain_rows": start.curricula.terrain.terrain_type.tolist(),
        "terrain_start": start.curricula.terrain.level.tolist(),
        "terrain_after": state.curricula.terrain.level.tolist(),
        "terrain_totals": {k: np.asarray(v).tolist() for k, v in out["totals"].items() if k.startswith("terrain_")},
    }
    leaves = jax.tree_util.tree_leaves_with_path({"learner": ts, "curriculum": state.curricula.goal})
    differing = [
        jax.tree_util.keystr(path)
        for path, x in leaves
        if not all(np.array_equal(np.asarray(x)[0], copy) for copy in np.asarray(x))
    ]
    return {
        "goals": start.envs.env.pipeline_state.task.goal_xy.tolist(),
        "epoch_compiles": list(seen["epoch_compiles"]),
        "leaves": len(leaves),
        "replicas_differing": differing,
        "episodes_seen": int(state.curricula.goal.episode_count[0]),
        **terrain,
    }


# Episode ends of 3 batch steps on 2 devices x 4 envs: 6 per device (under the window of 8), 12 in all.
DONE = [[[1, 1, 0, 0], [1, 0, 1, 0]], [[0, 1, 1, 0], [0, 0, 1, 1]], [[1, 0, 0, 1], [1, 1, 0, 0]]]
SUCCESS = [[[1, 1, 0, 0], [1, 0, 0, 0]], [[0, 1, 1, 0], [0, 0, 1, 1]], [[0, 0, 0, 1], [1, 0, 0, 0]]]


def _curriculum_facts() -> dict:
    """The goal curriculum under pmap from per-device outcomes gathered over the devices (as the learner
    gathers a collection's); one update over all of them; each device alone."""
    import jax
    import jax.numpy as jnp

    from hsa_mjx.curricula import goal_curriculum
    from hsa_mjx.curricula.state import CurriculumRules
    from train import config as train_config
    from train.learner import AXIS
    from train.replicas import replicate

    config = goal_curriculum.GoalCurriculumConfig(
        window_size=8, min_episodes=8, success_threshold=0.5, failure_threshold=0.2
    )
    env = train_config.from_dict({}).env
    rules, start = CurriculumRules(env, config), tuple(env.goal.radial_range)
    done, success = np.asarray(DONE, bool), np.asarray(SUCCESS, bool)  # (steps, devices, envs)

    def steps(cstate, success, done):  # (steps, envs) per device -> (steps, all envs), device order
        def gather(x):
            return jax.lax.all_gather(x, AXIS, axis=1, tiled=True)

        return rules.after_collection(cstate, gather(success), gather(done))

    first = replicate(goal_curriculum.init(config, start), jax.local_devices()[: done.shape[1]])
    gathered = jax.pmap(steps, axis_name=AXIS)(first, jnp.swapaxes(success, 0, 1), jnp.swapaxes(done, 0, 1))
    reference = goal_curriculum.init(config, start)
    alone = [goal_curriculum.init(config, start) for _ in range(done.shape[1])]
    for s, d in zip(success, done):  # device 0's envs, then device 1's
        reference = goal_curriculum.update(reference, s.reshape(-1), d.reshape(-1), config, start)
        alone = [goal_curriculum.update(a, s[i], d[i], config, start) for i, a in enumerate(alone)]

    def as_lists(tree):
        return {k: np.asarray(v).tolist() for k, v in vars(tree).items()}

    return {
        "curriculum_pmapped": as_lists(gathered),
        "curriculum_reference": as_lists(reference),
        "curriculum_alone": [as_lists(a) for a in alone],
    }


def scenario_two_devices(config_path: str, run_dir: str) -> dict:
    """Train through the CLI on two devices of one process, resume, refusals, per-device facts, the
    thread-per-device strategy on the Warp backend last (``phase_s``: each part's seconds)."""
    compiles, saved = _compile_counter(), _record_saves()
    clock, phases = time.perf_counter(), {}

    def phase(name: str) -> None:
        nonlocal clock
        phases[name], clock = round(time.perf_counter() - clock, 1), time.perf_counter()

    from train.cli import main
    from train.strategies import Pmap
    from train.thread_per_device import ThreadPerDevice

    pmap_seen = _probe(Pmap, compiles)
    args = ["--config", config_path, "--run-dir", run_dir, "--quiet"]
    rc_train = main(args)
    phase("pmap_train")
    saved_first = list(saved)
    learner = _learner_facts(pmap_seen)
    _fresh_traces()
    rc_resume = main(args + ["--resume", "--set", "run.num_timesteps=240"])
    phase("pmap_resume")
    facts = {
        "rc_train": rc_train,
        "rc_resume": rc_resume,
        "saved_first": saved_first,
        "saved_resume": saved[len(saved_first) :],
    }
    facts.update(learner)
    facts.update(_refusals(config_path, Path(run_dir).parent, compiles))
    phase("refusals")
    # the same run (config, seed, keys) with one jitted collection per device: checkpoints and logs as pmap's
    per_device_dir = str(Path(run_dir).parent / "run_per_device")
    _fresh_traces()
    per_device_seen = _probe(ThreadPerDevice, compiles)
    facts["rc_per_device"] = main(
        ["--config", config_path, "--run-dir", per_device_dir, "--quiet", "--set", "run.collection=thread_per_device"]
    )
    phase("thread_per_device_train")
    facts.update(
        _checkpoint_gap(run_dir, per_device_dir, 160),
        per_device_run_dir=per_device_dir,
        per_device_epoch_compiles=list(per_device_seen["epoch_compiles"]),
    )
    # the two-device checkpoint resumed on one device by the thread-per-device strategy (see ONE_DEVICE_RESUME)
    _fresh_traces()
    before = len(saved)
    facts["rc_one_device"] = main(args + ["--resume", *ONE_DEVICE_RESUME])
    facts["saved_one_device"] = saved[before:]
    phase("one_device_resume")
    facts.update(_curriculum_facts())
    phase("curriculum")
    _fresh_traces()
    facts["rc_warp"] = _warp_thread_per_device(config_path, str(Path(run_dir).parent / "run_warp"))
    phase("warp_thread_per_device")
    return {**facts, "phase_s": phases}


def scenario_process(config_path: str, run_dir: str, port: str, process_id: str) -> dict:
    """One of two processes (one CPU device each) training through the CLI; process 1 comes late to the loop."""
    saved = _record_saves()
    from train import trainer
    from train.cli import main

    loop = trainer.run_epochs

    def late_loop(*args, **kwargs):  # later than the 30 s a collective's first use waits for the other processes
        time.sleep(PROCESS_1_LATE_S if process_id == "1" else 0)
        return loop(*args, **kwargs)

    trainer.run_epochs = late_loop
    rc = main(
        [
            "--config",
            config_path,
            "--run-dir",
            run_dir,
            "--quiet",
            "--coordinator",
            f"127.0.0.1:{port}",
            "--num-processes",
            "2",
            "--process-id",
            process_id,
        ]
    )
    return {"rc": rc, "saved": saved}


def _warp_thread_per_device(config_path: str, run_dir: str) -> int:
    """The thread-per-device strategy (one env copy and one jitted collection per device) on the Warp
    backend, through the CLI: one epoch (10 steps per env) with 8-step episodes, so that every env ends
    one episode (Warp runs slowly on a CPU). The physics settings of tests/test_backend.py's Warp rollouts,
    which compile most of Warp's kernels for these ones (into Warp's cache) on the other worker before."""
    from train.cli import main

    overrides = (
        "env.physics.backend=warp",
        "env.physics.integrator=implicitfast",
        "env.physics.iterations=8",
        "env.physics.ls_iterations=8",
        "run.collection=thread_per_device",
        "run.num_timesteps=80",
        "env.termination.max_episode_steps=8",
    )
    return main(["--config", config_path, "--run-dir", run_dir, "--quiet", *(f"--set={o}" for o in overrides)])


SCENARIOS = {"two_devices": scenario_two_devices, "process": scenario_process}


# ----- the tests ------------------------------------------------------------------------------
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


def _check(proc: subprocess.CompletedProcess) -> str:
    """The stdout of a subprocess that must have succeeded (its output tails in the failure message)."""
    assert proc.returncode == 0, f"exit {proc.returncode}\n{proc.stdout[-4000:]}\n{proc.stderr[-4000:]}"
    return proc.stdout


def write_config(path: Path, data: dict) -> str:
    """Write a training config as YAML; its path."""
    path.write_text(yaml.safe_dump(data))
    return str(path)


def _facts(stdout: str) -> dict:
    """The JSON a scenario printed."""
    return json.loads([ln for ln in stdout.splitlines() if ln.startswith(FACTS)][-1][len(FACTS) :])


def run_scenario(name: str, *args: str) -> dict:
    """Run ``SCENARIOS[name](*args)`` in a fresh interpreter with the fake devices; the facts it printed."""
    proc = subprocess.run(
        [sys.executable, __file__, name, *args],
        cwd=ROOT,
        env=_subprocess_env(FAKE_DEVICES),
        capture_output=True,
        text=True,
        timeout=SUBPROCESS_TIMEOUT_S,
    )
    return _facts(_check(proc))


@dataclasses.dataclass
class Runs:
    """What the module's tests read: the two-device scenario's facts and run dirs, and the two processes'."""

    facts: dict
    run_dir: Path
    process_facts: list[dict]
    process_run_dir: Path

    def __iter__(self):  # facts, run_dir = two_devices
        return iter((self.facts, self.run_dir))


@pytest.fixture(scope="module")
def two_devices(tmp_path_factory):
    """The two-device scenario in one subprocess and, beside it, the same training run in two processes of
    one device each (started first: their deliberate wait overlaps the scenario's compiles)."""
    tmp = tmp_path_factory.mktemp("two_devices")
    config = write_config(tmp / "tiny.yaml", TWO_DEVICE_CONFIG)
    processes = _start_processes(
        [sys.executable, __file__, "process", config, str(tmp / "processes"), str(_free_port())], 2, tmp
    )
    try:
        facts = run_scenario("two_devices", config, str(tmp / "run"))
    finally:
        process_facts = _finish_processes(processes)
    return Runs(facts, tmp / "run", process_facts, tmp / "processes")


def _start_processes(command: list[str], count: int, logs: Path) -> list[tuple[subprocess.Popen, Path]]:
    """Start ``command + [process id]`` ``count`` times at once (one CPU device each), each writing its
    output to files under ``logs`` (pipes read one process at a time could fill up and stall the others)."""
    started = []
    for i in range(count):
        out = logs / f"process_{i}"
        with open(f"{out}.out", "w") as stdout, open(f"{out}.err", "w") as stderr:
            proc = subprocess.Popen(
                command + [str(i)], cwd=ROOT, env=_subprocess_env(None), stdout=stdout, stderr=stderr, text=True
            )
        started.append((proc, out))
    return started


def _finish_processes(started: list[tuple[subprocess.Popen, Path]]) -> list[dict]:
    """The facts of processes started by ``_start_processes`` (every failed one's output on failure)."""
    try:
        for proc, _ in started:
            proc.wait(timeout=SUBPROCESS_TIMEOUT_S)
    finally:
        for proc, _ in started:
            if proc.poll() is None:
                proc.kill()
    outs = [(Path(f"{out}.out").read_text(), Path(f"{out}.err").read_text()) for _, out in started]
    failed = [
        f"process {i}: exit {proc.returncode}\n{out[0][-3000:]}\n{out[1][-3000:]}"
        for i, ((proc, _), out) in enumerate(zip(started, outs))
        if proc.returncode != 0
    ]
    assert not failed, "\n\n".join(failed)  # every failed process's output: the first to fail may be another
    return [_facts(out[0]) for out in outs]


def _records(run_dir: Path) -> list[dict]:
    """The run's metrics records."""
    from train.logger import read_jsonl

    return read_jsonl(run_dir / "metrics.jsonl")


def test_two_devices_train_resume_and_write_each_checkpoint_once(two_devices):
    from train import checkpoint

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
    from train import checkpoint

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
    from train import checkpoint

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
    from train.logger import read_jsonl

    assert two_devices.facts["rc_warp"] == 0
    run_dir = two_devices.run_dir.parent / "run_warp"
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["physics_backend"] == "warp" and summary["env_steps"] == 80
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
    from train import checkpoint

    facts, run_dir = two_devices.process_facts, two_devices.process_run_dir
    assert [f["rc"] for f in facts] == [0, 0]
    assert facts[0]["saved"] == [80, 160] and facts[1]["saved"] == []  # process 0 alone writes
    assert [p.name for p in checkpoint.list_checkpoints(run_dir)] == ["step_000000000080", "step_000000000160"]
    records = _records(run_dir)
    assert [r["step"] for r in records] == [80, 160]
    # The same global env and epoch keys, the same reductions: what one process with two devices logged.
    for mine, theirs in zip(records, _records(two_devices.run_dir)):
        assert set(mine) == set(theirs)
        for key in (k for k in COMPARED_METRICS if k in theirs):
            assert mine[key] == pytest.approx(theirs[key], rel=1e-4, abs=1e-6), (mine["step"], key)
    assert "episode/return" in records[-1]  # compared, not skipped


def test_two_device_checkpoint_resumes_and_evaluates_on_one_device(two_devices):
    from train import checkpoint
    from train.evaluate import main as evaluate

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
            ]
        )
        == 0
    )
    table = json.loads((run_dir / "eval" / "terrain_eval.json").read_text())
    assert [(r["type"], r["difficulty"], r["episodes"]) for r in table["rows"]] == [
        (t, d, 2) for t in ("flat", "stairs") for d in (0.0, 0.5, 1.0)
    ]
    assert all(0.0 <= r["success_rate"] <= 1.0 and np.isfinite(r["mean_progress_m"]) for r in table["rows"])
    assert all((r["success_speed_m_s"] is None) == (r["success_rate"] == 0.0) for r in table["rows"])
    assert (run_dir / "eval" / "terrain_eval.png").stat().st_size > 5_000
    # evaluated on tiles the run's pool was not drawn from, both seeds recorded
    assert table["terrain_seed"] != table["training_terrain_seed"] and "training_seed" in table
    assert table["tiles_per_cell"] == 2


if __name__ == "__main__":
    faulthandler.enable(all_threads=True)  # a process aborted by JAX's coordinator shows where it was
    sys.path.insert(0, str(ROOT))  # benchmarks/ (not an installed package) for the scaling rows
    result = SCENARIOS[sys.argv[1]](*sys.argv[2:])
    print(FACTS + json.dumps(result), flush=True)
