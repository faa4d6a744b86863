"""Where the package's files live: robot assets, env presets and training configs, shipped policies,
robot profiles.

A checkout (or an editable install) reads the repository's top-level ``assets/``, ``configs/``,
``policies/`` and ``robots/``. A built wheel or ``pip install .`` carries the same folders as package data under
``hsa_mjx/data/`` (``pyproject.toml`` maps them there at build time), so an installed package finds
them from any working directory.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import yaml

KINDS = ("assets", "configs", "policies", "robots")
SCENE_FILES = {"flat": "scene_flat.xml", "terrain": "scene_terrain.xml"}
_PACKAGE = Path(__file__).resolve().parent


def data_dir(kind: str) -> Path:
    """The folder of one kind of package file: installed package data, else the checkout's folder."""
    if kind not in KINDS:
        raise ValueError(f"unknown kind of package file {kind!r}; valid kinds: {list(KINDS)}")
    packaged = _PACKAGE / "data" / kind
    return packaged if packaged.is_dir() else _PACKAGE.parent / kind


def scene_path(scene: str, asset_dir: Path | None = None) -> Path:
    """Path of the scene XML for ``scene`` ("flat" or "terrain"), checked to exist."""
    if scene not in SCENE_FILES:
        raise ValueError(f"unknown scene {scene!r}; valid scenes: {sorted(SCENE_FILES)}")
    path = Path(asset_dir or data_dir("assets")) / SCENE_FILES[scene]
    if not path.is_file():
        raise FileNotFoundError(
            f"robot asset not found: {path} (the scene XMLs ship with the package, in {data_dir('assets')})"
        )
    return path


def config_path(name: str | Path, what: str = "config") -> Path:
    """A YAML config: an existing path as given, else a file of the shipped configs by name or file name."""
    given = Path(name)
    if given.is_file():
        return given
    shipped = data_dir("configs") / (given.name if given.suffix in (".yaml", ".yml") else f"{given.name}.yaml")
    if given.parent in (Path("."), Path("configs")) and shipped.is_file():
        return shipped
    available = sorted(p.stem for p in data_dir("configs").glob("*.yaml"))
    raise FileNotFoundError(f"{what} not found: {name} (neither a file nor one of the shipped configs {available})")


BASE_KEY = "base"  # a YAML config may name the config it inherits from, e.g. ``base: train_flat.yaml``


def read_yaml(name: str | Path, what: str = "config") -> dict:
    """A YAML config as nested dicts, merged over the config its ``base:`` key names (recursively).

    ``base`` is a path relative to the file, or a shipped config's name. Raises FileNotFoundError for a
    missing file, ValueError for invalid YAML, a file that is not a mapping, or a cycle of bases.
    """
    return _read_with_bases(name, what, ())


def _read_with_bases(name: str | Path, what: str, seen: tuple[Path, ...]) -> dict:
    """``read_yaml`` that remembers the files already on the chain of bases."""
    path = config_path(name, what).resolve()
    if path in seen:
        raise ValueError(f"{what} {path}: its chain of '{BASE_KEY}' keys comes back to itself")
    try:
        data = yaml.safe_load(path.read_text()) or {}
    except yaml.YAMLError as err:
        raise ValueError(f"{what} {path} is not valid YAML: {err}") from err
    if not isinstance(data, Mapping):
        raise ValueError(f"{what} {path} must be a mapping of keys, got {type(data).__name__}")
    data = dict(data)
    base = data.pop(BASE_KEY, None)
    if base is None:
        return data
    near = path.parent / str(base)
    parent = _read_with_bases(near if near.is_file() else str(base), what, seen + (path,))
    return merge(parent, data)


def merge(base: Mapping, over: Mapping) -> dict:
    """``over`` merged into ``base``: nested mappings key by key, any other value replaced."""
    out = dict(base)
    for key, value in over.items():
        out[key] = merge(out[key], value) if isinstance(value, Mapping) and isinstance(out.get(key), Mapping) else value
    return out
