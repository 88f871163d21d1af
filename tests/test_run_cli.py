"""The CLI end to end on the sample world: outputs, determinism across runners, bad input."""

import json
import os

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from pipeline.validate import main as validate_main
from tests.cli import run_pipeline
from tests.fixtures.waymo_world import SEGMENT, clone_segment


def run_cli(*args):
    return run_pipeline("drivetrack", *args)


def npz_files(folder):
    return sorted(p for p in os.listdir(os.path.join(folder, "drivetrack")) if p.endswith(".npz"))


@pytest.fixture(scope="module")
def direct_run(sample_split, tmp_path_factory):
    out = str(tmp_path_factory.mktemp("direct"))
    result = run_cli("--input", sample_split[0], "--output", out, "--runner", "DirectRunner")
    assert result.returncode == 0, result.stderr[-3000:]
    return out, result


def test_run_writes_valid_clips_manifests_and_provenance(direct_run):
    out, result = direct_run
    assert len(npz_files(out)) == 4
    assert validate_main([out]) == 0
    minival = open(os.path.join(out, "manifests", "minival.txt")).read().split()
    full_test = open(os.path.join(out, "manifests", "full_test.txt")).read().split()
    assert sorted(minival + full_test) == sorted(f"drivetrack/{n}" for n in npz_files(out))
    record = json.load(open(os.path.join(out, "run_drivetrack.json")))
    assert record["config"]["flicker"]["max_fraction"] == 0.1
    assert record["summary"]["clips_written"] == 4 and record["summary"]["failures"] == 0
    assert len(record["units"]) == 3
    assert open(os.path.join(out, "failures_drivetrack.jsonl")).read() == ""
    # the summary printed at the end names the filters
    assert "dropped by filter: never_visible" in result.stdout
    audit = pq.read_table(os.path.join(out, "audit", "drivetrack"))
    assert {"visibility_flips", "mask_agreement", "pass_flicker", "output_index"} <= set(audit.column_names)
    assert (np.asarray(audit.column("output_index")) >= 0).sum() == record["summary"]["tracks_written"]


def test_multiprocessing_runner_writes_identical_bytes(direct_run, sample_split, tmp_path):
    out = str(tmp_path / "multi")
    result = run_cli(
        "--input",
        sample_split[0],
        "--output",
        out,
        "--runner",
        "DirectRunner",
        "--direct_running_mode=multi_processing",
        "--direct_num_workers=2",
    )
    assert result.returncode == 0, result.stderr[-3000:]
    assert npz_files(out) == npz_files(direct_run[0])
    for name in npz_files(out):
        with (
            open(os.path.join(out, "drivetrack", name), "rb") as a,
            open(os.path.join(direct_run[0], "drivetrack", name), "rb") as b,
        ):
            assert a.read() == b.read(), name


def _rewrite(path, column, transform):
    table = pq.read_table(path)
    index = table.schema.get_field_index(column)
    values = transform(table.column(column).to_pylist(), table)
    table = table.set_column(index, column, pa.array(values, table.schema.field(column).type))
    pq.write_table(table, path)


def test_bad_input_fails_its_units_only(split_copy, tmp_path):
    segments = {"missing": "bad_missing_lidar", "jpeg": "bad_corrupt_jpeg", "nan": "bad_nan_pose"}
    for name in segments.values():
        clone_segment(split_copy, SEGMENT, name)
    os.remove(os.path.join(split_copy, "lidar", f"{segments['missing']}.parquet"))

    def corrupt_jpeg(images, table):
        cameras = table.column("key.camera_name").to_pylist()
        target = [i for i, c in enumerate(cameras) if c == 1][5]
        images[target] = images[target][: len(images[target]) // 2]
        return images

    _rewrite(
        os.path.join(split_copy, "camera_image", f"{segments['jpeg']}.parquet"),
        "[CameraImageComponent].image",
        corrupt_jpeg,
    )

    def nan_pose(poses, _):
        poses[3] = [float("nan")] * 16
        return poses

    _rewrite(
        os.path.join(split_copy, "vehicle_pose", f"{segments['nan']}.parquet"),
        "[VehiclePoseComponent].world_from_vehicle.transform",
        nan_pose,
    )

    out = str(tmp_path / "out")
    result = run_cli("--input", split_copy, "--output", out)
    assert result.returncode == 1
    failures = [json.loads(line) for line in open(os.path.join(out, "failures_drivetrack.jsonl"))]
    by_unit = {f["unit"]: f["error"] for f in failures}
    assert "missing component file lidar/bad_missing_lidar.parquet" in by_unit["bad_missing_lidar/camera_1"]
    assert "corrupt JPEG" in by_unit["bad_corrupt_jpeg/camera_1"]
    assert "frame" in by_unit["bad_corrupt_jpeg/camera_1"]
    assert "NaN" in by_unit["bad_nan_pose/camera_1"] and "vehicle_pose" in by_unit["bad_nan_pose/camera_1"]
    assert all(f["error"].startswith("InputError") for f in failures)
    names = npz_files(out)
    # The good segment is complete, the corrupt-JPEG segment's other cameras too; failed
    # units wrote nothing, and no partial file is left anywhere.
    assert sum(SEGMENT in n for n in names) == 4
    assert sum("bad_corrupt_jpeg_3_" in n for n in names) == 1
    assert not any(
        n.startswith(("tapvid3d_bad_missing", "tapvid3d_bad_nan", "tapvid3d_bad_corrupt_jpeg_1_"))
        for n in names
    )
    leftovers = [f for _, _, files in os.walk(out) for f in files if ".partial" in f]
    assert leftovers == []
    assert validate_main([out]) == 0
    assert "failure(s): see" in result.stderr


def test_unknown_setting_is_refused_before_running(tmp_path):
    result = run_cli("--input", str(tmp_path), "--set", "flicker.bogus=1")
    assert result.returncode == 2 and "unknown setting" in result.stderr
