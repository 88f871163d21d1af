"""The toy source's benchmark entry (``tests/support/toy/bench.py``, named by ``Source(bench=...)``):
with the toy registered as a plug-in (``TAPVID3D_SOURCES``), ``python -m benchmarks toy --beam``
finds the entry through the registry and benchmarks it like a built-in source's (worker and floor
processes included, its variant's line, and its groups through ``python -m pipeline.run`` on Beam),
with no change to ``benchmarks/``."""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
import time

import pytest

from pipeline.sources import PLUGINS_ENV
from tests.support.cli import REPO

FIRST_USE_CPU_S = 0.25


def test_the_toy_is_benchmarked_through_its_own_entry(tmp_path):
    path = tmp_path / "bench.json"
    command = [
        sys.executable,
        "-m",
        "benchmarks",
        "toy",
        "--quick",
        "--beam",
        "--workdir",
        str(tmp_path),
        "--json",
        str(path),
    ]
    env = dict(os.environ, **{PLUGINS_ENV: "tests.support.toy.source"})
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
    # The toy's unit runs under a plain run's rules (its settings name none); its variant is no rule set.
    assert toy["peak_rss_gib_by_rules"] == {"refined": toy["peak_rss_gib"]}
    # Through Beam: 4 groups per worker, 1 then 2 workers, each command's serial start inside its time.
    walls, serial = toy["beam_wall_s"], toy["beam_serial_s"]
    assert toy["beam_groups"] == 8 and walls.keys() == serial.keys() == {"1", "2"}
    assert toy["beam_speedup"] == pytest.approx(walls["1"] / walls["2"])
    assert (toy["beam_speedup_target"], toy["beam_speedup_pass"]) == (1.8, None)  # quick: not judged
    assert all(0 < serial[count] < walls[count] for count in walls), (serial, walls)
    beam = next(line for line in done.stdout.splitlines() if line.startswith("through Beam:"))
    assert beam.startswith("through Beam: 8 groups (8 units) by python -m pipeline.run")
    assert f"1 worker {walls['1']:.1f} s, 2 workers {walls['2']:.1f} s" in beam
    said = next(line for line in done.stdout.splitlines() if line.startswith("  serial start"))
    assert f"= {serial['1']:.1f} s, 2 worker(s) " in said and said.endswith(f"= {serial['2']:.1f} s")


def test_a_warm_up_run_takes_what_only_a_processs_first_unit_pays_out_of_the_timed_run(tmp_path):
    """With ``warm_up`` in the spec (DriveTrack's setup asks for it), the unit runs once before the
    timed run: a cost its first call pays once per process (here 0.25 s of CPU, standing for an
    import made on first use) is in the warm-up's time and not in the unit's; the warm-up writes
    into a folder of its own, removed after it."""
    from benchmarks import worker
    from pipeline import sources
    from tests.support.toy import bench as toy_bench
    from tests.support.toy import source as toy_source

    def first_use_costs(input_root, unit, config):
        if not paid:
            started = time.process_time()
            while time.process_time() - started < FIRST_USE_CPU_S:
                pass
            paid.append(True)
        return toy_source.annotate(input_root, unit, config)

    paid: list[bool] = []
    sources.register(dataclasses.replace(toy_source.TOY, annotate_group=sources.one_by_one(first_use_costs)))
    try:
        root = toy_source.write_sample(str(tmp_path / "sample"))
        output = str(tmp_path / "out")
        spec = {"source": "toy", "input_root": root, "unit": [["walk"]], "overrides": [], "output": output}
        result = worker.unit_work(dict(spec, warm_up=True), toy_bench)
    finally:
        sources.unregister("toy")
    assert result["first_unit_cpu_s"] >= FIRST_USE_CPU_S
    assert result["work_cpu_s"] < FIRST_USE_CPU_S / 2 and result["annotate_cpu_s"] < FIRST_USE_CPU_S / 2
    extra = result["first_unit_cpu_s"] - result["work_cpu_s"]
    assert result["first_unit_extra_cpu_s"] == pytest.approx(extra)
    assert result["tracks_written"] == 3
    assert sorted(os.listdir(tmp_path)) == ["out", "sample"]
