"""Prose cannot drift from the tree: every file path of the repository named in the README, the docs,
the Makefile, and any module's docstrings and comments (``pipeline/...``, ``tests/...``,
``benchmarks/...``, ``docs/...``) exists. Patterns (``<source>``, ``*``) are left out."""

from __future__ import annotations

import pathlib
import re

from tests.support.cli import REPO

ROOT = pathlib.Path(REPO)
NAMED = re.compile(r"(?<![\w./-])((?:pipeline|tests|benchmarks|docs)/[\w/.\-<>{}*]+)")
SKIPPED = (".venv", ".cache", ".git", "out", "build")


def prose_files() -> list[pathlib.Path]:
    files = [ROOT / "README.md", ROOT / "Makefile"]
    for pattern in ("**/*.py", "**/*.md"):
        files += [path for path in ROOT.glob(pattern) if not set(path.relative_to(ROOT).parts) & set(SKIPPED)]
    return sorted(set(files))


def named_paths(text: str) -> set[str]:
    found = set()
    for match in NAMED.finditer(text):
        path = match[1].rstrip(".,:;)`'\"")
        if not any(mark in path for mark in "<>{}*"):
            found.add(path)
    return found


def test_the_pattern_finds_paths_in_prose():
    text = "see ``pipeline/io/http.py``, (`docs/release.md`), benchmarks/<source>.py and tests/*/x.py."
    assert named_paths(text) == {"pipeline/io/http.py", "docs/release.md"}


def test_every_path_named_in_prose_exists():
    missing = [
        f"{path.relative_to(ROOT)} names {named}"
        for path in prose_files()
        for named in sorted(named_paths(path.read_text(errors="replace")))
        if not (ROOT / named).exists()
    ]
    assert not missing, "; ".join(missing)
