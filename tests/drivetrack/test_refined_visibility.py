"""DriveTrack's refined visibility (``drivetrack.refined_visibility``) against ray-cast truth, on the
sample world and on the worlds of tests/support/stress_worlds.py: every clip and every world agrees
with the truth, the flicker filter drops about what it drops under the true visibility, brief true
occlusions stay, and each part of the method is needed for that (one part on a world of
tests/support/driving_family.py, where a truck taller than the lidar's highest beam crosses in front
of a parked one)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from pipeline.drivetrack import footprints, lidar, object_surface, tracks
from pipeline.drivetrack.sample.waymo_world import SEGMENT
from pipeline.export.shard_rows import track_quality
from pipeline.filters.flicker import passes_flicker, visibility_flips
from pipeline.settings.fields import with_overrides
from pipeline.settings.run_config import RunConfig
from tests.support import driving_family, stress_worlds
from tests.support.units import drivetrack_segment_clips
from tests.support.waymo_truth import true_tracks

REFINED = ["drivetrack.refined_visibility=true"]
# The family's world where a truck's top, above the lidar's highest beam, hides another truck.
TALL_TRUCK_SEED = 0
CLIP_AGREEMENT, WORLD_AGREEMENT, FLICKER_POINTS = 0.985, 0.99, 0.03


@dataclasses.dataclass(frozen=True)
class Scored:
    """One clip and its truth: tracks [T, N, 3], stored-frame pixels [T, N, 2], visibility [T, N]."""

    camera: int
    clip: object
    tracks: np.ndarray
    pixels: np.ndarray
    visible: np.ndarray


def scored_clips(split: str, segment: str, world, overrides: list[str], cameras=(1, 2, 3)) -> list[Scored]:
    """The clips of a world's segment made with ``overrides``, each with its ray-cast truth."""
    config = with_overrides(RunConfig(), overrides)
    scored = []
    for camera, clips in drivetrack_segment_clips(split, segment, cameras, config).items():
        for clip in clips:
            tracks, pixels, _, visible, _ = true_tracks(world, clip, camera)
            scored.append(Scored(camera, clip, tracks, pixels, visible))
    return scored


def agreement(scored: list[Scored]) -> float:
    """Share of the (frame, track) pairs of the clips whose visibility is the truth's."""
    agree = sum(int((s.visible == s.clip.visibility).sum()) for s in scored)
    return agree / sum(s.visible.size for s in scored)


def flicker_dropped(scored: list[Scored], truth: bool) -> float:
    """Share of the candidates the flicker filter drops, on the clips' visibility or the truth's."""
    max_fraction = RunConfig().flicker.max_fraction
    dropped = [
        ~passes_flicker(
            visibility_flips(s.visible if truth else s.clip.visibility), s.clip.num_frames, max_fraction
        )
        for s in scored
    ]
    return float(np.concatenate(dropped).mean())


def world_clips(
    name: str, sample_split, stress_split, family_split, world, cameras=(1, 2, 3)
) -> list[Scored]:
    """The refined clips of a world (``sample``, a stress world's name or ``family``: the family's
    TALL_TRUCK_SEED world) with their truth."""
    if name == "sample":
        return scored_clips(sample_split[0], SEGMENT, world, REFINED, cameras)
    if name == "family":
        overrides = REFINED + driving_family.OVERRIDES
        family_world, _ = driving_family.family_world(TALL_TRUCK_SEED)
        split = family_split(TALL_TRUCK_SEED)
        return scored_clips(split, driving_family.SEGMENT, family_world, overrides, cameras)
    make_world, _ = stress_worlds.WORLDS[name]
    overrides = REFINED + stress_worlds.OVERRIDES
    return scored_clips(stress_split(name), stress_worlds.SEGMENT, make_world(), overrides, cameras)


@pytest.fixture(scope="module")
def worlds(sample_split, stress_split, family_split, world) -> dict[str, list[Scored]]:
    """World name -> its refined clips with their truth: each world's segment annotated once."""
    made = {
        name: world_clips(name, sample_split, stress_split, family_split, world)
        for name in ["sample", *stress_worlds.WORLDS]
    }
    # The family's world: its FRONT camera's clips (its tall truck's among them) are enough here.
    made["family"] = world_clips("family", sample_split, stress_split, family_split, world, (1,))
    return made


@pytest.mark.parametrize("name", ["sample", *stress_worlds.WORLDS])
def test_every_clip_agrees_with_the_truth(worlds, name):
    assert len(worlds[name]) >= 3, f"{name}: the world should make several clips"
    for s in worlds[name]:
        score = agreement([s])
        assert score >= CLIP_AGREEMENT, f"{name} {s.clip.name}: visibility agrees on {score:.4f}"


@pytest.mark.parametrize("name", ["sample", *stress_worlds.WORLDS])
def test_every_world_agrees_with_the_truth(worlds, name):
    score = agreement(worlds[name])
    assert score >= WORLD_AGREEMENT, f"{name}: visibility agrees on {score:.4f}"


@pytest.mark.parametrize("name", ["sample", *stress_worlds.WORLDS])
def test_the_flicker_filter_drops_what_it_drops_under_the_truth(worlds, name):
    ours, truth = flicker_dropped(worlds[name], truth=False), flicker_dropped(worlds[name], truth=True)
    assert abs(ours - truth) <= FLICKER_POINTS, (
        f"{name}: flicker drops {ours:.3f}, under the truth {truth:.3f}"
    )


@pytest.mark.parametrize("name", ["sample", *stress_worlds.WORLDS, "family"])
def test_tracks_and_queries_follow_the_true_surface_points(worlds, name):
    for s in worlds[name]:
        error = np.linalg.norm(s.tracks - s.clip.tracks_xyz, axis=2).max()
        assert error < 0.01, f"{s.clip.name}: worst track error {error:.4f} m"
        queried = np.flatnonzero(np.isfinite(s.clip.queries_xyt[:, 2]))
        t_q = s.clip.queries_xyt[queried, 2].astype(int)
        miss = np.linalg.norm(s.pixels[t_q, queried] - s.clip.queries_xyt[queried, :2], axis=1)
        assert miss.max() < 0.01, f"{s.clip.name}: worst query {miss.max():.4f} px from the truth"
        assert s.clip.visibility[t_q, queried].all()


def brief_occlusions(visible: np.ndarray) -> np.ndarray:
    """[T, N] bool: frames of runs of one or two occluded frames with a visible frame on each side."""
    brief = np.zeros_like(visible)
    for length in (1, 2):
        for start in range(1, len(visible) - length):
            hidden = ~visible[start : start + length].any(axis=0)
            around = visible[start - 1] & visible[start + length]
            brief[start : start + length] |= hidden & around
    return brief


def test_brief_true_occlusions_stay_occluded(worlds):
    """The pole and the running pedestrian hide points of the parked car for one or two frames: those
    frames stay occluded, where filling short gaps between visible frames would make them visible."""
    (target,) = [s for s in worlds["brief"] if "parked_target" in s.clip.name]
    brief = brief_occlusions(target.visible)
    assert brief.sum() >= 100, "the pole and the runner should briefly hide many of the car's points"
    kept = (~target.clip.visibility[brief]).mean()
    assert kept >= 0.9, f"only {kept:.1%} of the brief true occlusions stay occluded"


def without_neighbour_sweeps(monkeypatch):
    """Each frame's own sweep alone covers its track points."""
    monkeypatch.setattr(footprints, "SOURCE_WEIGHTS", {-1: 0.0, 0: 1.0, 1: 0.0})


def without_own_surface(monkeypatch):
    """Nothing of its own object hides a track point (only its facing away)."""
    monkeypatch.setattr(
        object_surface.OwnSurface, "hides", lambda self, points, rays, clearance: np.zeros(len(points), bool)
    )


def without_fitted_normals(monkeypatch):
    """Each track point's range-image normal (its own sweep's neighbours) decides its facing."""
    monkeypatch.setattr(tracks, "track_normals", lambda pool, chosen: pool.normals[chosen])


def without_box_limits(monkeypatch):
    """A labelled object's footprints reach past its box."""
    monkeypatch.setattr(footprints, "MIN_LIMIT", 1.0)


def without_reach_past_the_field_of_view(monkeypatch):
    """A labelled object's returns on the lidar's highest and lowest beams reach no further than
    any other's: the object's surface that only the camera sees counts for nothing."""
    monkeypatch.setattr(lidar, "field_edge_rows", lambda rows, height: np.zeros(len(rows), np.int64))


# part removed -> (world, camera, clip) where the part matters.
NEEDED_WHERE = {
    without_neighbour_sweeps: ("brief", 3, "parked_target"),
    without_own_surface: ("sample", 3, "parked_right"),
    without_fitted_normals: ("sample", 1, "crossing_car"),
    without_box_limits: ("fast", 1, "far_parked"),
    without_reach_past_the_field_of_view: ("family", 1, "truck1"),
}


@pytest.mark.parametrize("remove", list(NEEDED_WHERE), ids=lambda remove: remove.__name__)
def test_each_part_of_the_method_is_needed(
    worlds, sample_split, stress_split, family_split, world, monkeypatch, remove
):
    """With one part of the method removed, a clip where that part matters misses the target the
    whole method meets."""
    name, camera, object_name = NEEDED_WHERE[remove]
    (whole,) = [s for s in worlds[name] if s.camera == camera and object_name in s.clip.name]
    remove(monkeypatch)
    partial = world_clips(name, sample_split, stress_split, family_split, world, (camera,))
    (partial,) = [s for s in partial if object_name in s.clip.name]
    with_part, without = agreement([whole]), agreement([partial])
    assert without < CLIP_AGREEMENT <= with_part, (
        f"{object_name}: {without:.4f} without, {with_part:.4f} with"
    )


@pytest.mark.parametrize("name", ["brief", "fast", "family"])
def test_steady_tracks_are_the_ones_the_visibility_gets_right(worlds, name):
    """A training shard's per-track ``quality`` (steadiness, ``shard_rows.track_quality``): the
    candidates that never flip agree with the ray-cast truth on at least 99.5% of their frames."""
    agree = total = 0
    for s in worlds[name]:
        steady = track_quality(s.clip.visibility) == 1.0
        agree += int((s.clip.visibility[:, steady] == s.visible[:, steady]).sum())
        total += int(steady.sum()) * s.clip.num_frames
    assert total > 0 and agree / total >= 0.995, f"{name}: {agree / max(total, 1):.4f}"
