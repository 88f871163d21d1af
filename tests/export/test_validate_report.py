"""``pipeline.validate``'s quality findings: each planted defect counted exactly, none on a clean clip."""

import json

import cv2
import numpy as np
import pytest

from pipeline.core.images import jpeg_size
from pipeline.export.invariants import quality_findings
from pipeline.export.npz_writer import encode_npz
from pipeline.validate import main

HEIGHT, WIDTH, FRAMES, TRACKS = 48, 64, 30, 6
K = np.array([50.0, 50.0, 32.0, 24.0], np.float32)


def clean_clip():
    """30 frames x 6 tracks at z = 2 m, all inside the 64x48 view and visible; track i queried at frame 5."""
    rng = np.random.default_rng(0)
    u, v = rng.uniform(5, WIDTH - 5, (FRAMES, TRACKS)), rng.uniform(5, HEIGHT - 5, (FRAMES, TRACKS))
    xyz = np.stack([(u - K[2]) / K[0] * 2.0, (v - K[3]) / K[1] * 2.0, np.full_like(u, 2.0)], -1)
    jpeg = cv2.imencode(".jpg", np.zeros((HEIGHT, WIDTH, 3), np.uint8))[1].tobytes()
    return {
        "images_jpeg_bytes": np.array([jpeg] * FRAMES),
        "queries_xyt": np.stack([u[5], v[5], np.full(TRACKS, 5.0)], 1).astype(np.float32),
        "tracks_XYZ": xyz.astype(np.float32),
        "visibility": np.ones((FRAMES, TRACKS), bool),
        "fx_fy_cx_cy": K,
        "extrinsics_w2c": np.tile(np.eye(4, dtype=np.float32), (FRAMES, 1, 1)),
    }


def defective_clip():
    arrays = clean_clip()
    vis, xyz = arrays["visibility"], arrays["tracks_XYZ"]
    vis[5, 1] = False  # track 1: hidden at its own query frame (2 flips, within 10% of 30 frames)
    xyz[10:13, 2, 0] = 5.0  # track 2: projects to u = 157 > 64 on frames 10-12 while visible
    xyz[20:22, 3, 0] = 5.0  # track 3: leaves the image too, but is marked hidden there: no finding
    vis[20:22, 3] = False
    vis[0:10:2, 4] = False  # track 4: hidden on frames 0, 2, 4, 6, 8 -> 9 flips > 3: flickering
    return arrays


def write(root, name, arrays):
    folder = root / "adt"
    folder.mkdir(parents=True, exist_ok=True)
    (folder / name).write_bytes(encode_npz(arrays))


def test_jpeg_size_reads_the_frame_header():
    jpeg = cv2.imencode(".jpg", np.zeros((37, 91, 3), np.uint8))[1].tobytes()
    assert jpeg_size(jpeg) == (37, 91)
    assert jpeg_size(b"\xff\xd8fake") is None
    assert jpeg_size(b"not a jpeg") is None


def test_each_planted_defect_is_counted_once():
    findings = quality_findings(defective_clip())
    assert findings["hidden_queries"] == 1
    assert findings["off_image_visible"] == 1
    assert findings["flickering"] == 1
    assert findings["tracks"] == TRACKS
    assert findings["image_hw"] == [HEIGHT, WIDTH]


def test_a_track_behind_the_camera_while_visible_is_a_finding():
    arrays = clean_clip()
    arrays["tracks_XYZ"][7, 0, 2] = -1.0
    assert quality_findings(arrays)["off_image_visible"] == 1


def test_clean_clip_has_no_findings():
    findings = quality_findings(clean_clip())
    assert (findings["hidden_queries"], findings["off_image_visible"], findings["flickering"]) == (0, 0, 0)


def test_cli_reports_every_clip_and_keeps_its_exit_code(tmp_path, capsys):
    write(tmp_path, "clean.npz", clean_clip())
    write(tmp_path, "defective.npz", defective_clip())
    report_path = tmp_path / "report.json"
    # The hidden query is also a schema violation, so the run still fails; the other findings do not.
    assert main([str(tmp_path), "--report", str(report_path)]) == 1
    out = capsys.readouterr().out
    assert "not visible at their query frame" in out
    assert "1 with violations" in out
    rows = {row["clip"].rsplit("/", 1)[-1]: row for row in json.loads(report_path.read_text())["clips"]}
    keys = ("hidden_queries", "off_image_visible", "flickering")
    assert [rows["defective.npz"][key] for key in keys] == [1, 1, 1]
    assert [rows["clean.npz"][key] for key in keys] == [0, 0, 0]
    assert rows["clean.npz"]["violations"] == []
    assert len(rows["defective.npz"]["violations"]) == 1


@pytest.mark.parametrize("fraction, flickering", [(0.10, 1), (0.5, 0)])
def test_flicker_threshold_option(tmp_path, fraction, flickering):
    arrays = defective_clip()
    arrays["visibility"][5, 1] = True  # no schema violation left: the findings alone must not fail the run
    write(tmp_path, "flicker.npz", arrays)
    report_path = tmp_path / "report.json"
    assert main([str(tmp_path), "--flicker-max-fraction", str(fraction), "--report", str(report_path)]) == 0
    report = json.loads(report_path.read_text())
    assert report["clips"][0]["flickering"] == flickering
    assert report["totals"]["off_image_visible"] == 1
