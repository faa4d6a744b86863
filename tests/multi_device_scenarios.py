"""What the multi-device tests run in fresh interpreters: ``python tests/multi_device_scenarios.py
SCENARIO ARGS...`` prints one JSON line of facts (tests/test_multi_device.py asserts on them).

Fake CPU devices (``JAX_NUM_CPU_DEVICES``) exist only when set before JAX starts, hence the fresh
interpreters; compiles go through the persistent cache configured in tests/conftest.py.
"""

from __future__ import annotations

import faulthandler
import json
import os
import signal
import sys
import time
from pathlib import Path

import numpy as np
from test_train_run import TINY

ROOT = Path(__file__).resolve().parents[1]
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
# The run of two processes: the flat tiny config (its programs compile in a fraction of the terrain
# run's time), 8 envs, one 80-step epoch a checkpoint; killed in its second epoch, then resumed and
# stopped by SIGTERM. The scenario trains the same config on two devices of one process to compare.
PROCESSES_CONFIG = {
    **TINY,
    "env": {**TINY["env"], "termination": {"max_episode_steps": 10}},  # every env ends one in the first epoch
    "ppo": {**TINY["ppo"], "batch_size": 8},
    "run": {**TINY["run"], "num_envs": 8, "num_timesteps": 160, "checkpoint_every": 80},
}


def _compile_counter() -> list:
    """A list that gains one entry per XLA compile request from now on (cache hits included)."""
    import jax

    events: list = []
    jax.monitoring.register_event_duration_secs_listener(
        lambda name, secs, **_: events.append(name) if name == "/jax/core/compile/backend_compile_duration" else None
    )
    return events


def _fresh_traces() -> None:
    """Forget this process's traces before a phase whose programs should hit the persistent cache (the
    resumes, and the per-device run whose device-0 collection the one-device resume reuses).

    JAX shares private functions inside one lowered module through caches keyed by in-memory objects,
    so the same epoch traced again later in a process can lower to different (equivalent) text and miss
    the cache; a fresh process, or a cleared one, lowers it as the first did. Cold, on the 2-core
    development machine: the pmap resume 25 instead of 41 s, the module 306 instead of 316 CPU-s."""
    import jax

    jax.clear_caches()


def _record_saves() -> list[int]:
    """Steps of every checkpoint written from now on (train.run.checkpoint.save wrapped)."""
    from train.run import checkpoint

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

    from train.run import checkpoint

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
    from train.devices.replicas import replicate
    from train.learners.ppo.learner import AXIS

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


def scenario_two_devices(config_path: str, run_dir: str, processes_config: str) -> dict:
    """Train through the CLI on two devices of one process, resume, refusals, per-device facts, the
    thread-per-device strategy on the Warp backend, then the two-process run's config on two devices of
    this process (``phase_s``: each part's seconds)."""
    compiles, saved = _compile_counter(), _record_saves()
    clock, phases = time.perf_counter(), {}

    def phase(name: str) -> None:
        nonlocal clock
        phases[name], clock = round(time.perf_counter() - clock, 1), time.perf_counter()

    from train.cli import main
    from train.devices.strategies import Pmap
    from train.devices.thread_per_device import ThreadPerDevice

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
    facts["rc_warp"] = _warp_thread_per_device(config_path, str(Path(run_dir).parent / "run_warp"))
    phase("warp_thread_per_device")
    flat_dir = str(Path(run_dir).parent / "run_flat")
    facts["rc_processes_config"] = main(["--config", processes_config, "--run-dir", flat_dir, "--quiet"])
    phase("processes_config")
    facts["td3"] = _td3_on_two_devices(processes_config, str(Path(run_dir).parent / "run_td3"))
    phase("td3_pmap")
    return {**facts, "phase_s": phases}


def _td3_on_two_devices(config_path: str, run_dir: str) -> dict:
    """The flat tiny config trained by TD3 on the two devices (``auto``: pmap), tiny networks and buffer."""
    from train.cli import main
    from train.run.logger import read_jsonl

    tiny_td3 = ["run.learner=td3", "td3.actor_hidden_sizes=[8]", "td3.critic_hidden_sizes=[8]", "td3.batch_size=8"]
    tiny_td3 += ["td3.buffer_size=32", "td3.num_atoms=11", "td3.learning_starts=3", "run.num_timesteps=80"]
    rc = main(["--config", config_path, "--run-dir", run_dir, "--quiet", *[f"--set={s}" for s in tiny_td3]])
    last = read_jsonl(Path(run_dir) / "metrics.jsonl")[-1] if rc == 0 else {}
    summary = json.loads((Path(run_dir) / "summary.json").read_text()) if rc == 0 else {}
    keys = ("loss/critic_loss", "loss/q_mean", "loss/buffer_size", "loss/skipped_updates")
    return {"rc": rc, "collection": summary.get("collection"), **{k: last.get(k) for k in keys}}


def scenario_process(config_path: str, run_dir: str, port: str, steps: str, action: str, process_id: str) -> dict:
    """One of two processes (one CPU device each) training through the CLI to ``steps`` env steps
    (``--resume`` once the run dir has a checkpoint). ``action``: a comma list of ``late`` (process 1
    reaches the training loop ``PROCESS_1_LATE_S`` late) and ``term@K`` / ``kill@K`` (this process gets
    SIGTERM / SIGKILL as it reaches its K-th logged epoch, before that epoch is logged or checkpointed),
    or ``none``."""
    saved = _record_saves()
    from train import trainer
    from train.cli import main

    loop, record, logged = trainer.run_epochs, trainer._record, []
    actions = action.split(",")
    kind, _, at = next((a for a in actions if "@" in a), "none@0").partition("@")

    def late_loop(*args, **kwargs):  # later than the 30 s a collective's first use waits for the other processes
        time.sleep(PROCESS_1_LATE_S if process_id == "1" else 0)
        return loop(*args, **kwargs)

    def record_after_signal(*args, **kwargs):
        logged.append(None)
        if kind in ("term", "kill") and len(logged) == int(at):
            os.kill(os.getpid(), signal.SIGTERM if kind == "term" else signal.SIGKILL)
        return record(*args, **kwargs)

    trainer.run_epochs = late_loop if "late" in actions else loop
    trainer._record = record_after_signal
    resume = ["--resume"] if (Path(run_dir) / "checkpoints").is_dir() else []
    cluster = ["--coordinator", f"127.0.0.1:{port}", "--num-processes", "2", "--process-id", process_id]
    total = f"--set=run.num_timesteps={steps}"
    rc = main(["--config", config_path, "--run-dir", run_dir, "--quiet", total, *resume, *cluster])
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

if __name__ == "__main__":
    faulthandler.enable(all_threads=True)  # a process aborted by JAX's coordinator shows where it was
    sys.path.insert(0, str(ROOT))  # benchmarks/ (not an installed package) for the scaling rows
    result = SCENARIOS[sys.argv[1]](*sys.argv[2:])
    print(FACTS + json.dumps(result), flush=True)
