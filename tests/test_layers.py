"""The code imports one way: each layer imports only its own layer and those below it, in hsa_mjx/, in
the trainer (train/; installed, hsa_mjx_train) and in benchmarks/; the command-line tools are on top,
nothing calls another module's private names, and nothing reaches into JAX's internals."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = {"hsa_mjx": "hsa_mjx", "train": "train", "benchmarks": "benchmarks"}  # import name: folder
T = "train."
# Bottom to top (docs/architecture.md). A module of layer i may import modules of layers 0..i.
LAYERS = (
    (
        "hsa_mjx.resources",
        "hsa_mjx.config",
        "hsa_mjx.config_checks",
        "hsa_mjx.config_schema",
        "hsa_mjx.migrations",
        "hsa_mjx.randomization_config",
        "hsa_mjx.servo_config",
        "hsa_mjx.robots",
        "hsa_mjx.pose",
        "hsa_mjx.terrain",
    ),
    ("hsa_mjx.sim",),
    ("hsa_mjx.task",),
    ("hsa_mjx.curricula",),
    ("hsa_mjx.batch",),
    ("hsa_mjx.adapters", "hsa_mjx.deploy", "hsa_mjx.sysid"),
    ("hsa_mjx",),  # the package's own __init__: make_env and the public names
    # the trainer, its folders floor by floor (TRAIN_FLOORS); on top, the command-line tools nothing imports
    *((T + floor,) for floor in ("config", "learners", "devices", "run", "episodes", "trainer")),
    (T + "cli", T + "evaluate", T + "export", T + "__main__", "train"),
    ("benchmarks",),
)
TOOLS = (T + "cli", T + "evaluate", T + "export", T + "__main__")  # imported by no other module
# train/'s floors are folders: the learners' code; the devices (collection strategies, replicas, several
# processes); the run (checkpoints, what they hold, the run folder, warm start, logs, plots); playing
# episodes (evaluation); beside them at the top level only the config, the training loop and the tools
TRAIN_FLOORS = ("config", "learners", "devices", "run", "episodes")
TRAIN_TOP = ("__init__", "__main__", "cli", "evaluate", "export", "trainer")
# benchmarks/ is one folder per question, beside two shared modules (benchmarks/README.md)
BENCHMARK_FOLDERS = ("speed", "fidelity", "scaling", "robustness", "sweeps", "terrain", "robots")
BENCHMARK_TOP = ("__init__", "stats", "run_info")


def layer_of(module: str) -> int:
    """The layer index of a dotted module name (the longest matching prefix)."""
    best = None
    for i, prefixes in enumerate(LAYERS):
        for prefix in prefixes:
            if module == prefix or module.startswith(prefix + "."):
                if best is None or len(prefix) > best[1]:
                    best = (i, len(prefix))
    assert best is not None, f"{module} belongs to no layer: add it to LAYERS"
    return best[0]


def module_name(path: Path) -> str:
    """The dotted module name of a source file of the checkout."""
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    parts[0] = {folder: name for name, folder in PACKAGES.items()}[parts[0]]
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _package_of(path: Path, package: str | None) -> str:
    """The package a file's relative imports start from: its own for an __init__, else its parent's."""
    package = package if package is not None else module_name(path)
    return package if path.name == "__init__.py" else package.rsplit(".", 1)[0]


def imported(path: Path, package: str | None = None) -> list[tuple[int, str]]:
    """(line, module) of every import of the project's packages in a file, at any depth (deferred ones too);
    relative imports (``from . import config``, ``from .config import load``) are resolved against the
    file's package (``package``: the file's module name, where it lies outside the checkout)."""
    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and (node.module or node.level):
            base = _package_of(path, package)
            for _ in range(node.level - 1):
                base = base.rsplit(".", 1)[0]
            base = node.module if not node.level else ".".join(p for p in (base, node.module) if p)
            # "from hsa_mjx.task import env" imports the module hsa_mjx.task.env
            found += [(node.lineno, f"{base}.{a.name}" if _is_module(f"{base}.{a.name}") else base) for a in node.names]
    return [(line, name) for line, name in found if name.split(".")[0] in PACKAGES]


def _is_module(name: str) -> bool:
    """Whether a dotted name is a module or package of the checkout."""
    parts = name.split(".")
    if parts[0] not in PACKAGES:
        return False
    path = ROOT.joinpath(PACKAGES[parts[0]], *parts[1:])
    return path.with_suffix(".py").is_file() or (path / "__init__.py").is_file()


def sources() -> list[Path]:
    """Every Python file of the three packages."""
    return sorted(p for folder in PACKAGES.values() for p in ROOT.glob(f"{folder}/**/*.py"))


def violations() -> list[str]:
    """Every import against the layer order, and every import of a command-line tool."""
    bad = []
    for path in sources():
        here = module_name(path)
        for line, name in imported(path):
            where = f"{path.relative_to(ROOT)}:{line} imports {name}"
            if layer_of(name) > layer_of(here):
                bad.append(f"{where} (layer {layer_of(name)} > {layer_of(here)})")
            elif name in TOOLS and here not in (name, T + "__main__"):
                bad.append(f"{where}: a command-line tool, which nothing in the packages imports")
    return bad


def test_imports_follow_the_layer_order():
    assert violations() == []


def test_the_trainer_has_no_chain_through_its_tools():
    """No trainer module imports evaluate or export: they are top-floor tools."""
    importers = {
        module_name(path)
        for path in sources()
        for _, name in imported(path)
        if name in (T + "evaluate", T + "export") and module_name(path) != T + "__main__"
    }
    assert importers == set()
    assert layer_of(T + "evaluate") == layer_of(T + "export") == max(layer_of(m) for m in TOOLS)
    assert all(layer_of(T + m) < layer_of(T + "evaluate") for m in ("trainer", "run.warm_start", "run.saved"))


def _stray(package: str, folders: tuple[str, ...], top: tuple[str, ...]) -> list[str]:
    """The modules of ``package`` outside its ``folders`` that are not one of its ``top`` modules."""
    stray = []
    for path in (ROOT / package).rglob("*.py"):
        parts = path.relative_to(ROOT / package).with_suffix("").parts
        if not (parts[0] in folders and len(parts) > 1 or len(parts) == 1 and parts[0] in top):
            stray.append(path.relative_to(ROOT).as_posix())
    faceless = [f for f in folders if not (ROOT / package / f / "__init__.py").is_file()]
    return stray + [f"{package}/{f}/__init__.py missing" for f in faceless]


def test_the_trainers_floors_and_the_benchmarks_questions_are_folders():
    """Every trainer module lies in one of its floor folders and every benchmark in its question's folder,
    but for the few top-level modules each names."""
    assert _stray("train", TRAIN_FLOORS, TRAIN_TOP) == []
    assert _stray("benchmarks", BENCHMARK_FOLDERS, BENCHMARK_TOP) == []


def test_the_run_evaluation_and_export_reach_a_learner_only_through_the_registry():
    """Checkpoints, warm starts, evaluation and export are learner-agnostic: no import of PPO's own modules."""
    reaching = {
        f"{path.relative_to(ROOT)}:{line}"
        for path in sources()
        if module_name(path).startswith((T + "run", T + "episodes", T + "export"))
        for line, name in imported(path)
        if name.startswith(T + "learners.ppo")
    }
    assert reaching == set()


def test_the_check_sees_an_upward_import(tmp_path):
    """The walk finds a deferred import of a higher layer (what the tests above would fail on)."""
    source = tmp_path / "probe.py"
    source.write_text(
        "def f():\n    from hsa_mjx.batch import auto_reset\n    import train.learners.ppo.learner\n"
        "    from .devices import strategies\n    from .trainer import train\n"
    )
    names = [name for _, name in imported(source, package="train.probe")]
    assert names == [
        "hsa_mjx.batch.auto_reset",
        "train.learners.ppo.learner",
        "train.devices.strategies",
        "train.trainer",
    ]
    assert layer_of("hsa_mjx.batch.auto_reset") > layer_of("hsa_mjx.sim.model")
    assert layer_of("train.learners.ppo.learner") > layer_of("train.config")
    assert module_name(ROOT / "train" / "trainer.py") == "train.trainer"


# The private names read on purpose: MJX keeps Warp-only options (which overflow warnings print) in
# ``Model.opt._impl`` with no public setter (its own deprecation message points there), and the
# Gymnasium entry point reads the time limit from ``gymnasium.make``'s frame (``sys._getframe``).
PRIVATE_ALLOWED = {
    ("hsa_mjx/sim/backend.py", "put_model", "_impl"),
    ("hsa_mjx/adapters/gymnasium.py", None, "_getframe"),
}


def _function_at(tree: ast.AST, line: int) -> str | None:
    """The name of the innermost function that spans ``line``."""
    spans = [(n.lineno, n.end_lineno, n.name) for n in ast.walk(tree) if isinstance(n, ast.FunctionDef)]
    inside = [s for s in spans if s[0] <= line <= s[1]]
    return max(inside)[2] if inside else None


def private_uses(path: Path, root: Path = ROOT) -> list[str]:
    """Where a file reads another object's or module's private name: ``x._name`` with ``x`` not ``self``
    or ``cls``, or ``from module import _name``."""
    tree, name = ast.parse(path.read_text()), path.relative_to(root).as_posix()
    hits = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and any(a.name.startswith("_") for a in node.names):
            hits.append(f"{name}:{node.lineno} imports a private name from {node.module}")
        if isinstance(node, ast.Attribute) and node.attr.startswith("_") and not node.attr.startswith("__"):
            owner = node.value.id if isinstance(node.value, ast.Name) else None
            if owner in ("self", "cls"):
                continue
            allowed = {(name, _function_at(tree, node.lineno), node.attr), (name, None, node.attr)}
            if not allowed & PRIVATE_ALLOWED:
                hits.append(f"{name}:{node.lineno} reads .{node.attr}")
    return hits


def test_no_module_calls_another_modules_private_names():
    assert [hit for path in sources() for hit in private_uses(path)] == []


def test_the_private_name_check_sees_one(tmp_path):
    source = tmp_path / "probe.py"
    source.write_text("from m import _hidden\nx = learner._on_each\ny = self._mine\n")
    hits = [h.split(" ", 1)[1] for h in private_uses(source, tmp_path)]
    assert hits == ["imports a private name from m", "reads ._on_each"]


def test_no_private_jax():
    """Nothing reaches into JAX's internals."""
    hits = []
    for path in sources():
        for i, line in enumerate(path.read_text().splitlines(), 1):
            if "jax._src" in line:
                hits.append(f"{path.relative_to(ROOT)}:{i}")
    assert hits == []
