"""The toy source's benchmark entry (``tests/support/toy/source.py`` names it with
``Source(bench=...)``), found by ``python -m benchmarks toy`` through the registry like a built-in
source's. Unit: the toy's sample unit (3 points over 12 frames), annotated, filtered and written, and
once more with another seed (a variant); its floor, reading the unit's JSON.

The pipeline's modules are imported inside the functions, so that a floor process imports only
what its floor reads.
"""

from __future__ import annotations

import json
import os
import tempfile
import time

from pipeline.core.benchmark import UnitSetup, wall_and_cpu

TARGETS = {"ms_per_frame": 50.0}  # per input frame on one core
RELEASE_SHAPE = (64, (8, 8))  # candidates per clip, (fewest, most) frames per clip, as a release would
FIXED_IN_WORK = ()  # nothing a repeated run pays again: the unit runs once
UNIT = "walk"  # the sample's one unit


def prepare(workdir: str, size: str) -> UnitSetup:
    """The toy's sample written under ``workdir`` (the same at every size), and its unit."""
    from tests.support.toy.source import write_sample

    root = write_sample(os.path.join(workdir, "sample"))
    with open(os.path.join(root, f"{UNIT}.json")) as handle:
        frames = json.load(handle)["frames"]
    return UnitSetup(
        source="toy",
        input_root=root,
        units=[[[UNIT]]],
        overrides=[],
        frames=frames,
        description=[f"the toy's sample unit {UNIT!r}: 3 points over {frames} frames"],
        full_units=1,
        full_units_note="the sample's one unit",
        size=size,
        variants={"another seed": ["seed=7"]},
    )


def measure_fixed_cost(spec: dict, config) -> dict:
    """{}: a toy unit has no cost apart from its frames."""
    return {}


def floor(spec: dict) -> dict:
    """floor_s / floor_cpu_s: reading and parsing the units' JSON; floor_frames: their frames."""
    specs = []

    def read() -> None:
        for (unit,) in spec["unit"]:
            with open(os.path.join(spec["input_root"], f"{unit}.json")) as handle:
                specs.append(json.load(handle))

    wall, cpu = wall_and_cpu(read)
    return {"floor_s": wall, "floor_cpu_s": cpu, "floor_frames": sum(s["frames"] for s in specs)}


def unit_of(fields: list):
    """The toy's unit of a spec's JSON fields (``[name]``)."""
    from tests.support.toy.source import SpecFile

    return SpecFile(*fields)


def micro(frames: int) -> None:
    """Print the time to annotate the sample unit, the mean of ``frames`` calls."""
    from pipeline.settings.run_config import RunConfig
    from tests.support.toy.source import SpecFile, annotate, write_sample

    with tempfile.TemporaryDirectory() as folder:
        root, config = write_sample(folder), RunConfig()
        started = time.perf_counter()
        for _ in range(frames):
            annotate(root, SpecFile(UNIT), config)
        print(f"annotate the toy's unit {UNIT!r}: {1000 * (time.perf_counter() - started) / frames:.2f} ms")


def beam_input(setup: UnitSetup, folder: str, groups: int) -> list[str]:
    """``groups`` units in ``folder``: the sample unit's file hard-linked under as many names (each
    unit a group of its own). Returns the ``pipeline.run`` arguments."""
    for k in range(groups):
        os.link(os.path.join(setup.input_root, f"{UNIT}.json"), os.path.join(folder, f"{UNIT}_{k}.json"))
    return ["--input", folder]
