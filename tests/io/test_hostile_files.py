"""Files from strangers: the release's byte format both ways, no reader ever unpickles, and bombs
are refused before anything is allocated (benchmarks/hostile_inputs.py makes the files).

A payload member creates a marker file when unpickled; every test here asserts no marker exists.
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import re
import shutil
import stat
import subprocess
import sys
import warnings
import zipfile

import numpy as np
import pytest
from PIL import Image

from benchmarks.hostile_inputs import bomb_clip, savez_bytes, shape_bomb_clip, with_payload
from pipeline.audit.compare import main as compare_main
from pipeline.core.errors import InputError
from pipeline.io.clip_reader import read_clip_bytes
from pipeline.io.given_queries import given_queries
from pipeline.io.npz_reader import NpzError
from pipeline.runner.command import main as run_main
from pipeline.validate import main as validate_main
from pipeline.viz.__main__ import main as viz_main
from tests.support.cli import REPO


def clip_files(out: str, source: str) -> list[str]:
    folder = os.path.join(out, source)
    return sorted(os.path.join(folder, name) for name in os.listdir(folder) if name.endswith(".npz"))


def plain_load(path: str) -> dict[str, np.ndarray]:
    """The TAPVid-3D Colab's read: ``np.load(f)``, no pickle, every member."""
    with open(path, "rb") as handle:
        archive = np.load(handle)
        return {key: archive[key] for key in archive.files}


@pytest.mark.parametrize("source", ["pstudio", "drivetrack"])
def test_our_clips_open_as_the_colab_and_the_evaluator_open_them(reference_run, source):
    for path in clip_files(reference_run(source), source):
        arrays = plain_load(path)
        assert arrays["images_jpeg_bytes"].dtype.kind == "S"
        assert arrays["fx_fy_cx_cy"].dtype == np.float64
        assert not any(array.dtype.hasobject for array in arrays.values())
        sizes = {
            np.array(Image.open(io.BytesIO(frame)).convert("RGB")).shape
            for frame in arrays["images_jpeg_bytes"]
        }
        assert len(sizes) == 1  # every frame decodes, all of one size
        # tapnet's evaluate_model.py: np.load(f, allow_pickle=True), then PIL on frame 0's bytes.
        with open(path, "rb") as handle:
            evaluator = np.load(handle, allow_pickle=True)
            height, width = np.array(
                Image.open(io.BytesIO(evaluator["images_jpeg_bytes"][0])).convert("RGB")
            ).shape[:2]
            assert (height, width, 3) in sizes
            assert evaluator["tracks_XYZ"].shape[:2] == evaluator["visibility"].shape


def release_style_files(pstudio_clip: str, folder) -> None:
    """Files written exactly as tapnet's generators write them, from one of our clips' arrays:
    ``adt_utils.py`` (float64 tracks, intrinsics from Python numbers, no extrinsics, frames a list
    of bytes) and ``generate_pstudio.py`` (the downloaded annotation's members, extra ones included,
    plus the frames as a list of bytes); both through ``np.savez``."""
    ours = plain_load(pstudio_clip)
    fx, fy, cx, cy = (float(v) for v in ours["fx_fy_cx_cy"])
    frames = [bytes(frame) for frame in ours["images_jpeg_bytes"]]
    (folder / "adt").mkdir(parents=True)
    example = {
        "images_jpeg_bytes": frames,
        "queries_xyt": ours["queries_xyt"],
        "tracks_XYZ": ours["tracks_XYZ"].astype(np.float64),
        "visibility": ours["visibility"],
        "fx_fy_cx_cy": np.array([fx, fy, cx, cy]),
    }
    np.savez(folder / "adt" / "release_adt_0.npz", **example)
    (folder / "pstudio").mkdir()
    annotation = {key: ours[key] for key in ("queries_xyt", "tracks_XYZ", "visibility", "fx_fy_cx_cy")}
    annotation["tracks_XYZ_hash"] = np.array("0f" * 16)
    example = dict(annotation)
    example["images_jpeg_bytes"] = frames
    np.savez(folder / "pstudio" / "release_pstudio.npz", **example)


def test_files_written_as_the_release_writes_them_validate(reference_run, tmp_path, capsys):
    release = tmp_path / "release"
    release_style_files(clip_files(reference_run("pstudio"), "pstudio")[0], release)
    assert validate_main([str(release)]) == 0
    assert "2 clip(s) checked, 2 valid" in capsys.readouterr().out
    assert compare_main([str(release), str(release), "--out", str(tmp_path / "self")]) == 0
    rows = json.loads((tmp_path / "self.json").read_text())["clips"]
    assert len(rows) == 2
    assert all(row["aj_none"] == 1.0 for row in rows)


@pytest.fixture
def hostile(reference_run, tmp_path):
    """(folder of pstudio clips: the first good, the others each carrying a pickle payload in one
    member; the markers that would prove a payload ran)."""
    paths = clip_files(reference_run("pstudio"), "pstudio")
    folder = tmp_path / "hostile" / "pstudio"
    folder.mkdir(parents=True)
    shutil.copy(paths[0], folder)
    markers = []
    for path, key in zip(paths[1:], ("images_jpeg_bytes", "queries_xyt", "tracks_XYZ"), strict=True):
        markers.append(tmp_path / f"marker_{key}")
        arrays = with_payload(plain_load(path), key, str(markers[-1]))
        (folder / os.path.basename(path)).write_bytes(savez_bytes(arrays))
    return folder, markers


def test_validate_names_each_pickled_file_and_checks_the_others(hostile, capsys):
    folder, markers = hostile
    assert validate_main([str(folder.parent)]) == 1
    out = capsys.readouterr().out
    refused = [line for line in out.splitlines() if "would need pickle" in line]
    assert len(refused) == 3
    assert all(line.startswith(str(folder)) for line in refused)
    assert "4 clip(s) checked, 1 valid, 3 with violations" in out
    assert not any(marker.exists() for marker in markers)


def test_compare_viz_and_stats_never_unpickle(hostile, reference_run, tmp_path, capsys):
    folder, markers = hostile
    reference = reference_run("pstudio")
    assert compare_main([reference, str(folder.parent), "--out", str(tmp_path / "c")]) == 0
    err = capsys.readouterr().err
    assert err.count("not scored: pstudio/") == 1  # the tracks payload; NEW's frames and queries are not read
    # as REF: three clips cannot be read (exit 1, each named in one line), the fourth is scored
    assert compare_main([str(folder.parent), reference, "--out", str(tmp_path / "d")]) == 1
    err = capsys.readouterr().err
    assert err.count("would need pickle") == 3  # REF reads frames, queries, tracks
    assert err.strip().splitlines()[-1] == "3 of 4 clip(s) could not be read from REF; rerun to complete them"
    for path in sorted(folder.glob("*.npz"))[1:]:
        assert viz_main([str(path), "--out", str(tmp_path / "v.png")]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1
        assert "is an object array: loading it would need pickle" in err[0]
    assert viz_main(["stats", str(folder.parent), "--out", str(tmp_path / "s.png")]) == 2
    err = capsys.readouterr().err
    assert "would need pickle" in err
    assert "Traceback" not in err
    assert not any(marker.exists() for marker in markers)


def test_bombs_are_refused_from_the_headers_alone(reference_run):
    clip = plain_load(clip_files(reference_run("pstudio"), "pstudio")[0])
    frames, tracks = clip["tracks_XYZ"].shape[:2]
    cases = {
        "deflate_tracks": (
            bomb_clip(clip, "tracks_XYZ", gib=20),
            f"clip of T = {frames} frames and N = {tracks}",
        ),
        "deflate_frames": (bomb_clip(clip, "images_jpeg_bytes", gib=20), "headers claim T = "),
        "shape_tracks": (
            shape_bomb_clip(clip, "tracks_XYZ", (frames, 10**9, 3)),
            "but the entry holds 64 bytes",
        ),
    }
    for name, (data, words) in cases.items():
        assert len(data) < 40 << 20, name
        with pytest.raises(NpzError, match=words):
            read_clip_bytes(data, name)
    # a member claiming more than a clip of T frames and N tracks can hold, honestly inflated
    visibility = np.ones((frames, tracks * 64), bool)
    with pytest.raises(NpzError, match=f"a clip of T = {frames} frames and N = {tracks} tracks"):
        read_clip_bytes(savez_bytes({**clip, "visibility": visibility}), "oversized")


def test_queries_from_survives_a_payload_a_bomb_and_a_fractional_frame(
    reference_run, pstudio_sample, tmp_path
):
    """One run: camera 3's clip carries a pickle payload, camera 8's a 20 GiB deflate bomb, camera 16's
    a good copy. The first two units fail with one clear line each, the third is written; the run's
    peak memory stays far below the bomb (measured with wait4 on the command's own process)."""
    given = tmp_path / "given" / "pstudio"
    given.mkdir(parents=True)
    reference = reference_run("pstudio")
    marker = tmp_path / "marker"
    clips = {
        name: plain_load(os.path.join(reference, "pstudio", name)) for name in ("dome_3.npz", "dome_8.npz")
    }
    (given / "dome_3.npz").write_bytes(
        savez_bytes(with_payload(clips["dome_3.npz"], "queries_xyt", str(marker)))
    )
    (given / "dome_8.npz").write_bytes(bomb_clip(clips["dome_8.npz"], "queries_xyt", gib=20))
    shutil.copy(os.path.join(reference, "pstudio", "dome_16.npz"), given)
    out = tmp_path / "out"
    command = [sys.executable, "-m", "pipeline.run", "--source", "pstudio", "--input", pstudio_sample[0]]
    command += ["--output", str(out), "--queries-from", str(given.parent), "--set", "pstudio.cameras=3,8,16"]
    with open(tmp_path / "stderr", "w") as err:
        process = subprocess.Popen(command, cwd=REPO, stdout=subprocess.DEVNULL, stderr=err)
        _, status, usage = os.wait4(process.pid, 0)
    stderr = (tmp_path / "stderr").read_text()
    assert os.waitstatus_to_exitcode(status) == 1, stderr[-2000:]
    failures = [json.loads(line) for line in (out / "failures_pstudio.jsonl").read_text().splitlines()]
    errors = {failure["unit"]: failure["error"] for failure in failures}
    assert "would need pickle" in errors["dome/camera_3"]
    assert "N = 1789569706 tracks; at most 100000 frames and 1048576 tracks" in errors["dome/camera_8"]
    assert sorted(p.name for p in (out / "pstudio").glob("*.npz")) == ["dome_16.npz"]
    assert usage.ru_maxrss * 1024 < 3 << 30, usage.ru_maxrss
    assert not marker.exists()
    assert "Traceback" not in stderr
    # a fractional query frame is an error, not a truncation
    arrays = plain_load(str(given / "dome_16.npz"))
    arrays["queries_xyt"][4, 2] += 0.5
    (given / "dome_16.npz").write_bytes(savez_bytes(arrays))
    with pytest.raises(InputError, match=r"query 4 has frame .*not a frame index"):
        given_queries(str(given.parent), "pstudio", "dome_16")


def test_resume_never_unpickles_nor_deletes_outside_the_output(pstudio_sample, tmp_path):
    out, victim = tmp_path / "out", tmp_path / "victim.npz"
    victim.write_bytes(b"keep me")
    command = ["--source", "pstudio", "--input", pstudio_sample[0], "--output", str(out)]
    command += ["--set", "pstudio.cameras=3"]
    assert run_main(command) == 0
    (record_path,) = (out / "units" / "pstudio").glob("*.json")
    clip = out / "pstudio" / "dome_3.npz"
    good = clip.read_bytes()
    marker = tmp_path / "marker"
    payload = savez_bytes(with_payload(plain_load(str(clip)), "tracks_XYZ", str(marker)))
    clip.write_bytes(payload)
    record = json.loads(record_path.read_text())
    record["clips"]["dome_3"] = hashlib.sha256(payload).hexdigest()  # a forged record vouches for it
    forged = dict(record["reports"][0], clip="../../victim")
    record["reports"].append(forged)
    record_path.write_text(json.dumps(record))
    assert run_main(command) == 0
    assert clip.read_bytes() == good
    assert victim.read_bytes() == b"keep me"
    assert not marker.exists()


def hostile_members(clip: dict[str, np.ndarray]) -> dict[str, bytes]:
    """A clip's bytes with one member made hostile each way a zip allows: flagged encrypted, compressed
    by a method an ``.npz`` never uses, twice in the directory, a symlink, an absolute name."""
    plain = savez_bytes(clip)

    def patched(flag: int = 0, method: int | None = None) -> bytes:
        data = bytearray(plain)
        for marker, flags_at in ((b"PK\x03\x04", 6), (b"PK\x01\x02", 8)):
            at = data.find(marker)
            while at >= 0:
                data[at + flags_at] |= flag
                if method is not None:
                    data[at + flags_at + 2 : at + flags_at + 4] = method.to_bytes(2, "little")
                at = data.find(marker, at + 4)
        return bytes(data)

    def rezipped(change) -> bytes:
        out = io.BytesIO()
        with zipfile.ZipFile(io.BytesIO(plain)) as source, zipfile.ZipFile(out, "w") as target:
            for info in source.infolist():
                change(target, info, source.read(info))
        return out.getvalue()

    def twice(target, info, data):
        target.writestr(info, data)
        if info.filename == "tracks_XYZ.npy":
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # zipfile warns of the duplicate name: the point here
                target.writestr(info, data)

    def symlink(target, info, data):
        if info.filename == "tracks_XYZ.npy":
            info.external_attr = (stat.S_IFLNK | 0o777) << 16
        target.writestr(info, data)

    def absolute(target, info, data):
        target.writestr("/tmp/" + info.filename if info.filename == "tracks_XYZ.npy" else info.filename, data)

    return {
        "encrypted": patched(flag=1),
        "method": patched(method=99),
        "twice": rezipped(twice),
        "symlink": rezipped(symlink),
        "absolute": rezipped(absolute),
    }


def test_hostile_zip_members_are_refused_in_one_line_and_validate_checks_the_others(
    reference_run, tmp_path, capsys
):
    folder = tmp_path / "files" / "pstudio"
    folder.mkdir(parents=True)
    good = clip_files(reference_run("pstudio"), "pstudio")[0]
    shutil.copy(good, folder)
    causes = {
        "encrypted": "member 'fx_fy_cx_cy.npy' is encrypted; refused",
        "method": "member 'fx_fy_cx_cy.npy' uses compression method 99; only stored and deflated members",
        "twice": "member 'tracks_XYZ.npy' appears more than once; refused",
        "symlink": "member 'tracks_XYZ.npy' is a symlink; refused",
        "absolute": "member '/tmp/tracks_XYZ.npy' has an absolute or '..' path; refused",
    }
    for name, data in hostile_members(plain_load(good)).items():
        with pytest.raises(NpzError, match=re.escape(causes[name])):
            read_clip_bytes(data, name)
        (folder / f"{name}.npz").write_bytes(data)
    assert validate_main([str(folder.parent)]) == 1
    out = capsys.readouterr().out
    assert "Traceback" not in out
    for name, cause in causes.items():
        said = [line for line in out.splitlines() if line.startswith(f"{folder / name}.npz: ")]
        assert len(said) == 1 and cause in said[0], said
    assert f"{len(causes) + 1} clip(s) checked, 1 valid, {len(causes)} with violations" in out
