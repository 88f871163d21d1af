"""Bad input every source shares: names that are not plain file names, and output that cannot
be written. The per-source cases are in tests/<source>/test_bad_input.py.

Each case: how it is made -> the expected error.

- unsafe clip name, drivetrack: object id "../escape" -> that clip only fails: "clip name ... is not
  a plain file name (characters ['/']; path separators are refused)"; the unit's other clips are written.
- unsafe clip name, adt: a sequence folder ``seq\\evil`` -> the same, characters ['\\'].
- unsafe clip name, pstudio: Beam's file match never lists such a sequence folder, so the writer's
  check is tested directly: '/', '\\', a leading '.', a space, the empty name.
- pstudio train_meta.json cut in half, cameras not set (they come from that file) -> the one unit
  <seq>/all_cameras fails: "not a Dynamic 3D Gaussians train_meta.json"; other sequences run.
- ``--output FILE/out`` under a regular file -> exit 2 before any work: "cannot start: output folder
  ... is not writable".
- ``<out>/<source>`` is a regular file -> each clip: "OutputError: cannot write <out>/<source>/<clip>.npz
  : [Errno 17] File exists: '<out>/<source>'"; the run still finishes, records every failure
  and no unit as finished.
"""

from __future__ import annotations

import json
import os
import re
import shutil

import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from pipeline.core.errors import InputError
from pipeline.drivetrack.sample.waymo_world import SEGMENT
from pipeline.export.layout import check_clip_name
from pipeline.sources import BUILT_IN
from tests.support.adt_excerpt import SAMPLE as ADT_EXCERPT
from tests.support.adt_excerpt import SETTINGS as ADT_SETTINGS
from tests.support.adt_excerpt import needs_excerpt
from tests.support.bad_input import failures_by_unit, partial_files
from tests.support.cli import run_in_process

ADT_SEQUENCE = str(ADT_EXCERPT)
UNSAFE = "is not a plain file name"


def rename_object(split: str, segment: str, old: str, new: str) -> None:
    """Give object ``old`` the id ``new`` in every component of the segment that names objects."""
    for component in sorted(os.listdir(split)):
        path = os.path.join(split, component, f"{segment}.parquet")
        if not os.path.exists(path):
            continue
        table = pq.read_table(path)
        if "key.laser_object_id" not in table.column_names:
            continue
        ids = [new if value == old else value for value in table.column("key.laser_object_id").to_pylist()]
        index = table.schema.get_field_index("key.laser_object_id")
        pq.write_table(table.set_column(index, "key.laser_object_id", pa.array(ids, pa.string())), path)


def test_drivetrack_object_id_with_path_separators_fails_its_clip_only(split_copy, tmp_path):
    rename_object(split_copy, SEGMENT, "lead_car_AAAAAAAAAAAAAAAAAAAAAA", "../escape")
    out = str(tmp_path / "out")
    result = run_in_process("drivetrack", "--input", split_copy, "--output", out)
    assert result.returncode == 1, result.stderr[-3000:]
    errors = failures_by_unit(out, "drivetrack")
    unit = f"{SEGMENT}/camera_1 (tapvid3d_{SEGMENT}_1_../escape)"
    assert set(errors) == {unit}
    assert errors[unit].startswith("InputError")
    assert UNSAFE in errors[unit]
    assert "['/']" in errors[unit]
    written = sorted(os.listdir(os.path.join(out, "drivetrack")))
    assert len(written) == 3
    assert not any("escape" in name for name in written)  # the other 3 clips
    assert not os.path.exists(os.path.join(tmp_path, "escape.npz"))
    assert partial_files(out) == []


def test_pstudio_unreadable_train_meta_fails_one_unit_when_cameras_come_from_it(pstudio_links, tmp_path):
    root = pstudio_links
    shutil.copytree(os.path.join(root, "data", "dome"), os.path.join(root, "data", "broken"))
    pretrained = os.path.join(root, "output", "pretrained")
    shutil.copytree(os.path.join(pretrained, "dome"), os.path.join(pretrained, "broken"))
    meta = os.path.join(root, "data", "broken", "train_meta.json")
    text = open(meta).read()
    os.remove(meta)  # a hard link to the sample's file: replace, never write through it
    open(meta, "w").write(text[: len(text) // 2])
    out = str(tmp_path / "out")
    result = run_in_process("pstudio", "--input", root, "--output", out)
    assert result.returncode == 1, result.stderr[-3000:]
    errors = failures_by_unit(out, "pstudio")
    assert set(errors) == {"broken/all_cameras"}
    assert (
        "broken/train_meta.json: not a Dynamic 3D Gaussians train_meta.json" in errors["broken/all_cameras"]
    )
    assert sorted(os.listdir(os.path.join(out, "pstudio"))) == [f"dome_{c}.npz" for c in (16, 21, 3, 8)]
    assert partial_files(out) == []


@pytest.mark.parametrize(
    ("name", "cause"),
    [
        ("a/b", "['/']"),
        ("a\\b", "['\\\\']"),
        ("..", "a leading '.'"),
        (".hidden", "a leading '.'"),
        ("dome 3", "[' ']"),
        ("", "an empty name"),
    ],
)
def test_clip_names_that_are_not_plain_file_names_are_refused(name, cause):
    with pytest.raises(InputError, match=re.escape(cause)):
        check_clip_name(name)


def test_plain_clip_names_pass():
    for name in (
        "dome_3",
        "tapvid3d_10017090168044687777_6380_000_6400_000_1_a-B+c.d",
        "Apartment_release_0",
    ):
        assert check_clip_name(name) == name


@needs_excerpt
def test_adt_unsafe_sequence_name_fails_its_unit_only(tmp_path):
    folder = tmp_path / "sequences"
    folder.mkdir()
    os.symlink(os.path.abspath(ADT_SEQUENCE), folder / "good")
    os.symlink(os.path.abspath(ADT_SEQUENCE), folder / "seq\\evil")
    out = str(tmp_path / "out")
    result = run_in_process("adt", "--input", str(folder), "--output", out, *ADT_SETTINGS)
    assert result.returncode == 1, result.stderr[-3000:]
    errors = failures_by_unit(out, "adt")
    assert len(errors) == 1
    ((unit, error),) = errors.items()
    assert unit.startswith("seq\\evil")
    assert UNSAFE in error
    assert "['\\\\']" in error
    assert os.listdir(os.path.join(out, "adt")) == ["good_0.npz"]
    assert partial_files(out) == []


@pytest.mark.parametrize("source", sorted(BUILT_IN))
def test_output_under_a_regular_file_is_refused_before_any_work(source, tmp_path):
    blocker = tmp_path / "not_a_folder"
    blocker.write_bytes(b"")
    result = run_in_process(source, "--input", str(tmp_path), "--output", str(blocker / "out"))
    assert result.returncode == 2
    assert f"cannot start: output folder {blocker}/out is not writable" in result.stderr
    assert sorted(os.listdir(tmp_path)) == ["not_a_folder"]


def blocked_run(source: str, source_input: str, out: str, *args: str) -> dict[str, str]:
    """Run with ``<out>/<source>`` a regular file; returns the failures by unit."""
    os.makedirs(out)
    open(os.path.join(out, source), "wb").close()
    result = run_in_process(source, "--input", source_input, "--output", out, *args)
    assert result.returncode == 1, result.stderr[-3000:]
    errors = failures_by_unit(out, source)
    assert errors
    assert all(
        error.startswith(f"OutputError: cannot write {out}/{source}/") and f"'{out}/{source}'" in error
        for error in errors.values()
    )
    summary = json.load(open(os.path.join(out, f"run_{source}.json")))["summary"]
    assert summary["clips_written"] == 0
    assert summary["failures"] == len(errors)
    # A unit with a failed clip is not recorded as finished, so a rerun once the folder is fixed
    # redoes it (a unit with no clip at all is finished).
    folder = os.path.join(out, "units", source)
    records = [json.load(open(os.path.join(folder, name))) for name in os.listdir(folder)]
    finished = {record["unit"] for record in records if not record["failures"]}  # failed: redone
    assert not finished & {unit.split(" (")[0] for unit in errors}
    assert partial_files(out) == []
    return errors


def test_blocked_clip_folder_drivetrack(sample_split, tmp_path):
    errors = blocked_run("drivetrack", sample_split[0], str(tmp_path / "out"))
    assert len(errors) == 4  # every clip of the sample, each with its own line


def test_blocked_clip_folder_pstudio(pstudio_sample, tmp_path):
    errors = blocked_run("pstudio", pstudio_sample[0], str(tmp_path / "out"), "--set", "pstudio.cameras=3,8")
    assert set(errors) == {"dome/camera_3 (dome_3)", "dome/camera_8 (dome_8)"}


@needs_excerpt
def test_blocked_clip_folder_adt(tmp_path):
    errors = blocked_run("adt", ADT_SEQUENCE, str(tmp_path / "out"), *ADT_SETTINGS)
    assert len(errors) == 1
