"""The .npz writer, the validator (one broken invariant at a time), manifests, config."""

import io
import json
import zipfile

import cv2
import numpy as np
import pytest

from pipeline.drivetrack.settings import DriveTrackConfig
from pipeline.export.invariants import check_arrays, check_clip_bytes
from pipeline.export.manifests import split_clips
from pipeline.export.npz_writer import FixedWidthBytes, encode_npz
from pipeline.io.clip_reader import read_clip_bytes
from pipeline.io.files import write_atomic
from pipeline.runner.splits import parse_release
from pipeline.settings.fields import with_overrides
from pipeline.settings.run_config import RunConfig

INTRINSICS = np.array([100.0, 100.0, 50.0, 50.0])


def jpeg(value: int, width: int = 100, height: int = 100) -> bytes:
    return cv2.imencode(".jpg", np.full((height, width, 3), value, np.uint8))[1].tobytes()


def good_arrays(frames=3, tracks=4):
    rng = np.random.default_rng(1)
    xyz = np.concatenate(
        [rng.uniform(-1, 1, (frames, tracks, 2)), rng.uniform(2, 5, (frames, tracks, 1))], -1
    ).astype(np.float32)
    t_q = np.arange(tracks) % frames
    at_query = xyz[t_q, np.arange(tracks)].astype(np.float64)
    xy = at_query[:, :2] / at_query[:, 2:] * 100 + 50
    return {
        "images_jpeg_bytes": np.array([jpeg(10 * i) for i in range(frames)]),
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
    loaded = read_clip_bytes(data, "clip")
    assert sorted(loaded) == sorted(arrays)
    np.testing.assert_array_equal(loaded["tracks_XYZ"], arrays["tracks_XYZ"])
    assert list(loaded["images_jpeg_bytes"]) == list(arrays["images_jpeg_bytes"])
    assert loaded["images_jpeg_bytes"].dtype.kind == "S"
    assert loaded["fx_fy_cx_cy"].dtype == np.float64
    assert check_clip_bytes(data) == []


def savez_recipe(arrays: dict, compress: bool) -> bytes:
    """What ``np.savez`` does, with the fixed timestamp: each member saved by ``np.save`` to bytes,
    then stored (or deflated) whole with ``ZipFile.writestr``."""
    buffer = io.BytesIO()
    method = zipfile.ZIP_DEFLATED if compress else zipfile.ZIP_STORED
    with zipfile.ZipFile(buffer, "w", compression=method, allowZip64=True) as archive:
        for key in sorted(arrays):
            member = io.BytesIO()
            np.save(member, arrays[key], allow_pickle=False)
            info = zipfile.ZipInfo(f"{key}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type, info.external_attr = method, 0o644 << 16
            archive.writestr(info, member.getvalue())
    return buffer.getvalue()


@pytest.mark.parametrize("compress", [False, True])
def test_members_streamed_into_the_archive_give_the_savez_recipes_bytes(compress):
    """Members written straight into the zip (no copy of their own) give the bytes of saving
    each to a buffer and storing that: same headers, sizes and CRCs, for arrays written in one
    piece, in several (over the 16 MiB that ``np.save`` writes at a time) and Fortran-ordered."""
    rng = np.random.default_rng(3)
    arrays = {
        **good_arrays(),
        "big": rng.integers(0, 4000, (9, 1000, 1000)).astype(np.uint16),  # 18 MB
        "fortran": np.asfortranarray(rng.random((5, 7))),
        "scalar": np.array(2.5),
        "empty": np.zeros((0, 3), np.float32),
    }
    assert encode_npz(arrays, compress) == savez_recipe(arrays, compress)


FRAME_LISTS = [[], [b""], [b"ab", b"c", b"\xff\xd9"], [b"\x00x\x00", b"y\x00"], [bytes(range(256)) * 3, b"z"]]


@pytest.mark.parametrize("items", FRAME_LISTS)
def test_frames_array_is_what_numpy_makes_of_the_list(items):
    """The release's frames array: what ``np.savez`` makes of a list of bytes, byte for byte."""
    ours, numpys = FixedWidthBytes(items).array(), np.array(items, dtype=np.bytes_)
    assert ours.dtype == numpys.dtype
    assert ours.shape == numpys.shape
    assert ours.tobytes() == numpys.tobytes()


@pytest.mark.parametrize("compress", [False, True])
def test_frames_written_item_by_item_give_the_savez_recipes_bytes(compress):
    """Frames padded as they are written into the archive (no array built) give the bytes of
    ``np.savez`` of the list, for each list above and for JPEG-sized frames."""
    rng = np.random.default_rng(4)
    jpegs = [rng.integers(0, 256, size, np.uint8).tobytes() for size in (700_000, 650_123, 699_999)]
    for items in [*FRAME_LISTS, jpegs]:
        ours = {"images_jpeg_bytes": FixedWidthBytes(items), "x": np.arange(3)}
        numpys = {"images_jpeg_bytes": np.array(items, dtype=np.bytes_), "x": np.arange(3)}
        assert encode_npz(ours, compress) == savez_recipe(numpys, compress)


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
        del arrays["visibility"]
    elif name == "dtype":
        arrays["tracks_XYZ"] = arrays["tracks_XYZ"].astype(np.float16)
    elif name == "negative_focal":
        arrays["fx_fy_cx_cy"] = INTRINSICS * [-1, 1, 1, 1]
    elif name == "query_outside":
        arrays["queries_xyt"][2, 0] = -0.25
        arrays["tracks_XYZ"][2, 2, 0] = -0.5025 * arrays["tracks_XYZ"][2, 2, 2]
    elif name == "frame_size":
        arrays["images_jpeg_bytes"] = np.array([jpeg(0), jpeg(0, width=99), jpeg(0)])
    elif name == "not_jpeg":
        arrays["images_jpeg_bytes"] = np.array([jpeg(0), b"\xff\xd8fake", jpeg(0)])
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
        ("missing_key", "missing ['visibility']"),
        ("dtype", "tracks_XYZ: dtype float16"),
        ("negative_focal", "focal lengths [-100.0, 100.0] must be positive"),
        ("query_outside", "1 query point(s) outside the 100x100 frame"),
        ("frame_size", "images_jpeg_bytes[1]: 99x100 pixels, frame 0 is 100x100"),
        ("not_jpeg", "images_jpeg_bytes[1]: not JPEG bytes"),
        ("query_frame", "not a frame index"),
    ],
)
def test_validator_names_each_broken_invariant(name, words):
    problems = check_arrays(_break(name))
    assert any(words in p for p in problems), problems


def test_validator_accepts_the_release_variants():
    """float64 geometry, no extrinsics (the release's ADT files), extra keys: all valid."""
    arrays = good_arrays()
    assert check_arrays(arrays) == []
    del arrays["extrinsics_w2c"]
    arrays.update(tracks_XYZ=arrays["tracks_XYZ"].astype(np.float64), extra=np.zeros(3))
    assert check_arrays(arrays) == []
    assert check_clip_bytes(encode_npz(arrays)) == []


def test_unreadable_file_is_a_problem_not_a_crash():
    assert "not an .npz archive" in check_clip_bytes(b"not a zip")[0]


def test_atomic_write_replaces_and_leaves_no_partial(tmp_path):
    path = str(tmp_path / "sub" / "a.npz")
    write_atomic(path, b"one")
    write_atomic(path, b"two")
    assert open(path, "rb").read() == b"two"
    assert sorted(p.name for p in (tmp_path / "sub").iterdir()) == ["a.npz"]


def test_manifests_follow_official_membership_when_names_match():
    official = parse_release(
        json.dumps({"minival": {"drivetrack": ["b.npz"]}, "full_eval": {"drivetrack": ["a.npz", "c.npz"]}})
    )
    minival, full_test = split_clips({"drivetrack": ["a.npz", "b.npz", "c.npz"]}, 50, 0, official.clips)
    assert minival == ["drivetrack/b.npz"]
    assert full_test == ["drivetrack/a.npz", "drivetrack/c.npz"]


def test_manifests_draw_a_deterministic_minival_otherwise():
    names = [f"clip{i:03d}.npz" for i in range(120)]
    minival, full_test = split_clips({"drivetrack": names}, 50, 0)
    assert len(minival) == 50
    assert len(full_test) == 70
    assert not set(minival) & set(full_test)
    assert split_clips({"drivetrack": list(reversed(names))}, 50, 0) == (minival, full_test)
    assert split_clips({"drivetrack": names}, 50, 1)[0] != minival


def test_config_overrides_are_typed_and_checked():
    config = with_overrides(
        RunConfig(),
        ["flicker.max_fraction=0.2", "drivetrack.cameras=1,3", "drivetrack.facing_test=false", "seed=4"],
    )
    assert config.flicker.max_fraction == 0.2
    assert config.section(DriveTrackConfig).cameras == (1, 3)
    assert config.section(DriveTrackConfig).facing_test is False
    assert config.seed == 4
    expected = r"unknown setting; did you mean flicker.max_fraction\? every key: docs/configuration.md$"
    with pytest.raises(ValueError, match=expected):
        with_overrides(RunConfig(), ["flicker.maxfraction=1"])
    with pytest.raises(ValueError, match="expected float"):
        with_overrides(RunConfig(), ["flicker.max_fraction=lots"])
    assert json.loads(json.dumps(config.to_dict()))["drivetrack"]["mask_min_agreement"] == 0.5
