"""The toy source's benchmark entry (``tests/support/toy_bench.py``, named by ``Source(bench=...)``):
with the toy registered as a plug-in (``TAPVID3D_SOURCES``), ``python -m benchmarks toy`` finds the
entry through the registry and benchmarks it like a built-in source's (worker and floor processes
included, and its variant's line), with no change to ``benchmarks/``."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from pipeline.sources import PLUGINS_ENV
from tests.support.cli import REPO


def test_the_toy_is_benchmarked_through_its_own_entry(tmp_path):
    path = tmp_path / "bench.json"
    command = [
        sys.executable,
        "-m",
        "benchmarks",
        "toy",
        "--quick",
        "--workdir",
        str(tmp_path),
        "--json",
        str(path),
    ]
    env = dict(os.environ, **{PLUGINS_ENV: "tests.support.toy_source"})
    done = subprocess.run(command, cwd=REPO, env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    summary = done.stdout[done.stdout.index("=== summary") :].splitlines()
    assert summary[1].split()[:2] == ["source", "ms/frame"]
    assert summary[2].startswith("toy ") and "<=50 n/a" in summary[2] and summary[3].startswith("all ")
    assert f"table written to {path}" in done.stdout
    variant = next(line for line in done.stdout.splitlines() if line.startswith("  with another seed"))
    assert variant.startswith("  with another seed (seed=7): unit work")
    assert "x the unit's CPU (each run" in variant
    data = json.loads(path.read_text())
    toy, every = data["rows"]
    assert (toy["source"], toy["measured_frames"], toy["tracks_written"]) == ("toy", 12, 3)
    assert toy["ms_per_frame_target"] == 50.0 and data["targets"]["ms_per_frame"] == {"toy": 50.0}
    for key in ("ms_per_frame", "peak_rss_gib", "speedup", "speedup_cpu", "floor_cpu_s", "floor_ratio"):
        assert toy[key] > 0, (key, toy[key])
    assert every["cpu_hours"] == pytest.approx(toy["cpu_hours"])
