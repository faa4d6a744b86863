"""Importing the packages changes nothing process-wide; building an env does, explicitly.

In a fresh interpreter, after the third-party libraries the packages use are imported (their own
imports may set things: Gymnasium sets ``PYGAME_HIDE_SUPPORT_PROMPT``), importing every module of
``hsa_mjx``, ``train`` and ``benchmarks`` must leave ``os.environ``, the start method of
``multiprocessing``, JAX's lowering rules and matplotlib's backend as they were, and read no config
file. Then ``make_env`` on a headless machine chooses MuJoCo's offscreen platform and installs the CPU
linear-algebra lowerings, as documented (docs/architecture.md), which shows the check would see such a
change.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

SCRIPT = r"""
import importlib, json, multiprocessing, os, pkgutil, sys
import brax, flax, gymnasium, jax, matplotlib, mujoco, numpy, optax, yaml  # the dependencies' own imports
from jax.interpreters import mlir

def lowerings():
    # the rule registered for every primitive, per platform and for all (JAX keeps no public view of them)
    rules = {"all": {p.name: id(r) for p, r in mlir._lowerings.items()}}
    rules.update({k: {p.name: id(r) for p, r in v.items()} for k, v in mlir._platform_specific_lowerings.items()})
    return rules

def state():
    return {"environ": dict(os.environ), "start_method": multiprocessing.get_start_method(allow_none=True),
            "lowerings": lowerings(), "mpl_backend": dict.__getitem__(matplotlib.rcParams, "backend"),
            "pyplot": "matplotlib.pyplot" in sys.modules}

reads = []  # YAML files read while importing (the presets are read on first use, not on import)
safe_load = yaml.safe_load
yaml.safe_load = lambda stream: reads.append(getattr(stream, "name", "text")) or safe_load(stream)
before = state()
imported = []
for top in ("hsa_mjx", "train", "benchmarks"):
    package = importlib.import_module(top)
    imported.append(top)
    for info in pkgutil.walk_packages(package.__path__, top + "."):
        if info.name.endswith("__main__"):
            continue
        importlib.import_module(info.name)
        imported.append(info.name)
after = state()
yaml.safe_load = safe_load
changed = {k: (before[k], after[k]) for k in before if before[k] != after[k]}
if "environ" in changed:
    b, a = changed["environ"]
    changed["environ"] = {k: (b.get(k), a.get(k)) for k in set(a) | set(b) if a.get(k) != b.get(k)}
if "lowerings" in changed:
    b, a = changed["lowerings"]
    changed["lowerings"] = sorted(
        f"{plat}:{name}" for plat in a for name in a[plat] if b.get(plat, {}).get(name) != a[plat][name])

import hsa_mjx
hsa_mjx.make_env("flat")
built = state()
print("FACTS " + json.dumps({
    "imported": imported, "changed": changed, "yaml_reads": len(reads),
    "make_env_gl": built["environ"].get("MUJOCO_GL"),
    "make_env_lowerings": sorted(name for name in ("cholesky", "triangular_solve")
                                 if built["lowerings"]["cpu"].get(name) != before["lowerings"]["cpu"].get(name)),
    "egl": bool(__import__("ctypes.util").util.find_library("EGL")),
}))
"""


def test_importing_the_packages_changes_nothing_and_make_env_sets_up_what_it_needs():
    env = {k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "DISPLAY", "WAYLAND_DISPLAY")}
    env["JAX_PLATFORMS"] = "cpu"
    proc = subprocess.run(
        [sys.executable, "-c", SCRIPT], cwd=ROOT, env=env, capture_output=True, text=True, timeout=300
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    (line,) = proc.stdout.splitlines()  # nothing printed but the facts, and no "Failed to import warp" line
    assert line.startswith("FACTS ") and "Failed to import" not in proc.stderr, proc.stdout + proc.stderr
    facts = json.loads(line[6:])
    assert {"hsa_mjx.sim.model", "train.trainer", "train.episodes.play", "benchmarks.scaling.devices"} <= set(
        facts["imported"]
    )
    assert facts["changed"] == {}  # environment, start method, JAX lowerings, matplotlib backend: as before
    assert facts["yaml_reads"] == 0  # no config file is read on import
    assert facts["make_env_lowerings"] == ["cholesky", "triangular_solve"]  # explicit, when an env is built
    assert facts["make_env_gl"] == ("egl" if facts["egl"] else facts["make_env_gl"])  # headless: offscreen GL


def test_import_hsa_mjx_alone_sets_only_what_gymnasium_sets():
    """``import hsa_mjx`` by itself (it imports Gymnasium to register ``hsa_mjx/HSA-v0``) changes the
    environment exactly as ``import gymnasium`` does, and registers the env."""
    probe = (
        "import json, os, sys\n"
        "before = dict(os.environ)\n"
        "import {module}\n"
        "import gymnasium\n"
        "changed = sorted(k for k in os.environ if before.get(k) != os.environ[k])\n"
        "print(json.dumps([changed, 'hsa_mjx/HSA-v0' in gymnasium.registry, 'jax' in sys.modules]))\n"
    )
    env = {k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "PYGAME_HIDE_SUPPORT_PROMPT")}
    outputs = {}
    for module in ("hsa_mjx", "gymnasium"):
        proc = subprocess.run(
            [sys.executable, "-c", probe.format(module=module)], env=env, capture_output=True, text=True, timeout=120
        )
        assert proc.returncode == 0, proc.stderr[-2000:]
        outputs[module] = json.loads(proc.stdout.splitlines()[-1])
    assert outputs["hsa_mjx"][0] == outputs["gymnasium"][0]  # Gymnasium's own variable(s), nothing of hsa_mjx
    assert outputs["hsa_mjx"][1] and not outputs["gymnasium"][1]  # registered by import hsa_mjx
    assert not outputs["hsa_mjx"][2]  # and without importing JAX
