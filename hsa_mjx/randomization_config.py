"""Config of the sim-to-real options: per-env physical randomisation, action latency, pushes, sensor noise.

Everything here is off by default (the nominal model, exact observations, actions applied at once)
and lives in two sections: ``randomization`` (what differs per env and episode: physical scales,
latency, pushes) and ``observation.noise`` (per observation group). ``hsa_mjx.task.randomization``
draws and applies them; ``docs/robustness.md`` says which model fields each one changes.
"""

from __future__ import annotations

import dataclasses

# Scale ranges (min, max) of nominal model values; [1, 1] leaves a field as the asset has it.
SCALE_KEYS = ("friction", "block_mass", "hsa_stiffness", "hsa_damping", "servo_gain")
FOOT_KEYS = ("foot_friction", "foot_anisotropy")  # scale ranges drawn per foot
NOMINAL = (1.0, 1.0)
NO_LIMIT = (0.0, 0.0)
NOISE_GROUPS = ("hinge_angles", "hinge_velocities", "position", "velocity", "goal", "heading")


@dataclasses.dataclass(frozen=True)
class RandomizationConfig:
    """``randomization``: each env draws its own values at every reset, uniformly in each range."""

    friction: tuple[float, float] = NOMINAL  # every contact's sliding friction (foot pairs and geoms)
    block_mass: tuple[float, float] = NOMINAL  # each block's mass and inertia (one draw per block)
    hsa_stiffness: tuple[float, float] = NOMINAL  # the HSA units' tendon springs' stiffness
    hsa_damping: tuple[float, float] = NOMINAL  # the tendon springs' damping
    servo_gain: tuple[float, float] = NOMINAL  # the position servos' kp (their damping kv stays)
    servo_force_limit: tuple[float, float] = NO_LIMIT  # N m, |servo torque| limit; [0, 0]: none (the asset's)
    # each foot's own draw (four per env): both sliding coefficients of its floor contact, and its
    # lower one alone (across the robot on a plane: the anisotropy the crawl relies on)
    foot_friction: tuple[float, float] = NOMINAL
    foot_anisotropy: tuple[float, float] = NOMINAL
    # robot profiles (hsa_mjx.robots) whose servos each env drives as one of them, drawn per episode (their
    # DC-motor servo figures and model; the control, sensors and latency stay the env's own robot's)
    robots: tuple[str, ...] = ()
    # how often each of ``robots`` is drawn, relative to the others (one weight each); []: all alike.
    # [0, 1, 0] plays the second profile alone with the observation a policy over all three trained on
    robot_weights: tuple[float, ...] = ()
    # DC-motor servos: scales of the stall torque, no-load speed, damping, friction and rotor inertia,
    # each drawn on its own (the same for the eight servos of an env)
    servo_figures: tuple[float, float] = NOMINAL
    latency_steps: tuple[int, int] = (0, 0)  # control steps before an action reaches the servos
    push_interval_s: tuple[float, float] = (0.0, 0.0)  # s between pushes; [0, 0]: no pushes
    push_speed: float = 0.0  # m/s, the largest horizontal speed one push adds to both blocks

    @property
    def physical(self) -> bool:
        """Whether any model field is randomised (scales off [1, 1], a torque limit or a drawn robot)."""
        scaled = any(getattr(self, name) != NOMINAL for name in SCALE_KEYS + FOOT_KEYS)
        return scaled or self.limits_force or bool(self.robots) or self.servo_figures != NOMINAL

    @property
    def per_foot(self) -> bool:
        """Whether each foot draws its own friction or anisotropy."""
        return any(getattr(self, name) != NOMINAL for name in FOOT_KEYS)

    @property
    def limits_force(self) -> bool:
        """Whether the servos get a torque limit (the model is then compiled force-limited)."""
        return self.servo_force_limit != NO_LIMIT

    @property
    def pushes(self) -> bool:
        """Whether envs are pushed at intervals."""
        return self.push_speed > 0 and self.push_interval_s[1] > 0

    @property
    def draws(self) -> bool:
        """Whether a reset draws anything (physical scales, a latency or push times)."""
        return self.physical or self.max_latency > 0 or self.pushes

    @property
    def max_latency(self) -> int:
        """The longest action delay in control steps (the action queue's length - 1)."""
        return self.latency_steps[1]


@dataclasses.dataclass(frozen=True)
class ObservationNoiseConfig:
    """``observation.noise``: uniform noise of +-value on each group's entries of the policy's observation."""

    hinge_angles: float = 0.0  # rad (hinge_angles: sincos: on the sines and cosines)
    hinge_velocities: float = 0.0  # rad/s
    position: float = 0.0  # m, the robot's x, y
    velocity: float = 0.0  # m/s, the blocks' mean velocity
    goal: float = 0.0  # the goal distance (m) and direction entries
    heading: float = 0.0  # the heading entries (cos, sin and the goal direction in the heading frame)

    @property
    def enabled(self) -> bool:
        """Whether any group is noisy."""
        return any(getattr(self, name) > 0 for name in NOISE_GROUPS)


def _check_range(key: str, lo: float, hi: float, low_bound: float, strictly: bool) -> None:
    """``lo <= hi`` and ``lo`` above the bound, or ValueError naming the key."""
    above = lo > low_bound if strictly else lo >= low_bound
    if not (above and lo <= hi):
        bound = f"{low_bound} < min" if strictly else f"{low_bound} <= min"
        raise ValueError(f"config key '{key}' must be a range [min, max] with {bound} <= max, got {[lo, hi]}")


def validate(config: RandomizationConfig, noise: ObservationNoiseConfig) -> None:
    """Raise ValueError naming the key and its valid range."""
    for name in SCALE_KEYS + FOOT_KEYS + ("servo_figures",):
        _check_range(f"randomization.{name}", *getattr(config, name), 0.0, strictly=True)
    lo, hi = config.servo_force_limit
    if config.limits_force:
        _check_range("randomization.servo_force_limit", lo, hi, 0.0, strictly=True)
    _check_range("randomization.latency_steps", *config.latency_steps, 0, strictly=False)
    _check_range("randomization.push_interval_s", *config.push_interval_s, 0.0, strictly=False)
    if config.push_speed < 0:
        raise ValueError(f"config key 'randomization.push_speed' must be >= 0 (m/s), got {config.push_speed!r}")
    if config.push_speed > 0 and config.push_interval_s[0] <= 0:
        raise ValueError(
            "config key 'randomization.push_interval_s' must be > 0 s when push_speed > 0, "
            f"got {list(config.push_interval_s)}"
        )
    _check_robot_weights(config)
    for name in NOISE_GROUPS:
        if getattr(noise, name) < 0:
            raise ValueError(f"config key 'observation.noise.{name}' must be >= 0, got {getattr(noise, name)!r}")


def _check_robot_weights(config: RandomizationConfig) -> None:
    """``randomization.robot_weights``: none, or one weight >= 0 per drawn robot, not all 0."""
    weights = config.robot_weights
    if not weights:
        return
    if len(weights) != len(config.robots) or min(weights) < 0 or sum(weights) <= 0:
        raise ValueError(
            "config key 'randomization.robot_weights' must give one weight >= 0 per profile of "
            f"randomization.robots {list(config.robots)}, not all 0 (or [] for all alike), got {list(weights)}"
        )
