"""Panoptic Studio clips of the sample world against its analytic truth."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.core.geometry import invert_se3, project, transform_points
from pipeline.export.invariants import check_arrays
from pipeline.export.npz_writer import clip_arrays
from pipeline.filters.select import apply_filters
from pipeline.pstudio.sample.studio_world import FRAMES
from pipeline.pstudio.settings import PstudioConfig
from pipeline.pstudio.tracks import candidate_clip, multiview_mask_fraction
from pipeline.pstudio.units import list_units
from pipeline.settings.run_config import RunConfig
from pipeline.sources import RunChoices
from tests.support.units import pstudio_input


@pytest.fixture(scope="module")
def clips(pstudio_sample):
    """Per camera: (camera, candidate clip, filtered clip, filter outcome, unit input)."""
    root, studio = pstudio_sample
    config = RunConfig()
    result = []
    for unit in list_units(root, config).units:
        unit_input = pstudio_input(root, unit.sequence, unit.camera, config)
        settings = config.section(PstudioConfig)
        clip = candidate_clip(unit_input, settings, RunChoices.of(config, "pstudio"))
        kept, outcome = apply_filters(clip, config, settings.mask_min_agreement)
        camera = next(c for c in studio.cameras if c.camera_id == unit.camera)
        result.append((camera, clip, kept, outcome, unit_input))
    return result


def attached_gaussian(studio, camera, clip) -> np.ndarray:
    """Per track, the Gaussian whose true position is nearest the track at its query frame
    (found from the world's truth, not from the pipeline's records) [N]."""
    found = np.empty(clip.num_tracks, np.int64)
    for i, (_, _, t) in enumerate(clip.queries_xyt):
        world = transform_points(invert_se3(camera.w2c), clip.tracks_xyz[int(t), i])
        found[i] = np.argmin(np.linalg.norm(studio.gaussian_positions(int(t)) - world, axis=1))
    return found


def test_tracks_follow_the_attached_material_point(pstudio_sample, clips):
    _, studio = pstudio_sample
    truth = np.stack([studio.gaussian_positions(t) for t in range(FRAMES)])
    worst = 0.0
    for camera, _, kept, _, _ in clips:
        gaussians = attached_gaussian(studio, camera, kept)
        np.testing.assert_array_equal(gaussians, kept.track_stats.extra["gaussian_index"])
        assert studio.foreground[gaussians].all()
        expected = truth[:, gaussians] @ camera.w2c[:3, :3].T + camera.w2c[:3, 3]
        worst = max(worst, np.abs(kept.tracks_xyz - expected).max())
        # The deforming and moving bodies are there: tracks really move.
        assert np.linalg.norm(expected[-1] - expected[0], axis=-1).max() > 0.2
    assert worst < 0.01


def test_queries_sit_on_the_visible_surface(clips):
    for _, clip, kept, _, _ in clips:
        assert not check_arrays(clip_arrays(kept))
        # Attachments farther than pstudio.max_attach_distance_m (blended depth at silhouettes)
        # are refused; most unprojected query points lie within a splat width of their Gaussian.
        distance = clip.track_stats.extra["attach_distance_m"]
        assert distance.max() <= 0.03
        assert np.median(distance) < 0.015
        assert kept.num_tracks == 50


def test_visibility_agrees_with_ray_cast_truth(pstudio_sample, clips):
    _, studio = pstudio_sample
    agree = total = hidden = 0
    for camera, _, kept, _, _ in clips:
        truth = studio.true_visibility(camera, kept.track_stats.extra["gaussian_index"])
        agree += int((truth == kept.visibility).sum())
        hidden += int((~truth).sum())
        total += truth.size
    assert agree / total >= 0.97, agree / total
    # Both states occur: bodies turn away and pass behind one another.
    assert hidden / total > 0.05


def test_mask_filter_drops_the_planted_floaters(pstudio_sample, clips):
    _, studio = pstudio_sample
    names = np.array(studio.part_names)[studio.part_of_gaussian]
    floaters_seen = 0
    for _, clip, kept, outcome, _ in clips:
        on_floater = names[clip.track_stats.extra["gaussian_index"]] == "floaters"
        floaters_seen += int(on_floater.sum())
        assert not outcome.verdicts["mask"][on_floater].any()
        assert outcome.verdicts["mask"][~on_floater].mean() > 0.97
        assert (names[kept.track_stats.extra["gaussian_index"]] != "floaters").all()
    assert floaters_seen > 0  # camera 8 sees the floaters over the box and samples them


def test_multiview_fraction_of_planted_tracks(pstudio_sample, clips):
    """Gaussians placed by hand: body surface points lie on most views' masks, floaters and
    floor points (foreground or not) on few."""
    _, studio = pstudio_sample
    unit_input = clips[0][4]
    names = np.array(studio.part_names)[studio.part_of_gaussian]
    picks = {
        name: np.nonzero(names == name)[0][::50][:10] for name in ("rigid", "deforming", "floaters", "floor")
    }
    fractions = {name: multiview_mask_fraction(unit_input, index) for name, index in picks.items()}
    # Body points seen from behind still project inside that view's silhouette (points on a
    # view's limb may round to a pixel just outside it).
    for body in ("rigid", "deforming"):
        assert (fractions[body] >= 0.8).all()
        assert fractions[body].mean() >= 0.9
    assert (fractions["floaters"] < 0.75).all()
    assert (fractions["floor"] < 0.5).all()  # behind a body, some views see it in its silhouette


def test_static_cameras_and_no_extrinsics(clips):
    for camera, _, kept, _, unit_input in clips:
        assert kept.extrinsics_w2c is None
        assert "extrinsics_w2c" not in clip_arrays(kept)
        np.testing.assert_allclose(kept.fx_fy_cx_cy, camera.fx_fy_cx_cy)
        assert kept.name == f"dome_{camera.camera_id}"
        assert kept.images_jpeg == unit_input.frames_jpeg
        pixels = project(
            kept.tracks_xyz[kept.queries_xyt[:, 2].astype(int), np.arange(kept.num_tracks)], kept.fx_fy_cx_cy
        )
        np.testing.assert_allclose(pixels, kept.queries_xyt[:, :2], atol=1e-6)


def test_a_sequences_cameras_share_one_read_and_make_the_same_clips(clips, pstudio_sample, monkeypatch):
    """The graph's group (``annotate_group``): params.npz is read once for every camera, each
    mask decoded at most once, and every clip is the one its camera makes alone."""
    import pipeline.pstudio.annotate as source
    import pipeline.pstudio.reader as reader
    from pipeline.pstudio import mask_cache

    root, _ = pstudio_sample
    reads, decodes = [], []
    read_gaussians, decode = source.read_gaussians, mask_cache.decode_image

    def counted_read(*args):
        reads.append(args)
        return read_gaussians(*args)

    def counted_decode(data, *args, **kwargs):
        decodes.append(bytes(data))
        return decode(data, *args, **kwargs)

    monkeypatch.setattr(source, "read_gaussians", counted_read)
    monkeypatch.setattr(mask_cache, "decode_image", counted_decode)
    monkeypatch.setattr(reader, "MASKS", mask_cache.MaskCache())  # cold, as in a fresh worker
    units = list_units(root, RunConfig()).units
    grouped = list(source.annotate_group(root, units, RunConfig(), [None] * len(units)))
    assert len(reads) == 1
    assert len(decodes) == len(set(decodes)) > 0
    for (_, alone, _, _, _), (together,) in zip(clips, [made.clips for made in grouped], strict=True):
        assert together.name == alone.name
        assert together.images_jpeg == alone.images_jpeg
        for field in ("tracks_xyz", "visibility", "queries_xyt", "extrinsics_w2c"):
            np.testing.assert_array_equal(getattr(together, field), getattr(alone, field))
        np.testing.assert_array_equal(together.track_stats.mask_agreement, alone.track_stats.mask_agreement)
