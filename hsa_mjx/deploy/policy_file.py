"""A trained policy as plain arrays: the policy file format, its loader and a numpy forward pass.

A policy directory holds two files (``python -m train.export`` writes them, ``policies/`` ships them):

- ``policy.npz``: float32 arrays only, loaded with ``allow_pickle=False``: ``obs_mean`` and
  ``obs_std`` (the observation normaliser exactly as the policy applies it,
  ``(obs - obs_mean) / obs_std``, then clipped to +-``observation_clip`` when that is > 0), and
  ``dense_<i>_kernel`` (in, out) / ``dense_<i>_bias`` (out,) for each dense layer in order.
- ``policy.json``: the format version, observation size and labels, action size, activation,
  distribution type and how the deterministic action is computed, the observation clip, the layer
  list, the full training config (so the env can be rebuilt) and where the policy came from.

The deterministic action: hidden layers ``x = act(x @ kernel + bias)``, the last layer linear,
then ``tanh`` for a ``tanh_normal`` policy (Brax's mode of the squashed Gaussian) or nothing for a
``normal`` one (its mean; the env clips actions to [-1, 1]). This module needs only numpy (it
imports neither JAX nor Brax), so a robot controller can load and run a policy with it alone.
"""

from __future__ import annotations

import dataclasses
import io
import json
import os
import shutil
import tempfile
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

FORMAT = "hsa_mjx.policy"  # the file format's name (kept when the module moved)
FORMAT_VERSION = 1
WEIGHTS_FILE, META_FILE = "policy.npz", "policy.json"
ACTIVATIONS = ("swish", "tanh", "relu", "elu")
SQUASH = {"tanh_normal": "tanh", "normal": "identity"}  # distribution type -> output transform


def shipped() -> dict[str, Path]:
    """The policies that ship with the package, by name (``policies/`` in a checkout, package data once installed)."""
    from hsa_mjx.resources import data_dir

    return {p.name: p for p in sorted(data_dir("policies").glob("*")) if (p / META_FILE).is_file()}


def find(name_or_dir: str | Path) -> Path | None:
    """The policy directory that ``name_or_dir`` names (a path holding the metadata, or a shipped name), else None."""
    path = Path(name_or_dir)
    return path if (path / META_FILE).is_file() else shipped().get(str(name_or_dir))


def locate(name_or_dir: str | Path) -> Path:
    """Like :func:`find`, but a FileNotFoundError listing the shipped policies when there is none."""
    found = find(name_or_dir)
    if found is None:
        raise FileNotFoundError(
            f"no policy {str(name_or_dir)!r}: not a directory with {META_FILE} and not one of "
            f"the shipped policies {list(shipped())}"
        )
    return found


def activate(x: Any, name: str, xp: Any = np) -> Any:
    """The named activation (``xp``: numpy or jax.numpy), as flax.linen defines it."""
    if name == "swish":
        return x * (0.5 * xp.tanh(0.5 * x) + 0.5)  # x * sigmoid(x), without overflow
    if name == "tanh":
        return xp.tanh(x)
    if name == "relu":
        return xp.maximum(x, 0)
    if name == "elu":
        return xp.where(x > 0, x, xp.expm1(xp.minimum(x, 0)))
    raise ValueError(f"unknown activation {name!r}; choose one of {list(ACTIVATIONS)}")


def forward(params: dict, obs: Any, activation: str, squash: str, observation_clip: float, xp: Any = np) -> Any:
    """The deterministic action for ``obs`` (one observation or a batch) from ``params``
    (``obs_mean``, ``obs_std``, ``kernels``, ``biases``); ``xp``: numpy or jax.numpy."""
    x = (obs - params["obs_mean"]) / params["obs_std"]
    if observation_clip > 0:
        x = xp.clip(x, -observation_clip, observation_clip)
    last = len(params["kernels"]) - 1
    for i, (kernel, bias) in enumerate(zip(params["kernels"], params["biases"])):
        x = x @ kernel + bias
        if i < last:
            x = activate(x, activation, xp)
    return xp.tanh(x) if squash == "tanh" else x


@dataclasses.dataclass(frozen=True)
class NumpyPolicy:
    """A loaded policy: ``policy(obs) -> action`` for one observation (obs,) or a batch (n, obs).

    Attributes:
        params: ``obs_mean``, ``obs_std`` (obs,), ``kernels`` and ``biases`` (tuples, one per layer).
        meta: the policy's ``policy.json`` (config, observation labels, provenance, ...).
    """

    params: dict
    meta: dict

    @property
    def observation_size(self) -> int:
        """Values per observation."""
        return int(self.meta["observation"]["size"])

    @property
    def action_size(self) -> int:
        """Values per action."""
        return int(self.meta["action"]["size"])

    def __call__(self, obs: Any) -> np.ndarray:
        """Deterministic action(s), float32, shape (action,) or (n, action)."""
        obs = np.asarray(obs, dtype=np.float32)
        if obs.shape[-1:] != (self.observation_size,) or obs.ndim > 2:
            raise ValueError(
                f"observation must have shape ({self.observation_size},) or "
                f"(n, {self.observation_size}), got {obs.shape}"
            )
        net = self.meta["network"]
        return forward(self.params, obs, net["activation"], net["output"], float(net["observation_clip"]))


def layer_names(count: int) -> list[tuple[str, str]]:
    """The npz keys (kernel, bias) of ``count`` dense layers, in order."""
    return [(f"dense_{i}_kernel", f"dense_{i}_bias") for i in range(count)]


def flatten(params: dict) -> dict[str, np.ndarray]:
    """The npz arrays of a params dict: ``obs_mean``, ``obs_std``, ``dense_<i>_kernel`` / ``_bias``."""
    out = {"obs_mean": params["obs_mean"], "obs_std": params["obs_std"]}
    for (k, b), kernel, bias in zip(layer_names(len(params["kernels"])), params["kernels"], params["biases"]):
        out[k], out[b] = kernel, bias
    return {name: np.asarray(value) for name, value in out.items()}


def describe(params: dict, activation: str, distribution_type: str, observation_clip: float, labels: list[str]) -> dict:
    """The format-defining part of ``policy.json`` for ``params`` (sizes, layers, how to compute the action)."""
    if distribution_type not in SQUASH:
        raise ValueError(f"unknown distribution type {distribution_type!r}; choose one of {list(SQUASH)}")
    kernels = params["kernels"]
    layers = [
        {
            "kernel": k,
            "bias": b,
            "in": int(w.shape[0]),
            "out": int(w.shape[1]),
            "activation": activation if i < len(kernels) - 1 else "none",
        }
        for i, ((k, b), w) in enumerate(zip(layer_names(len(kernels)), kernels))
    ]
    action = (
        "tanh(mean)" if SQUASH[distribution_type] == "tanh" else "mean"
    ) + " of the Gaussian whose mean the last layer outputs"
    return {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "observation": {"size": int(kernels[0].shape[0]), "labels": list(labels)},
        "action": {
            "size": int(kernels[-1].shape[1]),
            "range": [-1.0, 1.0],
            "note": "the env clips actions to the range",
        },
        "network": {
            "activation": activation,
            "distribution_type": distribution_type,
            "output": SQUASH[distribution_type],
            "deterministic_action": action,
            "observation_clip": float(observation_clip),
            "normalizer": "(obs - obs_mean) / obs_std, then clipped to +-observation_clip if > 0",
            "layers": layers,
        },
    }


def check_output(out: Path) -> None:
    """Refuse an output path that exists and is neither empty nor a policy directory."""
    if out.exists() and (not out.is_dir() or (any(out.iterdir()) and not (out / META_FILE).is_file())):
        raise ValueError(
            f"output {out} exists and is not a policy directory (no {META_FILE}); choose a new or empty directory"
        )


def write_directory(out: str | Path, files: dict[str, bytes]) -> Path:
    """Write ``files`` into directory ``out`` atomically (temp dir + rename); replaces an existing
    policy directory, refuses any other non-empty one."""
    out = Path(out)
    check_output(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".tmp_{out.name}_", dir=out.parent))
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o777 & ~umask)  # mkdtemp's 0700 would stay on the renamed directory
    old = out.parent / f".old_{out.name}_{os.getpid()}"
    try:
        for name, data in files.items():
            with open(tmp / name, "wb") as fh:
                fh.write(data)
                fh.flush()
                os.fsync(fh.fileno())
        if out.exists():
            os.replace(out, old)
        os.replace(tmp, out)
    finally:
        for leftover in (tmp, old):
            if leftover.exists():
                shutil.rmtree(leftover, ignore_errors=True)
    return out


def npz_bytes(arrays: dict[str, np.ndarray]) -> bytes:
    """Arrays as the bytes of a (deflate-compressed) npz file."""
    buffer = io.BytesIO()
    np.savez_compressed(buffer, **arrays)
    return buffer.getvalue()


def save_policy(out: str | Path, params: dict, meta: dict) -> Path:
    """Write ``policy.npz`` (float32) and ``policy.json`` (``meta``: :func:`describe` plus config and
    source) into directory ``out`` atomically, after checking them against each other."""
    params = {
        "obs_mean": np.asarray(params["obs_mean"], np.float32),
        "obs_std": np.asarray(params["obs_std"], np.float32),
        "kernels": tuple(np.asarray(k, np.float32) for k in params["kernels"]),
        "biases": tuple(np.asarray(b, np.float32) for b in params["biases"]),
    }
    check(params, meta, Path(out))
    return write_directory(
        out, {WEIGHTS_FILE: npz_bytes(flatten(params)), META_FILE: json.dumps(meta, indent=1).encode()}
    )


def read_meta(directory: str | Path) -> dict:
    """The ``policy.json`` of a policy directory (FileNotFoundError / ValueError naming the file)."""
    path = Path(directory) / META_FILE
    if not path.is_file():
        raise FileNotFoundError(f"policy file not found: {path}")
    try:
        meta = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise ValueError(f"policy file {path} is corrupt: not valid JSON ({err})") from err
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        raise ValueError(f"policy file {path} is not an {FORMAT} file")
    if meta.get("format_version") != FORMAT_VERSION:
        raise ValueError(
            f"policy file {path} has format version {meta.get('format_version')!r}; "
            f"this code reads version {FORMAT_VERSION}"
        )
    missing = [k for k in ("observation", "action", "network") if not isinstance(meta.get(k), dict)]
    if missing:
        raise ValueError(f"policy file {path} is corrupt: missing section(s) {missing}")
    return meta


def read_arrays(path: Path, layers: int) -> dict:
    """The params dict of ``layers`` dense layers stored in ``path`` (a policy.npz)."""
    if not path.is_file():
        raise FileNotFoundError(f"policy file not found: {path}")
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {name: data[name] for name in data.files}
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as err:
        raise ValueError(f"policy file {path} is corrupt and cannot be read ({type(err).__name__}: {err})") from err
    names = layer_names(layers)
    missing = [n for n in ["obs_mean", "obs_std", *(n for pair in names for n in pair)] if n not in arrays]
    if missing:
        raise ValueError(f"policy file {path} lacks array(s) {missing}")
    return {
        "obs_mean": arrays["obs_mean"],
        "obs_std": arrays["obs_std"],
        "kernels": tuple(arrays[k] for k, _ in names),
        "biases": tuple(arrays[b] for _, b in names),
    }


def expected_shapes(meta: dict) -> dict[str, tuple[int, ...]]:
    """The shape of every npz array that ``meta`` (a policy.json) describes."""
    net, n_obs, n_act = meta["network"], int(meta["observation"]["size"]), int(meta["action"]["size"])
    sizes = [n_obs] + [int(layer["out"]) for layer in net["layers"]]
    if sizes[-1] != n_act:
        raise ValueError(f"the last layer has {sizes[-1]} outputs but the action size is {n_act}")
    shapes = {"obs_mean": (n_obs,), "obs_std": (n_obs,)}
    for i, ((k, b), layer) in enumerate(zip(layer_names(len(net["layers"])), net["layers"])):
        if (layer.get("kernel"), layer.get("bias")) != (k, b):
            raise ValueError(f"layer {i} must name its arrays {k!r} and {b!r}")
        shapes[k], shapes[b] = (sizes[i], sizes[i + 1]), (sizes[i + 1],)
    return shapes


def check(params: dict, meta: dict, where: Path) -> None:
    """Every array float32, finite and of the shape the metadata says (ValueError naming the problem)."""
    net, obs = meta["network"], meta["observation"]
    if net.get("activation") not in ACTIVATIONS or net.get("output") not in SQUASH.values():
        raise ValueError(
            f"policy {where}: unknown activation {net.get('activation')!r} or output "
            f"{net.get('output')!r}; supported: {list(ACTIVATIONS)}, {sorted(set(SQUASH.values()))}"
        )
    if len(obs.get("labels", [])) != int(obs["size"]):
        raise ValueError(
            f"policy {where}: {len(obs.get('labels', []))} observation labels for observation size {obs['size']}"
        )
    try:
        expected = expected_shapes(meta)
    except ValueError as err:
        raise ValueError(f"policy {where}: {err}") from err
    for name, array in flatten(params).items():
        if array.dtype != np.float32 or array.shape != expected[name]:
            raise ValueError(
                f"policy {where}: array {name} has {array.dtype} {array.shape}, expected float32 {expected[name]}"
            )
        if not np.all(np.isfinite(array)):
            raise ValueError(f"policy {where}: array {name} holds NaN or Inf")
    if np.any(params["obs_std"] <= 0):
        raise ValueError(f"policy {where}: obs_std must be > 0 everywhere")


def load_policy(directory: str | Path) -> NumpyPolicy:
    """Load a policy directory (``policy.npz`` + ``policy.json``), checking every array's shape.

    Raises:
        FileNotFoundError: the directory or one of its files is missing.
        ValueError: a corrupt file, another format version, or arrays of the wrong shape or dtype.
    """
    directory = Path(directory)
    if not directory.is_dir():
        raise FileNotFoundError(f"policy directory not found: {directory}")
    meta = read_meta(directory)
    try:
        params = read_arrays(directory / WEIGHTS_FILE, len(meta["network"]["layers"]))
        check(params, meta, directory / WEIGHTS_FILE)
    except (KeyError, TypeError) as err:
        raise ValueError(f"policy file {directory / META_FILE} is corrupt: missing or bad entry {err!r}") from err
    return NumpyPolicy(params=params, meta=meta)
