"""Every ``python -m MODULE`` the README, the docs and the benchmarks' and policies' READMEs give names a
module of the checkout (a command a user copies must exist)."""

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md")), ROOT / "benchmarks" / "README.md"]
PAGES += [ROOT / "policies" / "README.md"]
COMMAND = re.compile(r"python3? -m ((?:hsa_mjx_train|hsa_mjx|train|benchmarks)(?:\.\w+)*)(?![\w.])")
FOLDERS = {"hsa_mjx_train": "train"}  # the trainer's installed name


def _exists(module: str) -> bool:
    top, *rest = module.split(".")
    path = ROOT.joinpath(FOLDERS.get(top, top), *rest)
    return path.with_suffix(".py").is_file() or (path / "__main__.py").is_file()


def test_documented_commands_name_modules_that_exist():
    found = {(page.relative_to(ROOT).as_posix(), m) for page in PAGES for m in COMMAND.findall(page.read_text())}
    missing = sorted(f"{page}: {module}" for page, module in found if not _exists(module))
    assert missing == []


def test_the_command_check_can_fail():
    assert _exists("benchmarks.speed.throughput") and _exists("train") and _exists("hsa_mjx.sysid")
    assert not _exists("benchmarks.throughput") and _exists("hsa_mjx_train.evaluate")
    assert COMMAND.findall("python -m benchmarks.<folder>.<module> and python -m train.evaluate") == ["train.evaluate"]
