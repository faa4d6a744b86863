"""A sweep file (``benchmarks/sweeps/*.yaml``), read and checked before anything runs: unknown keys, a
missing key, an arm whose config does not build, an unknown grid or reference policy are refused with a
ValueError (FileNotFoundError for a missing file) naming them and the valid choices."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import yaml

from benchmarks.robustness import grids
from hsa_mjx.deploy import policy_file
from train import config as train_config

KEYS = ("name", "question", "config", "env_steps", "seeds", "set", "arms", "evaluate", "target_success", "budget_s")
EVALUATE_KEYS = ("episodes", "steps", "goal_range", "seed", "backend", "terrain", "grid", "every_checkpoint")
GRID_KEYS = ("name", "episodes", "reference")
ARM_KEYS = ("config", "set")  # an arm given as a mapping: its own training config, its overrides
TERRAIN_KEYS = ("types", "levels", "tiles", "terrain_seed")


@dataclasses.dataclass(frozen=True)
class Sweep:
    """A sweep file, checked."""

    name: str
    question: str
    config: str
    env_steps: int
    seeds: tuple[int, ...]
    common: tuple[str, ...]
    arms: dict[str, tuple[str, ...]]
    evaluate: dict[str, Any]
    target_success: float = 0.9
    arm_configs: dict[str, str] = dataclasses.field(default_factory=dict)  # arms trained from another config
    budget_s: float = 0.0  # > 0: every run trains this many seconds of its training clock (run.max_training_s)

    def config_of(self, arm: str) -> str:
        """The training config of one arm: its own, or the sweep's."""
        return self.arm_configs.get(arm, self.config)

    def overrides(self, arm: str, seed: int) -> list[str]:
        """The ``--set`` overrides of one run: the common ones, the arm's, its seed and length (and budget)."""
        budget = [f"run.max_training_s={self.budget_s}"] if self.budget_s > 0 else []
        return [*self.common, *self.arms[arm], f"run.seed={seed}", f"run.num_timesteps={self.env_steps}", *budget]


def _unknown(data: dict, valid: tuple[str, ...], where: str) -> None:
    unknown = sorted(set(data) - set(valid))
    if unknown:
        raise ValueError(f"{where}: unknown key(s) {unknown}; valid keys: {list(valid)}")


def _check_grid(grid: Any, where: str) -> None:
    """ValueError (or FileNotFoundError for a reference policy) unless ``grid`` is None or a valid grid."""
    if grid is None:
        return
    if not isinstance(grid, dict):
        raise ValueError(f"{where}: a mapping with keys {list(GRID_KEYS)}, got {grid!r}")
    _unknown(grid, GRID_KEYS, where)
    if grid.get("name") not in grids.GRIDS:
        raise ValueError(f"{where}.name: {grid.get('name')!r}; grids: {sorted(grids.GRIDS)}")
    if int(grid.get("episodes", 1)) < 1:
        raise ValueError(f"{where}.episodes must be >= 1, got {grid['episodes']!r}")
    for policy in grid.get("reference") or ():
        policy_file.locate(policy)


def _arms(data: dict, path: Path) -> tuple[dict[str, tuple[str, ...]], dict[str, str]]:
    """Each arm's overrides, and the config of each arm given as ``{config: PATH, set: [...]}``."""
    arms, configs = {}, {}
    for name, value in data.items():
        if isinstance(value, dict):
            _unknown(value, ARM_KEYS, f"{path}: arm {name!r}")
            if "config" in value:
                configs[str(name)] = str(value["config"])
            value = value.get("set")
        arms[str(name)] = tuple(value or ())
    return arms, configs


def load(path: str | Path) -> Sweep:
    """Read and check a sweep file: every arm's config is built (and so validated) here, before any run."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"sweep file not found: {path}")
    data = yaml.safe_load(path.read_text()) or {}
    _unknown(data, KEYS, str(path))
    missing = [k for k in ("name", "config", "env_steps", "seeds", "arms", "evaluate") if k not in data]
    if missing:
        raise ValueError(f"{path}: missing key(s) {missing}")
    evaluate = dict(data["evaluate"] or {})
    _unknown(evaluate, EVALUATE_KEYS, f"{path}: evaluate")
    _unknown(evaluate.get("terrain") or {}, TERRAIN_KEYS, f"{path}: evaluate.terrain")
    _check_grid(evaluate.get("grid"), f"{path}: evaluate.grid")
    arms, arm_configs = _arms(data["arms"] or {}, path)
    seeds = tuple(int(s) for s in data["seeds"])
    if len(arms) < 1 or len(seeds) < 1 or len(set(seeds)) != len(seeds):
        raise ValueError(f"{path}: need at least one arm and distinct seeds, got arms {list(arms)}, seeds {seeds}")
    sweep = Sweep(
        name=str(data["name"]),
        question=str(data.get("question", "")),
        config=str(data["config"]),
        env_steps=int(data["env_steps"]),
        seeds=seeds,
        common=tuple(data.get("set") or ()),
        arms=arms,
        evaluate=evaluate,
        target_success=float(data.get("target_success", 0.9)),
        arm_configs=arm_configs,
        budget_s=float(data.get("budget_s", 0.0)),
    )
    for arm in arms:
        try:
            train_config.load(sweep.config_of(arm), sweep.overrides(arm, seeds[0]))
        except (ValueError, TypeError) as err:
            raise ValueError(f"{path}: arm {arm!r} does not build: {err}") from err
    return sweep
