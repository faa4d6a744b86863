"""The package's imports run one way: each layer imports only its own layer and those below it."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# Bottom to top (docs/architecture.md). A module of layer i may import modules of layers 0..i.
LAYERS = (
    ("hsa_mjx.resources", "hsa_mjx.config", "hsa_mjx.randomization_config", "hsa_mjx.pose", "hsa_mjx.terrain"),
    ("hsa_mjx.sim",),
    ("hsa_mjx.task",),
    ("hsa_mjx.curricula",),
    ("hsa_mjx.batch",),
    ("hsa_mjx.adapters", "hsa_mjx.deploy"),
    ("hsa_mjx",),  # the package's own __init__: make_env and the public names
    ("train",),
)


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
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imported(path: Path) -> list[tuple[int, str]]:
    """(line, module) of every import of hsa_mjx or train in a file, at any depth (deferred ones too)."""
    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            base = node.module
            # "from hsa_mjx.task import env" imports the module hsa_mjx.task.env
            found += [(node.lineno, f"{base}.{a.name}" if _is_module(f"{base}.{a.name}") else base) for a in node.names]
    return [(line, name) for line, name in found if name.split(".")[0] in ("hsa_mjx", "train")]


def _is_module(name: str) -> bool:
    """Whether a dotted name is a module or package of the checkout."""
    path = ROOT.joinpath(*name.split("."))
    return path.with_suffix(".py").is_file() or (path / "__init__.py").is_file()


def violations() -> list[str]:
    """Every import against the layer order in hsa_mjx/ and train/."""
    bad = []
    for path in sorted([*ROOT.glob("hsa_mjx/**/*.py"), *ROOT.glob("train/**/*.py")]):
        here = module_name(path)
        for line, name in imported(path):
            if layer_of(name) > layer_of(here):
                bad.append(
                    f"{path.relative_to(ROOT)}:{line} imports {name} (layer {layer_of(name)} > {layer_of(here)})"
                )
    return bad


def test_imports_follow_the_layer_order():
    assert violations() == []


def test_the_check_sees_an_upward_import(tmp_path):
    """The walk finds a deferred import of a higher layer (what the test above would fail on)."""
    source = tmp_path / "probe.py"
    source.write_text("def f():\n    from hsa_mjx.batch import auto_reset\n    import train.ppo\n")
    names = [name for _, name in imported(source)]
    assert names == ["hsa_mjx.batch.auto_reset", "train.ppo"]
    assert layer_of("hsa_mjx.batch.auto_reset") > layer_of("hsa_mjx.sim.model") and layer_of("train.ppo") == 7


# The one private field read: MJX keeps Warp-only options (here, which overflow warnings print) in
# ``Model.opt._impl`` and offers no public setter; its own deprecation message points there.
PRIVATE_FIELD_ALLOWED = {("hsa_mjx/sim/backend.py", "put_model")}


def _function_at(tree: ast.AST, line: int) -> str | None:
    """The name of the innermost function that spans ``line``."""
    spans = [(n.lineno, n.end_lineno, n.name) for n in ast.walk(tree) if isinstance(n, ast.FunctionDef)]
    inside = [s for s in spans if s[0] <= line <= s[1]]
    return max(inside)[2] if inside else None


def test_no_private_jax():
    """Nothing reaches into JAX internals; a backend's private field only in the one function named above."""
    hits = []
    for path in [*ROOT.glob("hsa_mjx/**/*.py"), *ROOT.glob("train/**/*.py")]:
        text, name = path.read_text(), path.relative_to(ROOT).as_posix()
        for i, line in enumerate(text.splitlines(), 1):
            if "jax._src" in line or (
                "._impl" in line and (name, _function_at(ast.parse(text), i)) not in PRIVATE_FIELD_ALLOWED
            ):
                hits.append(f"{name}:{i}")
    assert hits == []
