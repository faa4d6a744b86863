"""``benchmarks/results`` holds only what the docs cite, within a size and file budget.

A file counts as cited when the README, a page of ``docs/``, ``policies/README.md`` or
``benchmarks/README.md`` names it: by its path under ``benchmarks/results/``, by its name (when no
other result file has it) alone or in a brace list (``name.{json,md}``, ``name.*``), or by a folder
below the question's (``training/flat/``, ``sweeps/rough_recipe/``: every file in it). The results
index (``benchmarks/results/README.md``) does not count: it lists what is there.
"""

import re
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
MAX_BYTES = 6_000_000
MAX_FILES = 119  # with the index: 120


def _docs_text() -> str:
    pages = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md")), ROOT / "policies" / "README.md"]
    return "\n".join(p.read_text() for p in [*pages, ROOT / "benchmarks" / "README.md"])


def _result_files() -> list[Path]:
    return sorted(p for p in RESULTS.rglob("*") if p.is_file() and p != RESULTS / "README.md")


def _cited(path: Path, text: str, unique_names: set[str]) -> bool:
    rel = path.relative_to(RESULTS).as_posix()
    if rel in text:
        return True
    for folder in path.parents:
        if folder == RESULTS:
            break
        name = folder.relative_to(RESULTS)
        if len(name.parts) >= 2 and re.search(re.escape(name.as_posix()) + r"(/|`|\)|\s|,)", text):
            return True
    if path.name not in unique_names:
        return False
    stem, _, ext = path.name.partition(".")
    bare = r"(?<![\w-])" + re.escape(path.name) + r"(?![\w-])"
    braced = r"(?<![\w-])" + re.escape(stem) + r"\.(\*|\{[^}]*(?<![\w])" + re.escape(ext) + r"(?![\w])[^}]*\})"
    return bool(re.search(bare, text) or re.search(braced, text))


def test_results_stay_within_their_budget():
    files = _result_files()
    size = sum(p.stat().st_size for p in files)
    assert len(files) <= MAX_FILES, f"{len(files)} files in benchmarks/results (at most {MAX_FILES})"
    assert size <= MAX_BYTES, f"{size / 1e6:.2f} MB in benchmarks/results (at most {MAX_BYTES / 1e6:.0f} MB)"


def test_every_result_file_is_cited_by_a_doc():
    files, text = _result_files(), _docs_text()
    counts = Counter(p.name for p in files)
    unique = {name for name, n in counts.items() if n == 1}
    uncited = [p.relative_to(RESULTS).as_posix() for p in files if not _cited(p, text, unique)]
    assert not uncited, f"result files no doc cites (cite them or delete them): {uncited}"


def test_the_citation_rule_can_fail():
    text = "see `training/flat/` and `throughput/speed_x.{json,md}` and capability.md"
    assert _cited(RESULTS / "training" / "flat" / "metrics.jsonl", text, set())
    assert not _cited(RESULTS / "training" / "flat_dr" / "metrics.jsonl", text, set())
    unique = {"speed_x.json", "speed_x.png", "capability.md", "other.json"}
    assert _cited(RESULTS / "throughput" / "speed_x.json", text, unique)
    assert not _cited(RESULTS / "throughput" / "speed_x.png", text, unique)
    assert _cited(RESULTS / "capability" / "capability.md", text, unique)
    assert not _cited(RESULTS / "capability" / "other.json", text, unique)


# A folder of some machine's file system: a result (or a shipped policy's metadata) records paths
# within the repository, and a command as one would type it in a checkout.
MACHINE_PATH = re.compile(r"(?<![\w.~-])/(root|tmp|home|work|Users|mnt|scratch)/")


def test_results_and_policies_name_no_machine_paths():
    files = [*_result_files(), *(p for p in (ROOT / "policies").rglob("*") if p.suffix in (".json", ".md", ".yaml"))]
    found = [
        f"{p.relative_to(ROOT)}: {m.group(0)}"
        for p in files
        if p.suffix in (".json", ".jsonl", ".md", ".yaml")
        for m in [MACHINE_PATH.search(p.read_text())]
        if m
    ]
    assert found == []
    assert MACHINE_PATH.search('"--out-dir /root/out"') and not MACHINE_PATH.search("benchmarks/results/tmp/x")
