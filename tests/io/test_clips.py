"""``pipeline.clips``: the README's example runs verbatim on a run's output; ``open`` hands over a clip's
arrays exactly as stored, read-only, and refuses what is not a clip without unpickling it; ``split``
follows the run's manifest. A run's clips also load with tapnet's own two loaders: the evaluator's
(``np.load(f, allow_pickle=True)``) and the Colab's (``np.load(f)``)."""

from __future__ import annotations

import contextlib
import io
import os
import re

import numpy as np
import pytest
from PIL import Image

import pipeline.clips
from benchmarks.hostile_inputs import savez_bytes, with_payload
from tests.support.cli import REPO

KEYS = ("images_jpeg_bytes", "queries_xyt", "tracks_XYZ", "visibility", "fx_fy_cx_cy")


def readme_example() -> str:
    """The README's one Python block."""
    with open(os.path.join(REPO, "README.md"), encoding="utf-8") as handle:
        (code,) = re.findall(r"^```python\n(.*?)^```", handle.read(), re.M | re.S)
    return code


def stored(path: str) -> dict[str, np.ndarray]:
    with np.load(path) as archive:
        return {key: archive[key] for key in archive.files}


def test_the_readme_example_runs_verbatim(reference_run, tmp_path, monkeypatch):
    """``out/demo`` stands for a finished run (the Panoptic Studio sample's)."""
    run = reference_run("pstudio")
    (tmp_path / "out").mkdir()
    os.symlink(run, tmp_path / "out" / "demo")
    monkeypatch.chdir(tmp_path)
    code = readme_example()
    assert len(code.strip().splitlines()) == 5
    printed, names = io.StringIO(), {}
    with contextlib.redirect_stdout(printed):
        exec(compile(code, "README.md", "exec"), names)  # the README's example, as written
    manifest = open(os.path.join(run, "manifests", "minival.txt")).read().split()
    expected = []
    for entry in manifest:
        arrays = stored(os.path.join(run, entry))
        name = entry.split("/")[1][: -len(".npz")]
        visible = arrays["visibility"].mean()
        expected.append(f"pstudio {name} {arrays['tracks_XYZ'].shape} {visible:.0%} visible")
    assert printed.getvalue().splitlines() == expected
    first = stored(os.path.join(run, "pstudio", "dome_3.npz"))["images_jpeg_bytes"][0]
    assert names["frame"].shape == (*Image.open(io.BytesIO(first)).size[::-1], 3)
    assert np.abs(names["frame"].astype(int) - np.asarray(Image.open(io.BytesIO(first)))).mean() < 1


@pytest.mark.parametrize("source", ["pstudio", "drivetrack"])
def test_open_hands_over_the_stored_arrays_read_only(reference_run, source):
    folder = os.path.join(reference_run(source), source)
    path = os.path.join(folder, sorted(os.listdir(folder))[0])
    arrays = stored(path)
    clip = pipeline.clips.open(path)
    assert (clip.name, clip.source) == (os.path.basename(path)[: -len(".npz")], source)
    assert clip.frames == tuple(arrays["images_jpeg_bytes"])
    assert all(frame[:2] == b"\xff\xd8" and frame[-2:] == b"\xff\xd9" for frame in clip.frames)
    for field, key in (("queries", "queries_xyt"), ("tracks", "tracks_XYZ"), ("visibility", "visibility")):
        assert np.array_equal(getattr(clip, field), arrays[key])
        assert getattr(clip, field).dtype == arrays[key].dtype
    assert clip.intrinsics.dtype == np.float64
    assert np.array_equal(clip.intrinsics, arrays["fx_fy_cx_cy"])
    assert (clip.num_frames, clip.num_tracks) == arrays["visibility"].shape
    if source == "pstudio":
        assert clip.extrinsics is None
    else:
        assert np.array_equal(clip.extrinsics, arrays["extrinsics_w2c"])
        assert clip.extrinsics.shape == (clip.num_frames, 4, 4)
    with pytest.raises(ValueError, match="read-only"):
        clip.tracks[0, 0, 0] = 1.0
    with pytest.raises(AttributeError):
        clip.name = "other"


def test_a_pickled_member_is_refused_and_never_loaded(reference_run, tmp_path):
    path = os.path.join(reference_run("pstudio"), "pstudio", "dome_3.npz")
    marker = tmp_path / "unpickled"
    hostile = tmp_path / "pstudio" / "dome_3.npz"
    hostile.parent.mkdir()
    hostile.write_bytes(savez_bytes(with_payload(stored(path), "tracks_XYZ", str(marker))))
    with pytest.raises(ValueError, match="would need pickle"):
        pipeline.clips.open(str(hostile))
    assert not marker.exists()
    bare = tmp_path / "bare.npz"
    np.savez(bare, queries_xyt=np.zeros((2, 3)))
    with pytest.raises(ValueError, match=f"{bare}: not a TAPVid-3D clip: keys: missing"):
        pipeline.clips.open(str(bare))


def test_split_follows_the_manifest_and_names_what_is_wrong(reference_run, tmp_path):
    run = reference_run("drivetrack")
    listed = open(os.path.join(run, "manifests", "full_test.txt")).read().split()
    names = [f"drivetrack/{clip.name}.npz" for clip in pipeline.clips.split(run, "full_eval")]
    assert names == listed  # full_eval, the release's name, reads full_test
    with pytest.raises(ValueError, match="split 'test': a run's splits are minival, full_test"):
        list(pipeline.clips.split(run, "test"))
    with pytest.raises(ValueError, match="no manifest of a run"):
        list(pipeline.clips.split(str(tmp_path), "minival"))
    (tmp_path / "manifests").mkdir()
    (tmp_path / "manifests" / "minival.txt").write_text("drivetrack/../../etc/passwd\n")
    with pytest.raises(ValueError, match="line 1: 'drivetrack/../../etc/passwd' is not <source>/<clip>.npz"):
        list(pipeline.clips.split(str(tmp_path), "minival"))


@pytest.mark.parametrize("source", ["pstudio", "drivetrack"])
def test_tapnets_loaders_read_a_runs_clips(reference_run, source):
    """The evaluator opens the file and reads five members with pickle allowed, frame 0's size from
    its JPEG; the Colab uses a plain np.load. Both see what pipeline.clips sees."""
    folder = os.path.join(reference_run(source), source)
    for name in sorted(os.listdir(folder)):
        path = os.path.join(folder, name)
        clip = pipeline.clips.open(path)
        with open(path, "rb") as handle:
            evaluator = np.load(handle, allow_pickle=True)
            frames, queries, tracks, visible, intrinsics = (evaluator[key] for key in KEYS)
        height, width = np.asarray(Image.open(io.BytesIO(frames[0])).convert("RGB")).shape[:2]
        assert (height, width) == clip.image(0).shape[:2] == clip.frame_size
        assert tracks.shape == (len(frames), len(queries), 3) and visible.shape == tracks.shape[:2]
        assert np.array_equal(tracks, clip.tracks) and np.array_equal(intrinsics, clip.intrinsics)
        with open(path, "rb") as handle, np.load(handle) as colab:
            assert all(key in colab.files for key in KEYS)
            loaded = {key: colab[key] for key in colab.files}
        assert list(loaded["images_jpeg_bytes"]) == list(clip.frames)
        assert np.array_equal(loaded["visibility"], clip.visibility)
        assert np.array_equal(loaded["queries_xyt"], queries)
