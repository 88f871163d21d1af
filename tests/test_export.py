"""The .npz writer, the validator (one broken invariant at a time), manifests, config."""

import json

import numpy as np
import pytest

from pipeline.core.config import RunConfig, with_overrides
from pipeline.export.files import write_atomic
from pipeline.export.manifests import load_official_splits, split_clips
from pipeline.export.npz_writer import encode_npz
from pipeline.export.validator import check_arrays, check_clip_bytes, load_clip

INTRINSICS = np.array([100.0, 100.0, 50.0, 50.0], np.float32)


def good_arrays(frames=3, tracks=4):
    rng = np.random.default_rng(1)
    xyz = np.concatenate(
        [rng.uniform(-1, 1, (frames, tracks, 2)), rng.uniform(2, 5, (frames, tracks, 1))], -1
    ).astype(np.float32)
    t_q = np.arange(tracks) % frames
    at_query = xyz[t_q, np.arange(tracks)].astype(np.float64)
    xy = at_query[:, :2] / at_query[:, 2:] * 100 + 50
    images = np.empty(frames, object)
    images[:] = [b"\xff\xd8fake" + bytes([i]) for i in range(frames)]
    return {
        "images_jpeg_bytes": images,
        "queries_xyt": np.concatenate([xy, t_q[:, None]], 1).astype(np.float32),
        "tracks_XYZ": xyz,
        "visibility": np.ones((frames, tracks), bool),
        "fx_fy_cx_cy": INTRINSICS,
        "extrinsics_w2c": np.tile(np.eye(4, dtype=np.float32), (frames, 1, 1)),
    }


def test_npz_round_trip_and_bytes_are_reproducible():
    arrays = good_arrays()
    data = encode_npz(arrays)
    assert data == encode_npz(good_arrays())
    loaded = load_clip(data)
    assert sorted(loaded) == sorted(arrays)
    np.testing.assert_array_equal(loaded["tracks_XYZ"], arrays["tracks_XYZ"])
    assert list(loaded["images_jpeg_bytes"]) == list(arrays["images_jpeg_bytes"])
    assert check_clip_bytes(data, "drivetrack") == []


def _break(name):
    arrays = good_arrays()
    if name == "query_off":
        arrays["queries_xyt"][0, 0] += 0.6
    elif name == "hidden_at_query":
        arrays["visibility"][0, 0] = False
    elif name == "behind":
        arrays["tracks_XYZ"][:, 1, 2] *= -1
    elif name == "nan":
        arrays["tracks_XYZ"][2, 3, 0] = np.nan
    elif name == "no_tracks":
        arrays = good_arrays(tracks=0)
    elif name == "wrong_frames":
        arrays["images_jpeg_bytes"] = arrays["images_jpeg_bytes"][:2]
    elif name == "missing_key":
        del arrays["extrinsics_w2c"]
    elif name == "dtype":
        arrays["tracks_XYZ"] = arrays["tracks_XYZ"].astype(np.float64)
    elif name == "query_frame":
        arrays["queries_xyt"][1, 2] = 7.0
    return arrays


@pytest.mark.parametrize(
    "name, words",
    [
        ("query_off", "px from their track's projection"),
        ("hidden_at_query", "not visible at their query frame"),
        ("behind", "z <= 0"),
        ("nan", "non-finite"),
        ("no_tracks", "N = 0"),
        ("wrong_frames", "tracks_XYZ shape"),
        ("missing_key", "missing ['extrinsics_w2c']"),
        ("dtype", "tracks_XYZ: dtype float64"),
        ("query_frame", "not a frame index"),
    ],
)
def test_validator_names_each_broken_invariant(name, words):
    problems = check_arrays(_break(name), "drivetrack")
    assert any(words in p for p in problems), problems


def test_pstudio_clips_have_no_extrinsics():
    arrays = good_arrays()
    assert (
        check_arrays(arrays, "pstudio")
        and "unexpected ['extrinsics_w2c']" in check_arrays(arrays, "pstudio")[0]
    )
    del arrays["extrinsics_w2c"]
    assert check_arrays(arrays, "pstudio") == []


def test_unreadable_file_is_a_problem_not_a_crash():
    assert "unreadable" in check_clip_bytes(b"not a zip", "adt")[0]


def test_atomic_write_replaces_and_leaves_no_partial(tmp_path):
    path = str(tmp_path / "sub" / "a.npz")
    write_atomic(path, b"one")
    write_atomic(path, b"two")
    assert open(path, "rb").read() == b"two"
    assert sorted(p.name for p in (tmp_path / "sub").iterdir()) == ["a.npz"]


def test_manifests_follow_official_membership_when_names_match():
    official = load_official_splits(
        json.dumps({"minival": {"drivetrack": ["b.npz"]}, "full_eval": {"drivetrack": ["a.npz", "c.npz"]}})
    )
    minival, full_test = split_clips({"drivetrack": ["a.npz", "b.npz", "c.npz"]}, 50, 0, official)
    assert minival == ["drivetrack/b.npz"] and full_test == ["drivetrack/a.npz", "drivetrack/c.npz"]


def test_manifests_draw_a_deterministic_minival_otherwise():
    names = [f"clip{i:03d}.npz" for i in range(120)]
    minival, full_test = split_clips({"drivetrack": names}, 50, 0)
    assert len(minival) == 50 and len(full_test) == 70 and not set(minival) & set(full_test)
    assert split_clips({"drivetrack": list(reversed(names))}, 50, 0) == (minival, full_test)
    assert split_clips({"drivetrack": names}, 50, 1)[0] != minival


def test_config_overrides_are_typed_and_checked():
    config = with_overrides(
        RunConfig(),
        ["flicker.max_fraction=0.2", "drivetrack.cameras=1,3", "drivetrack.facing_test=false", "seed=4"],
    )
    assert config.flicker.max_fraction == 0.2 and config.drivetrack.cameras == (1, 3)
    assert config.drivetrack.facing_test is False and config.seed == 4
    with pytest.raises(ValueError, match="unknown setting; valid keys:.*flicker.max_fraction"):
        with_overrides(RunConfig(), ["flicker.maxfraction=1"])
    with pytest.raises(ValueError, match="expected float"):
        with_overrides(RunConfig(), ["flicker.max_fraction=lots"])
    assert json.loads(json.dumps(config.to_dict()))["drivetrack"]["mask_min_agreement"] == 0.5
