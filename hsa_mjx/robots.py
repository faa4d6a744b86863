"""Robot profiles: what a builder chooses, by name (``env.robot: NAME``).

A profile is a YAML file (shipped in the package's ``robots/`` folder, or any path) that names the
robot's hardware and sets every env key that hardware decides (``ROBOT_KEYS``): the servo model and its
figures (``env.servo``), the control rate and the target rate the servo can follow (``control``), the
servos' range, what each observation's sensor adds (``observation.noise`` of the hinge readings) and
the latency from command to servo (``randomization.latency_steps``). Keys it leaves out take the
original's values, so that switching profiles leaves nothing of the last one behind. Every figure's
source is in the file (``sources``): the maker's sheet, or how an estimate was made.

How the layers combine (``hsa_mjx.config.from_dict``): the defaults, then the profile the ``robot`` key
names, then every key given beside it (a YAML file's own keys, ``make_env`` keywords, ``--set``): a key
given explicitly wins over the profile.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from hsa_mjx.config_schema import build_section
from hsa_mjx.resources import data_dir, read_yaml
from hsa_mjx.servo_config import MIXED, ServoConfig, ServoParams, resolve_servo, validate

DEFAULT = "original"  # the original's spring servos: the defaults themselves
SECTIONS = ("description", "hardware", "sources", "identification", "env")  # identification: a fit's report
# the env keys a profile may set: whole sections, or (section, key) pairs
ROBOT_KEYS: dict[str, tuple[str, ...] | None] = {
    "servo": None,  # every key
    "control": ("frame_skip", "max_increment", "servo_target_limit"),
    "observation": ("noise",),
    "randomization": ("latency_steps",),
}
NOISE_KEYS = ("hinge_angles", "hinge_velocities")  # the observation noise a robot's sensors decide


@dataclasses.dataclass(frozen=True)
class RobotProfile:
    """A loaded profile: its name, what it is, its parts, each figure's source, its env keys and, for a
    fitted profile, the fit's report (``hsa_mjx.sysid``)."""

    name: str
    description: str
    hardware: dict
    sources: dict
    env: dict
    identification: dict = dataclasses.field(default_factory=dict)


def profile_names() -> list[str]:
    """The shipped profiles' names."""
    return sorted(path.stem for path in data_dir("robots").glob("*.yaml"))


def profile_path(name: str | Path) -> Path:
    """A profile's file: an existing path as given, else a shipped profile by name.

    Raises:
        FileNotFoundError: neither; the message lists the shipped profiles.
    """
    given = Path(name)
    if given.suffix in (".yaml", ".yml") and given.is_file():
        return given
    shipped = data_dir("robots") / f"{given.stem}.yaml"
    if given.parent == Path(".") and shipped.is_file():
        return shipped
    raise FileNotFoundError(f"robot profile not found: {name} (neither a file nor one of {profile_names()})")


def load_profile(name: str | Path) -> RobotProfile:
    """Read and check a profile: its sections, and only robot keys in its ``env`` (ValueError naming the
    key and the valid ones)."""
    path = profile_path(name)
    data = read_yaml(path, "robot profile")
    unknown = sorted(set(data) - set(SECTIONS))
    if unknown:
        raise ValueError(f"robot profile {path}: unknown section(s) {unknown}; valid sections: {list(SECTIONS)}")
    env = dict(data.get("env") or {})
    check_robot_keys(env, f"robot profile {path}")
    return RobotProfile(
        name=str(name) if Path(name).suffix else Path(name).stem,
        description=str(data.get("description", "")),
        hardware=dict(data.get("hardware") or {}),
        sources=dict(data.get("sources") or {}),
        env=env,
        identification=dict(data.get("identification") or {}),
    )


def check_robot_keys(env: Mapping[str, Any], where: str) -> None:
    """ValueError unless ``env`` sets only robot keys (``ROBOT_KEYS``; ``observation.noise``: the hinges')."""
    for section, value in env.items():
        if section not in ROBOT_KEYS:
            raise ValueError(f"{where}: env section {section!r} is not the robot's; valid: {sorted(ROBOT_KEYS)}")
        keys = ROBOT_KEYS[section]
        if keys is None:
            continue
        if not isinstance(value, Mapping):
            raise ValueError(f"{where}: env section {section!r} must be a mapping, got {value!r}")
        extra = sorted(set(value) - set(keys))
        if extra:
            raise ValueError(
                f"{where}: env keys {[f'{section}.{k}' for k in extra]} are not the robot's; valid: {keys}"
            )
    noise = env.get("observation", {}).get("noise", {})
    extra = sorted(set(noise) - set(NOISE_KEYS))
    if extra:
        raise ValueError(f"{where}: observation.noise keys {extra} are not the robot's sensors'; valid: {NOISE_KEYS}")


def robot_env(name: str | Path, defaults: Mapping[str, Any]) -> dict:
    """The env keys of profile ``name``, completed with ``defaults`` (the env config's defaults as a dict)
    for every robot key it leaves out."""
    env = load_profile(name).env
    out: dict = {}
    for section, keys in ROBOT_KEYS.items():
        base = dict(defaults[section])
        if keys is not None:
            base = {key: base[key] for key in keys}
        if section == "observation":
            base["noise"] = {key: defaults["observation"]["noise"][key] for key in NOISE_KEYS}
            base["noise"].update(env.get("observation", {}).get("noise", {}))
        else:
            base.update(env.get(section, {}))
        out[section] = base
    return out


def profile_servo(name: str | Path) -> ServoConfig:
    """The servo section of profile ``name`` (validated)."""
    return build_section(ServoConfig, load_profile(name).env.get("servo", {}), "servo")


def drawn_servos(names: tuple[str, ...]) -> list[ServoParams]:
    """The DC-motor servos of the profiles ``randomization.robots`` draws from (ValueError for a profile
    whose servo is the spring, FileNotFoundError for an unknown one)."""
    servos = []
    for name in names:
        params = resolve_servo(validate(profile_servo(name)))
        if params is None:
            raise ValueError(
                f"config key 'randomization.robots': profile {name!r} has spring servos; robots drawn per env "
                "need DC-motor servos (servo.model position or continuous)"
            )
        servos.append(params)
    return servos


def env_motors(own: ServoConfig, robots: tuple[str, ...]) -> ServoParams | None:
    """The DC-motor servos an env drives (None: the springs): its own, with the model ``MIXED`` where the
    robots it draws (``randomization.robots``) and its own do not all share one servo model."""
    params = resolve_servo(own)
    if params is None:
        return None
    models = {p.model for p in drawn_servos(robots)} | {params.model}
    return params if len(models) == 1 else dataclasses.replace(params, model=MIXED)
