"""The package installs like a library: a built wheel carries the robot assets, the configs and the
shipped policies, and, installed on its own, builds an env, evaluates a shipped policy and runs the
README's main command from an empty folder: ``hsa-train`` with its default config, the CPU quickstart,
which continues the shipped flat policy, says so and reaches goals."""

from __future__ import annotations

import importlib.util
import os
import re
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest
from conftest import XLA_NO_LLVM_OPTIMISATION

ROOT = Path(__file__).resolve().parents[1]
TIMEOUT_S = 600
# The quickstart run, shortened to 3,200 env steps here (the README's run is 9,600).
QUICKSTART_STEPS = 3200


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


def test_wheel_holds_the_code_assets_configs_policies_and_robot_profiles(wheel):
    names = set(zipfile.ZipFile(wheel).namelist())
    for package, folder in (("hsa_mjx", "hsa_mjx"), ("hsa_mjx_train", "train")):
        missing = {f"{package}/{f}" for f in _repo_files(folder, "**/*.py")} - names
        assert not missing, f"modules left out of the wheel (pyproject's packages list): {sorted(missing)}"
    # the trainer ships under its own name: no top-level "train" package to collide with another's
    assert not [n for n in names if n.startswith("train/")]
    shipped = (("assets", "*.xml"), ("configs", "*.yaml"), ("policies", "*/policy.*"), ("robots", "*.*"))
    for folder, pattern in shipped:
        expected = {f"hsa_mjx/data/{folder}/{f}" for f in _repo_files(folder, pattern)}
        assert expected and expected <= names, sorted(expected - names)
    top = ("tests/", "benchmarks/", "assets/", "configs/", "policies/", "robots/")
    assert not [n for n in names if n.startswith(top)]


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
    # the console script with its default config (the CPU quickstart, from the shipped flat policy), its
    # programs compiled at LLVM O1 instead of the suite's O0: 15 instead of 9 s of compiling, then about
    # 10 instead of 33 s of training
    assert XLA_NO_LLVM_OPTIMISATION in env["XLA_FLAGS"]
    o1 = env["XLA_FLAGS"].replace(XLA_NO_LLVM_OPTIMISATION, "--xla_backend_optimization_level=1")
    run_dir = work / "runs" / "quick"
    trained = subprocess.run(
        [str(site / "bin" / "hsa-train"), "--run-dir", str(run_dir)]
        + [f"--set=run.{key}={QUICKSTART_STEPS}" for key in ("num_timesteps", "checkpoint_every")],
        cwd=work,
        env={**env, "XLA_FLAGS": o1},
        capture_output=True,
        text=True,
        timeout=TIMEOUT_S,
    )
    assert trained.returncode == 0, trained.stderr[-3000:]
    out = trained.stdout
    assert f"run dir: {run_dir}" in out.splitlines()[0]  # printed before anything compiles
    start = re.search(r"starting from the policy network and observation statistics of the policy file (\S*)", out)
    assert start and Path(start.group(1)).is_relative_to(site / "hsa_mjx" / "data" / "policies" / "flat")  # installed
    success = re.search(r"episode/success_rate: (\S+)", out)
    assert success and float(success.group(1)) > 0.5, out[-2000:]  # a missing line fails here too, with the output
    assert (run_dir / "learning_curve.png").is_file() and (run_dir / "summary.json").is_file()


MARKER = "THE-CHECKOUT-COPY"
PROBE = (
    "import runpy, sys\n"
    "sys.argv = ['train', '--help']\n"
    "try:\n"
    "    runpy.run_module('train', run_name='__main__', alter_sys=True)\n"
    "except SystemExit:\n"
    "    pass\n"
    "import hsa_mjx\n"
    "print(sys.modules['train.cli'].__file__, hsa_mjx.__file__, 'hsa_mjx_train' in sys.modules)\n"
)


def _checkout(tmp_path: Path) -> Path:
    """The checkout's code, configs and assets copied, the trainer's help marked: whose code runs shows."""
    copy = tmp_path / "checkout"
    for folder in ("hsa_mjx", "train", "configs", "assets"):
        shutil.copytree(ROOT / folder, copy / folder, ignore=shutil.ignore_patterns("__pycache__"))
    cli = copy / "train" / "cli.py"
    cli.write_text(cli.read_text().replace('"""Command line:', f'"""{MARKER} Command line:', 1))
    return copy


def _train_help_runs_the_checkout(copy: Path, pythonpath: str) -> None:
    """``python -m train --help`` in the checkout (run as ``-m`` does, through runpy, so that the same
    process then says which files it loaded) prints its help from its own train/ and hsa_mjx/ only."""
    env = {**os.environ, "PYTHONPATH": pythonpath, "JAX_PLATFORMS": "cpu"}
    shown = subprocess.run(
        [sys.executable, "-c", PROBE], cwd=copy, env=env, capture_output=True, text=True, timeout=TIMEOUT_S
    )
    assert shown.returncode == 0 and MARKER in shown.stdout, shown.stderr[-3000:]
    cli_file, env_file, installed_name = shown.stdout.split()[-3:]
    assert Path(cli_file).is_relative_to(copy) and Path(env_file).is_relative_to(copy)
    assert installed_name == "False"  # the installed trainer's modules never load beside the checkout's


def test_python_m_train_in_a_checkout_with_only_pythonpath(tmp_path):
    copy = _checkout(tmp_path)
    _train_help_runs_the_checkout(copy, str(copy))


def test_python_m_train_in_a_checkout_runs_its_code_beside_an_installed_wheel(wheel, tmp_path):
    """After ``pip install .`` the checkout's edits are what ``python -m train`` runs there."""
    site = tmp_path / "site"
    subprocess.run(
        [sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--no-compile", "--target", str(site), str(wheel)],
        check=True,
        timeout=TIMEOUT_S,
    )
    _train_help_runs_the_checkout(_checkout(tmp_path), str(site))
