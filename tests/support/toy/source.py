"""A toy source, defined entirely here and registered at run time: the proof that a source needs
one object and nothing else in the package (docs/adding-a-source.md), its settings section
(``ToyConfig``: ``--set toy.<field>=...``) and its benchmark entry (``tests/support/toy/bench.py``:
``python -m benchmarks toy``) included.

Input: a folder of ``<name>.json`` files, each a unit (on a release run, those the release names a
clip of): ``{"frames": T, "points": [[x, y, z], ...],
"velocity": [vx, vy, vz]}``: points moving at constant velocity (metres per frame, times
``toy.speed_scale``) in front of a static 64x48 pinhole camera. Each unit makes one clip
``toy_<name>`` of every point, visible while it projects into the frame; with ``--queries-from``,
only the clips found there, with their queries. A unit is a scene of its own (its name), the scene
of clip ``toy_<name>``.

Registered by the tests (``sources.register(TOY)``), or for every process of a run by naming this
module in ``TAPVID3D_SOURCES`` (it defines ``SOURCE``).
"""

from __future__ import annotations

import dataclasses
import json
import os

import cv2
import numpy as np

from pipeline.core.clip import ClipRecord, TrackStats
from pipeline.core.errors import InputError
from pipeline.settings.fields import ranged
from pipeline.settings.run_config import RunConfig
from pipeline.sources import RunChoices, Source, UnitPlan, one_by_one

WIDTH, HEIGHT = 64, 48
INTRINSICS = np.array([40.0, 40.0, 32.0, 24.0])
MASK_THRESHOLD = 0.5


@dataclasses.dataclass(frozen=True)
class ToyConfig:
    """The ``toy`` section of the run's settings.

    speed_scale: every unit's velocity is multiplied by this (0: the points stand still).
    """

    speed_scale: float = ranged(1.0, "[0, 10]")


@dataclasses.dataclass(frozen=True, order=True)
class SpecFile:
    """A toy unit: the file ``<name>.json`` of the input folder; each is a group of its own."""

    name: str

    @property
    def group(self) -> str:
        return self.name


def list_units(
    input_root: str, config: RunConfig, release: frozenset[str] | None = None
) -> UnitPlan[SpecFile]:
    names = sorted(name[: -len(".json")] for name in os.listdir(input_root) if name.endswith(".json"))
    if not names:
        raise InputError(f"{input_root}: no <unit>.json files")
    units = [SpecFile(name) for name in names]
    if release is None:
        return UnitPlan(units)
    kept = [unit for unit in units if f"toy_{unit.name}" in release]
    made = {f"toy_{unit.name}" for unit in kept}
    absent = {clip: f"no {clip.removeprefix('toy_')}.json in --input" for clip in sorted(release - made)}
    return UnitPlan(kept, expected={unit.name: (f"toy_{unit.name}",) for unit in kept}, absent=absent)


def truth(spec: dict, speed_scale: float = 1.0) -> np.ndarray:
    """Points [T, N, 3] of a unit, from its analytic motion at ``speed_scale`` x its velocity."""
    steps = np.arange(spec["frames"])[:, None, None]
    return np.asarray(spec["points"], float)[None] + steps * speed_scale * np.asarray(spec["velocity"], float)


def annotate(input_root: str, unit: SpecFile, config: RunConfig) -> list[ClipRecord]:
    given = RunChoices.of(config, "toy").given
    queries_given = given.of(f"toy_{unit.name}")
    if given.active and queries_given is None:
        return []
    with open(os.path.join(input_root, f"{unit.name}.json")) as handle:
        spec = json.load(handle)
    tracks = truth(spec, config.section(ToyConfig).speed_scale)
    fx, fy, cx, cy = INTRINSICS
    pixels = np.stack(
        [fx * tracks[..., 0] / tracks[..., 2] + cx, fy * tracks[..., 1] / tracks[..., 2] + cy], -1
    )
    visible = (
        (pixels[..., 0] >= 0) & (pixels[..., 0] < WIDTH) & (pixels[..., 1] >= 0) & (pixels[..., 1] < HEIGHT)
    )
    query_frames = visible.argmax(axis=0)
    index = np.arange(tracks.shape[1])
    queries = np.concatenate([pixels[query_frames, index], query_frames[:, None]], axis=1)
    if queries_given is not None:
        queries = queries_given
    frame = cv2.imencode(".jpg", np.full((HEIGHT, WIDTH, 3), 90, np.uint8))[1].tobytes()
    return [
        ClipRecord(
            source="toy",
            name=f"toy_{unit.name}",
            unit=unit.name,
            images_jpeg=[frame] * spec["frames"],
            fx_fy_cx_cy=INTRINSICS,
            image_size=(WIDTH, HEIGHT),
            extrinsics_w2c=None,
            tracks_xyz=tracks,
            visibility=visible,
            queries_xyt=queries,
            frame_ids=np.arange(spec["frames"]),
            track_stats=TrackStats(np.ones(tracks.shape[1])),
            target_tracks=tracks.shape[1],
            given_queries=queries_given is not None,
        )
    ]


def write_sample(folder: str) -> str:
    os.makedirs(folder, exist_ok=True)
    spec = {
        "frames": 12,
        "points": [[-0.4, 0.1, 2.0], [0.2, -0.2, 3.0], [0.0, 0.0, 4.0]],
        "velocity": [0.02, 0, 0],
    }
    with open(os.path.join(folder, "walk.json"), "w") as handle:
        json.dump(spec, handle)
    return folder


TOY: Source[SpecFile] = Source(
    name="toy",
    list_units=list_units,
    annotate_group=one_by_one(annotate),
    sample_input=write_sample,
    mask_min_agreement=lambda config: MASK_THRESHOLD,
    settings=ToyConfig,
    bench="tests.support.toy.bench",
    scene_of=lambda unit: unit.name,
    clip_scene=lambda name: name.removeprefix("toy_") if name.startswith("toy_") else None,
)
SOURCE = TOY
