"""The package installs like a library: a built wheel carries the robot assets, the configs and the
shipped policies, and, installed on its own, builds an env, evaluates a shipped policy and trains
with its default config (``hsa-train``) from an empty folder."""

from __future__ import annotations

import importlib.util
import json
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
TIMEOUT_S = 600


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    """A wheel built from a copy of the checkout (setuptools builds in the source tree; a stale build/
    folder would add old files), in the test's venv when it has setuptools, else isolated."""
    out, source = tmp_path_factory.mktemp("wheel"), tmp_path_factory.mktemp("source") / "hsa_mjx"
    shutil.copytree(ROOT, source, ignore=shutil.ignore_patterns(".*", "runs", "build", "*.egg-info", "__pycache__"))
    isolation = [] if importlib.util.find_spec("setuptools") is None else ["--no-build-isolation"]
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", *isolation, "-w", str(out), str(source)],
        check=True,
        timeout=TIMEOUT_S,
        cwd=out,
    )
    (found,) = out.glob("hsa_mjx-*.whl")
    return found


def _repo_files(folder: str, pattern: str) -> set[str]:
    """The checkout's files under ``folder`` matching ``pattern``, relative to it."""
    return {
        p.relative_to(ROOT / folder).as_posix() for p in (ROOT / folder).glob(pattern) if "__pycache__" not in p.parts
    }


def test_wheel_holds_the_code_assets_configs_and_policies(wheel):
    names = set(zipfile.ZipFile(wheel).namelist())
    for package, folder in (("hsa_mjx", "hsa_mjx"), ("hsa_mjx_train", "train")):
        missing = {f"{package}/{f}" for f in _repo_files(folder, "**/*.py")} - names
        assert not missing, f"modules left out of the wheel (pyproject's packages list): {sorted(missing)}"
    # the trainer ships under its own name: no top-level "train" package to collide with another's
    assert not [n for n in names if n.startswith("train/")]
    for folder, pattern in (("assets", "*.xml"), ("configs", "*.yaml"), ("policies", "*/policy.*")):
        expected = {f"hsa_mjx/data/{folder}/{f}" for f in _repo_files(folder, pattern)}
        assert expected and expected <= names, sorted(expected - names)
    assert not [n for n in names if n.startswith(("tests/", "benchmarks/", "assets/", "configs/", "policies/"))]


def _compilation_cache() -> dict[str, str]:
    """The suite's persistent compilation cache for a subprocess (its programs are the checkout's: the
    cache keys leave out where the source lies)."""
    import jax

    if not jax.config.jax_compilation_cache_dir:
        return {}
    return {
        "JAX_COMPILATION_CACHE_DIR": str(jax.config.jax_compilation_cache_dir),
        "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS": str(jax.config.jax_persistent_cache_min_compile_time_secs),
    }


def test_installed_package_runs_from_an_empty_folder(wheel, tmp_path):
    """Installed apart from the checkout (its own folder first on the path), run where no repo folder is."""
    site, work = tmp_path / "site", tmp_path / "work"
    work.mkdir()
    subprocess.run(
        [sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--no-compile", "--target", str(site), str(wheel)],
        check=True,
        timeout=TIMEOUT_S,
    )
    env = {**os.environ, "PYTHONPATH": str(site), "JAX_PLATFORMS": "cpu", **_compilation_cache()}
    script = (
        "import json, hsa_mjx\n"
        "from hsa_mjx_train import cli\n"
        "env = hsa_mjx.make_env('flat')\n"
        "config, run_dir = cli.resolve(cli.parse_args([]))\n"
        "print(json.dumps({'file': hsa_mjx.__file__, 'obs': env.observation_size,\n"
        "                  'envs': config.run.num_envs, 'init_from': config.run.init_from}))\n"
    )
    facts = json.loads(
        subprocess.run(
            [sys.executable, "-c", script],
            cwd=work,
            env=env,
            capture_output=True,
            text=True,
            check=True,
            timeout=TIMEOUT_S,
        ).stdout.splitlines()[-1]
    )
    assert Path(facts["file"]).is_relative_to(site)  # the installed copy, not the checkout
    assert facts["obs"] == 24 and facts["init_from"] == "flat"  # the CPU quickstart config, found as package data
    evaluated = subprocess.run(
        [sys.executable, "-m", "hsa_mjx_train.evaluate", "--policy", "flat", "--episodes", "2", "--steps", "10"],
        cwd=work,
        env=env,
        capture_output=True,
        text=True,
        timeout=TIMEOUT_S,
    )
    assert evaluated.returncode == 0, evaluated.stderr[-3000:]
    assert (work / "runs" / "eval_flat" / "eval.json").is_file()
    # the console script with its default config (the CPU quickstart, from the shipped flat policy)
    trained = subprocess.run(
        [str(site / "bin" / "hsa-train"), "--set", "run.num_timesteps=160", "--run-dir", "runs/q"],
        cwd=work,
        env=env,
        capture_output=True,
        text=True,
        timeout=TIMEOUT_S,
    )
    assert trained.returncode == 0, trained.stderr[-3000:]
    assert "policy file" in trained.stdout and (work / "runs" / "q" / "summary.json").is_file()
