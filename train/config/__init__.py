"""Training configuration: the env, the curricula, PPO hyperparameters and the run, from one YAML file.

A training YAML has seven sections, each optional (missing keys take the dataclass defaults below,
the only defaults there are)::

    env: {...}                 # an hsa_mjx env config: `preset: NAME` (default flat_radial) plus keys over it
    goal_curriculum: {...}     # hsa_mjx.curricula.goal_curriculum.GoalCurriculumConfig (goal distances)
    terrain_curriculum: {...}  # hsa_mjx.curricula.terrain_curriculum.TerrainCurriculumConfig (terrain levels)
    randomization_curriculum: {...}  # hsa_mjx.curricula.randomization_curriculum (randomisation ranges)
    ppo: {...}                 # PPOConfig
    td3: {...}                 # train.config.td3.TD3Config (run.learner: td3)
    run: {...}                 # RunConfig

Older keys (``curriculum:``, ``curriculum.initial_range``, ``run.multi_device``) are mapped by
``hsa_mjx.migrations``. Unknown keys, wrong types and incompatible values raise ``ValueError``
naming the key when the config is built, before any compilation; a built ``TrainConfig`` is valid
(``__post_init__``), so nothing checks it again. ``--set section.key=value`` overrides use the same checks.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import hsa_mjx.config
from hsa_mjx import migrations, resources
from hsa_mjx.config import EnvConfig
from hsa_mjx.config_schema import build_section, plain
from hsa_mjx.curricula import goal_curriculum, randomization_curriculum, terrain_curriculum
from hsa_mjx.deploy.policy_file import ACTIVATIONS
from hsa_mjx.terrain.params import RANDOM_TYPES

from . import td3 as td3_config
from .overrides import SECTIONS, apply_overrides, assignments, parse_assignment  # noqa: F401  (the config's API)
from .td3 import TD3Config

CPU_CONFIG = "configs/train_quickstart_cpu.yaml"  # python -m train on a CPU: the quickstart
GPU_CONFIG = "configs/train_flat.yaml"  # and on a GPU: the flat task from scratch

DISTRIBUTIONS = ("tanh_normal", "normal")
VALUE_TARGETS = ("per_iteration", "per_minibatch")  # ppo.value_targets (train.learners.ppo.update)
LR_SCHEDULES = ("fixed", "adaptive_kl")  # ppo.learning_rate_schedule
NOISE_STD_TYPES = ("scalar", "log")
LEARNERS = ("ppo", "td3")  # run.learner: the section whose hyperparameters train (train.learners.registry)
DEFAULT_ENV_PRESET = "flat_radial"
COLLECTIONS = ("auto", "one_device", "pmap", "thread_per_device")  # run.collection (train.devices.strategies)


@dataclasses.dataclass(frozen=True)
class PPOConfig:
    """PPO hyperparameters (Brax names) and network sizes."""

    learning_rate: float = 3e-4
    entropy_cost: float = 1e-3
    discounting: float = 0.99
    gae_lambda: float = 0.95
    clipping_epsilon: float = 0.2
    unroll_length: int = 20
    batch_size: int = 256  # unrolls per minibatch
    num_minibatches: int = 8
    num_updates_per_batch: int = 4
    reward_scaling: float = 1.0
    normalize_observations: bool = True
    # normalised observations are clipped to +-observation_clip, as the original's VecNormalize
    # (clip_obs 10): a dimension that barely varied when the statistics were last updated (every env
    # starts in the same pose) otherwise reaches the networks as thousands of standard deviations. 0 (the
    # default) = no clip: at 5, with the floor below at 0.01, the flat task did not train better (91 against
    # 95 % of goals at equal steps, two seeds each; docs/experiments.md); the shipped policies train without.
    observation_clip: float = 0.0
    # the running statistics' standard deviation never goes below this (Brax's 1e-6 is the default: a
    # dimension constant over the first collection, e.g. the heading of envs that all start facing +x, then
    # normalises its first changes to 1e4 standard deviations and more)
    observation_std_min: float = 1e-6
    normalize_advantage: bool = True
    max_grad_norm: float = 1.0
    vf_loss_coefficient: float = 0.5
    # when the value targets and advantages are computed (train.learners.ppo.update): "per_minibatch" at every
    # minibatch from the critic being trained (Brax's PPO, the default: its values chase their own bootstrap,
    # the first value losses of 1e8-1e10), or "per_iteration" once per collection from the critic that
    # collected it (rsl_rl, CleanRL, SB3: first value loss 0.2-0.4). On the flat task the held targets did
    # not train a better policy at equal steps (95 against 98 % of goals, two seeds each; docs/experiments.md)
    value_targets: str = "per_minibatch"
    # > 0: the clipped value loss of rsl_rl (the value moves at most this far from the rollout's); 0 = off
    value_clip: float = 0.0
    # "fixed", or "adaptive_kl": after each minibatch the rate is divided by 1.5 when the KL divergence
    # from the collecting policy exceeds 2 x desired_kl, multiplied by 1.5 below half of it (rsl_rl)
    learning_rate_schedule: str = "fixed"
    desired_kl: float = 0.01
    policy_hidden_sizes: tuple[int, ...] = (128, 128, 128)
    value_hidden_sizes: tuple[int, ...] = (256, 256, 256)
    activation: str = "swish"
    init_noise_std: float = 1.0
    # "tanh_normal" (Brax's default: squashed into [-1, 1]) or "normal" (unsquashed; the env clips
    # actions to [-1, 1], as the original's SB3 policy was clipped); the std is a learned scalar per
    # action dim, "scalar" (softplus) or "log" (exp, as SB3's log_std)
    distribution_type: str = "tanh_normal"
    noise_std_type: str = "scalar"
    # true: the value network also reads the privileged inputs (hsa_mjx.task.privileged: the noise-free
    # height scan, true block velocities, foot forces, terrain type and level) after the observation;
    # the policy, and every exported policy, reads the observation alone
    privileged_critic: bool = False

    @property
    def applied_observation_clip(self) -> float:
        """The clip the networks apply to their inputs: ``observation_clip``, 0 (none) without normalisation."""
        return self.observation_clip if self.normalize_observations else 0.0


@dataclasses.dataclass(frozen=True)
class RunConfig:
    """Run length, batch, seed and the cadence of logs and checkpoints."""

    num_timesteps: int = 1_000_000
    num_envs: int = 1024
    seed: int = 0
    epochs_per_log: int = 1  # training epochs between host logs
    steps_per_epoch: int = 0  # env steps per jitted epoch; 0 = one PPO iteration per epoch
    checkpoint_every: int = 1_000_000  # env steps between checkpoints
    # also a checkpoint once this many seconds of training have passed since the last (0: off): checkpoints
    # at a steady clock, whose evaluations give the time to a target (each records training_walltime_s)
    checkpoint_every_s: float = 0.0
    keep_checkpoints: int = 3
    num_devices: int = 0  # local devices to use; 0 = all
    # how the devices share an epoch (train.devices.strategies): "one_device", "pmap" (one pmapped
    # epoch), "thread_per_device" (one env collection per GPU, pmapped update), "auto" (one_device on
    # one device, thread_per_device on 2+ GPUs, pmap otherwise)
    collection: str = "auto"
    # a run dir or checkpoint dir whose policy, value network and observation statistics start this
    # run (fine-tuning; a fresh optimiser, curriculum and step count); ignored by --resume
    init_from: str = ""
    # with init_from: restart the observation statistics' sample count at this many samples (mean and
    # std kept), so they follow the new task's observations within about as many env steps instead of
    # being anchored by the source's tens of millions; 0 keeps the source's count
    init_normalizer_count: int = 0
    # PPO iterations between re-draws of the random terrain types' tiles on the device (fresh terrain, no
    # pool to memorise: hsa_mjx.terrain.regeneration); 0 keeps the pool drawn from env.terrain.seed
    regenerate_terrain_every: int = 0
    # true: each env's first episode starts a random number of steps old (0..max_episode_steps), so that the
    # batch's episodes end spread over time instead of all at once (legged_gym's random episode phase)
    random_initial_phase: bool = False
    # > 0: stop (with a checkpoint) once the training clock of every call so far reaches this many seconds:
    # runs compared at equal wall-clock (a sweep's budget_s); summary.json says stopped_by max_training_s
    max_training_s: float = 0.0
    learner: str = "ppo"  # "ppo" (on-policy, the default) or "td3" (FastTD3: replay buffer, distributional critics)


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """Everything one training run needs."""

    env: EnvConfig = dataclasses.field(default_factory=lambda: hsa_mjx.config.get_preset(DEFAULT_ENV_PRESET))
    goal_curriculum: goal_curriculum.GoalCurriculumConfig = goal_curriculum.GoalCurriculumConfig()
    terrain_curriculum: terrain_curriculum.TerrainCurriculumConfig = terrain_curriculum.TerrainCurriculumConfig()
    randomization_curriculum: randomization_curriculum.RandomizationCurriculumConfig = (
        randomization_curriculum.RandomizationCurriculumConfig()
    )
    ppo: PPOConfig = PPOConfig()
    td3: TD3Config = TD3Config()
    run: RunConfig = RunConfig()

    def __post_init__(self) -> None:
        validate(self)  # every config is valid from the moment it is built: no later check repeats it

    @property
    def env_steps_per_iteration(self) -> int:
        """Env steps collected by one iteration (all devices): PPO's collection, or one step of every env (TD3)."""
        if self.run.learner == "td3":
            return self.run.num_envs
        return self.ppo.batch_size * self.ppo.num_minibatches * self.ppo.unroll_length

    @property
    def privileged_critic(self) -> bool:
        """Whether the learner's critic reads the privileged inputs (its section's ``privileged_critic``)."""
        return getattr(self, self.run.learner).privileged_critic


def _env_from(data: Any) -> EnvConfig:
    """Env section: keys over ``preset: NAME`` (default ``flat_radial``: curriculum goals)."""
    if data is None:
        return hsa_mjx.config.PRESETS[DEFAULT_ENV_PRESET]
    if not isinstance(data, Mapping):
        raise ValueError(f"config section 'env' must be a mapping, got {data!r}")
    data = dict(data)
    base = hsa_mjx.config.get_preset(data.pop("preset", DEFAULT_ENV_PRESET))
    return hsa_mjx.config.from_dict(data, base=base)


def from_dict(data: Mapping[str, Any] | None) -> TrainConfig:
    """Build (and so validate) a TrainConfig from nested mappings, older keys mapped first."""
    data = migrations.training_keys(dict(data or {}))
    unknown = sorted(set(data) - set(SECTIONS))
    if unknown:
        raise ValueError(f"unknown config section(s) {unknown}; valid sections: {list(SECTIONS)}")
    return TrainConfig(
        env=_env_from(data.get("env")),
        goal_curriculum=build_section(
            goal_curriculum.GoalCurriculumConfig, data.get("goal_curriculum") or {}, "goal_curriculum"
        ),
        terrain_curriculum=build_section(
            terrain_curriculum.TerrainCurriculumConfig, data.get("terrain_curriculum") or {}, "terrain_curriculum"
        ),
        randomization_curriculum=build_section(
            randomization_curriculum.RandomizationCurriculumConfig,
            data.get("randomization_curriculum") or {},
            "randomization_curriculum",
        ),
        ppo=build_section(PPOConfig, data.get("ppo") or {}, "ppo"),
        td3=build_section(TD3Config, data.get("td3") or {}, "td3"),
        run=build_section(RunConfig, data.get("run") or {}, "run"),
    )


def validate(config: TrainConfig) -> TrainConfig:
    """Check the config's internal consistency (``TrainConfig`` runs it when built); return it or raise ValueError."""
    _validate_curricula(config)
    _validate_ppo(config.ppo)
    td3_config.validate(config.td3)
    _validate_run(config.run)
    _validate_ranges(config)
    ppo, run = config.ppo, config.run
    if run.learner == "ppo" and (ppo.batch_size * ppo.num_minibatches) % run.num_envs:
        raise ValueError(
            f"ppo.batch_size x ppo.num_minibatches = {ppo.batch_size * ppo.num_minibatches} must be "
            f"a multiple of run.num_envs = {run.num_envs} (each env contributes whole unrolls)"
        )
    td3, rows = config.td3, config.td3.buffer_size // run.num_envs
    if run.learner == "td3" and rows < td3.learning_starts:
        raise ValueError(
            f"td3.buffer_size = {td3.buffer_size} holds {rows} steps of each of run.num_envs = {run.num_envs}, "
            f"fewer than td3.learning_starts = {td3.learning_starts}: it would never learn; raise td3.buffer_size"
        )
    _validate_regeneration(config)
    if run.steps_per_epoch and run.steps_per_epoch % config.env_steps_per_iteration:
        raise ValueError(
            f"run.steps_per_epoch = {run.steps_per_epoch} must be a multiple of the env steps per "
            f"{run.learner} iteration ({config.env_steps_per_iteration})"
        )
    return config


def _validate_regeneration(config: TrainConfig) -> None:
    """``run.regenerate_terrain_every``: >= 0; re-drawing needs per-env terrain with a random type."""
    every, env = config.run.regenerate_terrain_every, config.env
    if isinstance(every, bool) or every < 0:
        raise ValueError(f"config key 'run.regenerate_terrain_every' must be an integer >= 0, got {every!r}")
    random = [t for t in env.terrain.types if t in RANDOM_TYPES]
    if every and not (env.scene == "terrain" and env.terrain.per_env and random):
        raise ValueError(
            "config key 'run.regenerate_terrain_every' > 0 needs per-env terrain (env.scene 'terrain', "
            f"env.terrain.per_env true) with a random type among {list(RANDOM_TYPES)}; got scene "
            f"{env.scene!r}, types {list(env.terrain.types)}"
        )
    if every and env.terrain.tiles_per_type < 2:
        raise ValueError(
            "config key 'run.regenerate_terrain_every' > 0 needs env.terrain.tiles_per_type >= 2 (a cell's tiles are "
            f"re-drawn in two halves, so none changes under a running episode), got {env.terrain.tiles_per_type}"
        )


def _validate_curricula(config: TrainConfig) -> None:
    """The curricula's settings, and how they fit the env (radial goals, per-env terrain, randomisation)."""
    env = config.env
    randomization_curriculum.validate(config.randomization_curriculum, env.randomization.draws)
    if config.goal_curriculum.enabled:  # off, goals come from env.goal.radial_range as it is
        goal_curriculum.validate(config.goal_curriculum, tuple(env.goal.radial_range))
    per_env = env.scene == "terrain" and env.terrain.per_env
    terrain_curriculum.validate(config.terrain_curriculum, env.terrain, per_env, env.goal.mode)
    if config.goal_curriculum.enabled and env.goal.mode != "radial":
        raise ValueError(
            "goal_curriculum.enabled needs env goal.mode 'radial' (goals drawn from the curriculum's range), got "
            f"{env.goal.mode!r}; set goal_curriculum.enabled: false or env.goal.mode: radial"
        )


def _validate_ppo(ppo: PPOConfig) -> None:
    """Choices and counts of the ppo section."""
    for key, choices in (
        ("activation", ACTIVATIONS),
        ("distribution_type", DISTRIBUTIONS),
        ("noise_std_type", NOISE_STD_TYPES),
        ("value_targets", VALUE_TARGETS),
        ("learning_rate_schedule", LR_SCHEDULES),
    ):
        if getattr(ppo, key) not in choices:
            raise ValueError(f"config key 'ppo.{key}' = {getattr(ppo, key)!r}; choose one of {list(choices)}")
    if ppo.observation_clip < 0:
        raise ValueError(f"config key 'ppo.observation_clip' must be >= 0 (0: no clip), got {ppo.observation_clip}")
    for key in ("unroll_length", "batch_size", "num_minibatches", "num_updates_per_batch"):
        if getattr(ppo, key) < 1:
            raise ValueError(f"config key 'ppo.{key}' must be >= 1, got {getattr(ppo, key)}")


def _validate_run(run: RunConfig) -> None:
    """Choices and counts of the run section."""
    for key in ("num_timesteps", "num_envs", "epochs_per_log", "checkpoint_every", "keep_checkpoints"):
        if getattr(run, key) < 1:
            raise ValueError(f"config key 'run.{key}' must be >= 1, got {getattr(run, key)}")
    if not run.max_training_s >= 0:
        raise ValueError(f"config key 'run.max_training_s' must be >= 0 (0: off), got {run.max_training_s}")
    if run.checkpoint_every_s < 0:
        raise ValueError(f"config key 'run.checkpoint_every_s' must be >= 0 (0: off), got {run.checkpoint_every_s}")
    if run.init_normalizer_count < 0:
        raise ValueError(
            f"config key 'run.init_normalizer_count' must be >= 0 (0: keep the source's), "
            f"got {run.init_normalizer_count}"
        )
    if run.learner not in LEARNERS:
        raise ValueError(f"config key 'run.learner' = {run.learner!r}; choose one of {list(LEARNERS)}")
    if run.collection not in COLLECTIONS:
        raise ValueError(f"config key 'run.collection' = {run.collection!r}; choose one of {list(COLLECTIONS)}")
    if run.collection == "thread_per_device" and run.learner != "ppo":
        raise ValueError(f"run.collection thread_per_device trains PPO only; run.learner {run.learner!r} runs on pmap")


# (section, key): (lowest, highest, whether the ends are allowed), checked before anything compiles
RANGES = {
    ("ppo", "learning_rate"): (0.0, float("inf"), (True, False)),  # 0 freezes the networks (a warm-start check)
    ("ppo", "entropy_cost"): (0.0, float("inf"), (True, False)),
    ("ppo", "discounting"): (0.0, 1.0, (False, True)),
    ("ppo", "gae_lambda"): (0.0, 1.0, (True, True)),
    ("ppo", "clipping_epsilon"): (0.0, float("inf"), (False, False)),
    ("ppo", "reward_scaling"): (0.0, float("inf"), (False, False)),
    ("ppo", "max_grad_norm"): (0.0, float("inf"), (False, False)),
    ("ppo", "vf_loss_coefficient"): (0.0, float("inf"), (False, False)),
    ("ppo", "init_noise_std"): (0.0, float("inf"), (False, False)),
    ("ppo", "observation_std_min"): (0.0, float("inf"), (False, False)),
    ("ppo", "value_clip"): (0.0, float("inf"), (True, False)),
    ("ppo", "desired_kl"): (0.0, float("inf"), (False, False)),
    ("run", "seed"): (0, 2**32 - 1, (True, True)),
}


def _validate_ranges(config: TrainConfig) -> None:
    """Every number with a valid range inside it (finite), or ValueError naming key, value and range."""
    for (section, key), (lo, hi, (lo_in, hi_in)) in RANGES.items():
        value = getattr(getattr(config, section), key)
        ok = (value >= lo if lo_in else value > lo) and (value <= hi if hi_in else value < hi)
        if not ok or value != value:  # NaN fails every comparison
            span = f"{'[' if lo_in else '('}{lo}, {hi}{']' if hi_in else ')'}"
            raise ValueError(f"config key '{section}.{key}' = {value!r} is out of range; it must lie in {span}")


def validate_devices(config: TrainConfig, devices: int) -> TrainConfig:
    """The run's split over ``devices`` (every process's): num_envs and minibatches must divide evenly,
    and ``run.collection: one_device`` needs one. Checked before anything compiles; ValueError."""
    if config.run.collection == "one_device" and devices != 1:
        raise ValueError(f"run.collection one_device runs on one device, but {devices} are in use (run.num_devices)")
    if config.run.num_envs % devices:
        raise ValueError(f"run.num_envs = {config.run.num_envs} must be divisible by the {devices} devices in use")
    section = config.run.learner
    if getattr(config, section).batch_size % devices:
        batch = getattr(config, section).batch_size
        raise ValueError(f"{section}.batch_size = {batch} must be divisible by the {devices} devices in use")
    return config


def read_yaml(path: str | Path) -> dict:
    """A training YAML file (or a shipped config's name) as nested dicts, merged over its ``base:``."""
    return resources.read_yaml(path, "training config")


def default_config() -> str:
    """The config a run without ``--config`` trains: the full-size GPU one when JAX sees a GPU, else the
    CPU quickstart."""
    import jax  # the backend, not at import: reading a config needs no device

    return GPU_CONFIG if jax.default_backend() == "gpu" else CPU_CONFIG


def load(path: str | Path, overrides: list[str] | None = None) -> TrainConfig:
    """Load a training config file and apply ``--set`` overrides (over the file's keys, older ones mapped)."""
    return from_dict(apply_overrides(read_yaml(path), overrides or []))


def to_dict(config: TrainConfig) -> dict:
    """Plain nested dicts (YAML/JSON-ready); ``from_dict(to_dict(c)) == c``."""
    return plain(config)
