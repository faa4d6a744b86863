"""The ``td3`` section of a training config (``train.config``): FastTD3's hyperparameters (arXiv
2505.22642) for thousands of envs on the device: a replay buffer per device, a distributional (C51)
clipped double-Q critic, n-step returns, exploration noise drawn per env, several updates per env step."""

from __future__ import annotations

import dataclasses

from hsa_mjx.deploy.policy_file import ACTIVATIONS


@dataclasses.dataclass(frozen=True)
class TD3Config:
    """TD3 hyperparameters and network sizes (``run.learner: td3``)."""

    actor_learning_rate: float = 3e-4
    critic_learning_rate: float = 3e-4
    weight_decay: float = 0.1  # AdamW's, both networks
    max_grad_norm: float = 0.0  # 0: no clipping
    discounting: float = 0.99
    n_step: int = 3  # the critic's targets: n rewards, then the target critic (an episode's end cuts them short)
    tau: float = 0.1  # the target networks' Polyak step after every critic update
    # transitions the replay buffer holds over all of a device's envs (a ring per env; refilled on resume)
    buffer_size: int = 1_048_576
    batch_size: int = 32_768  # transitions per gradient update (each device's share of it: over devices)
    updates_per_step: int = 2  # critic updates per env step of every env
    policy_frequency: int = 2  # critic updates per actor update (TD3's delay)
    learning_starts: int = 10  # env steps of every env before the first update
    # exploration: each env's noise scale drawn from [noise_std_min, noise_std_max] at each episode's start
    noise_std_min: float = 0.001
    noise_std_max: float = 0.4
    target_noise: float = 0.2  # target policy smoothing: Gaussian noise on the target action, clipped
    target_noise_clip: float = 0.5
    num_atoms: int = 101  # the critic's distribution: atoms evenly spaced over [v_min, v_max]
    v_min: float = -250.0
    v_max: float = 250.0
    actor_hidden_sizes: tuple[int, ...] = (512, 256, 128)
    critic_hidden_sizes: tuple[int, ...] = (1024, 512, 256)
    activation: str = "relu"
    normalize_observations: bool = True
    observation_std_min: float = 1e-6
    # true: the critics also read the privileged inputs after the observation (the actor, and every
    # exported policy, reads the observation alone)
    privileged_critic: bool = False


POSITIVE = (  # keys that must be > 0
    "actor_learning_rate",
    "critic_learning_rate",
    "tau",
    "noise_std_max",
)
COUNTS = ("n_step", "buffer_size", "batch_size", "updates_per_step", "policy_frequency", "num_atoms")


def validate(td3: TD3Config) -> None:
    """The section's ranges and choices; ValueError naming the key and what it must be."""

    def bad(key: str, must: str) -> ValueError:
        return ValueError(f"config key 'td3.{key}' = {getattr(td3, key)!r}; it must be {must}")

    if td3.activation not in ACTIVATIONS:
        raise bad("activation", f"one of {list(ACTIVATIONS)}")
    for key in POSITIVE:
        if not getattr(td3, key) > 0:
            raise bad(key, "> 0")
    for key in ("weight_decay", "max_grad_norm", "noise_std_min", "target_noise", "target_noise_clip"):
        if not getattr(td3, key) >= 0:
            raise bad(key, ">= 0")
    for key in COUNTS:
        if isinstance(getattr(td3, key), bool) or getattr(td3, key) < 1:
            raise bad(key, "an integer >= 1")
    if td3.num_atoms < 2:
        raise bad("num_atoms", ">= 2")
    if not 0.0 < td3.discounting <= 1.0:
        raise bad("discounting", "in (0, 1]")
    if not td3.tau <= 1.0:
        raise bad("tau", "in (0, 1]")
    if td3.learning_starts < td3.n_step:
        raise bad("learning_starts", f">= td3.n_step ({td3.n_step}): an update needs n steps of every env")
    if not td3.v_min < td3.v_max:
        raise bad("v_min", f"below td3.v_max ({td3.v_max})")
    if td3.noise_std_min > td3.noise_std_max:
        raise bad("noise_std_min", f"<= td3.noise_std_max ({td3.noise_std_max})")
    if td3.observation_std_min <= 0:
        raise bad("observation_std_min", "> 0")
