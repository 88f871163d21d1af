"""Freed heap given back between units (``pipeline.core.memory``): a process that freed many small
blocks keeps them resident until ``release_freed_memory`` returns them; every group of units ends
with it, in a worker's step and in ``run_group``."""

from __future__ import annotations

import subprocess
import sys

import pytest

from pipeline import sources
from pipeline.runner import stages
from pipeline.runner.stages import UnitJob, run_group
from pipeline.settings.run_config import RunConfig
from tests.support.cli import REPO
from tests.support.toy.source import TOY, write_sample

# Frees 190 MiB of 64 KiB blocks (under glibc's mmap threshold, so they come from the heap) but the
# last, then gives the heap back; prints the resident MiB before and after.
FREE_THEN_RELEASE = """
import os
from pipeline.core.memory import release_freed_memory
def rss():
    return int(open("/proc/self/statm").read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20
blocks = [bytearray(64 * 1024) for _ in range(3000)]
del blocks[:-1]
freed = rss()
release_freed_memory()
print(freed, rss())
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's malloc_trim")
def test_the_freed_heap_goes_back_to_the_system():
    done = subprocess.run([sys.executable, "-c", FREE_THEN_RELEASE], cwd=REPO, capture_output=True, text=True)
    freed, released = map(float, done.stdout.split())
    assert freed - released > 150, (freed, released)


def test_each_group_of_units_ends_by_giving_its_heap_back(tmp_path, monkeypatch):
    calls = []
    monkeypatch.setattr(stages, "release_freed_memory", lambda: calls.append(True))
    sources.register(TOY)
    try:
        root = write_sample(str(tmp_path / "in"))
        job = UnitJob(TOY, root, RunConfig(), str(tmp_path / "out"))
        (outcome,) = run_group(job, TOY.list_units(root, RunConfig()).units)
    finally:
        sources.unregister(TOY.name)
    assert not outcome.failures and calls == [True]
