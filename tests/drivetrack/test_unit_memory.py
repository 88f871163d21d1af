"""A DriveTrack unit lets go of what scales with its frames once it is used: the refined visibility's
footprints stream (a few frames' at a time, not every frame's), each camera's evidence goes once its
clips are made, and the JPEGs read go once the frames stored are made. Counted on the sample world's
segment (3 cameras x 40 frames, the refined rules) by weak references to the objects as they are
made, read when each frame's occluders reach the clips and when each camera's clips are finished."""

from __future__ import annotations

import weakref

import pytest

from pipeline.drivetrack import annotate, footprints, lidar
from pipeline.drivetrack.refined_visibility import RefinedTracks
from pipeline.drivetrack.sample.waymo_world import NUM_FRAMES, SEGMENT
from pipeline.drivetrack.settings import DriveTrackConfig
from pipeline.settings.fields import with_overrides, with_rules
from pipeline.settings.run_config import RunConfig
from pipeline.sources import RunChoices

CAMERAS = [1, 2, 3]


class Alive:
    """Weak references to the objects made of each kind, and how many of each are alive at each
    count (and the most). None of them is in a reference cycle: each dies when its last reference
    goes, without a collection."""

    def __init__(self, kinds: list[str]):
        self.made: dict[str, list[weakref.ref]] = {kind: [] for kind in kinds}
        self.most = dict.fromkeys(kinds, 0)
        self.counts: dict[str, list[int]] = {kind: [] for kind in kinds}

    def add(self, kind: str, item) -> None:
        if not any(ref() is item for ref in self.made[kind]):
            self.made[kind].append(weakref.ref(item))

    def count(self) -> None:
        for kind, items in self.made.items():
            living = sum(ref() is not None for ref in items)
            self.most[kind] = max(self.most[kind], living)
            self.counts[kind].append(living)


@pytest.fixture(scope="module")
def counted(sample_split):
    """The sample segment's cameras annotated under the refined rules with the objects counted: the
    ``Alive`` counts, the units (after) and their clips."""
    monkeypatch = pytest.MonkeyPatch()
    alive = Alive(["occluders", "parts", "evidence"])
    made_occluders = footprints.FrameOccluders.__init__
    made_parts = lidar.frame_footprints
    see, finish = RefinedTracks.see, annotate.finish_clip

    def occluders_init(self, parts):
        alive.add("occluders", self)
        made_occluders(self, parts)

    def parts(*args):
        made = made_parts(*args)
        alive.add("parts", made)
        return made

    def seeing(self, i, occluders):
        alive.count()
        see(self, i, occluders)

    def finishing(unit, prepared, evidence, *rest):
        alive.add("evidence", evidence)
        alive.count()
        return finish(unit, prepared, evidence, *rest)

    monkeypatch.setattr(footprints.FrameOccluders, "__init__", occluders_init)
    monkeypatch.setattr(lidar, "frame_footprints", parts)
    monkeypatch.setattr(RefinedTracks, "see", seeing)
    monkeypatch.setattr(annotate, "finish_clip", finishing)
    try:
        config = with_overrides(with_rules(RunConfig(), "refined"), [])
        units = [unit for unit in annotate.load_units(sample_split[0], SEGMENT, CAMERAS)]
        made = annotate.annotate_cameras(
            list(units), config.section(DriveTrackConfig), RunChoices.of(config, "drivetrack")
        )
    finally:
        monkeypatch.undo()
    return alive, units, made


def test_cameras_make_clips_over_many_frames(counted):
    _, _, made = counted
    clips = [clip for result in made for clip in result.clips]
    assert len({clip.unit for clip in clips}) >= 2
    assert sum(len(clip.frame_ids) for clip in clips) >= 2 * NUM_FRAMES


def test_footprints_stream_a_few_frames_at_a_time(counted):
    alive, _, _ = counted
    # Every frame's occluders at once would be 3 cameras x 40 frames, their parts 3 x 40 x 3 sweeps.
    assert len(alive.counts["occluders"]) >= NUM_FRAMES
    assert alive.most["occluders"] <= len(CAMERAS)
    assert alive.most["parts"] <= len(CAMERAS) * 3 * 3


def test_a_cameras_evidence_goes_once_its_clips_are_made(counted):
    alive, _, _ = counted
    evidence = alive.counts["evidence"]
    # Counted at each clip's finish: the camera finishing holds its own, the cameras before it none.
    assert len(evidence) >= 2
    assert max(evidence) == 1


def test_the_jpegs_read_go_once_the_frames_stored_are_made(counted):
    _, units, made = counted
    assert all(not isinstance(unit, Exception) and unit.frames.jpegs == [] for unit in units)
    assert all(clip.images_jpeg for result in made for clip in result.clips)
