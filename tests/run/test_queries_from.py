"""``--queries-from``: re-annotating the queries of existing clips reproduces their tracks."""

from __future__ import annotations

import pathlib

import numpy as np
import pyarrow.parquet as pq

from pipeline.runner.command import main as run_main
from tests.support.adt_excerpt import SAMPLE as ADT_EXCERPT
from tests.support.adt_excerpt import SETTINGS as ADT_SETTINGS
from tests.support.adt_excerpt import needs_excerpt


def same_bytes(first: pathlib.Path, second: pathlib.Path, source: str) -> list[str]:
    names = sorted(p.name for p in (first / source).glob("*.npz"))
    assert names
    assert names == sorted(p.name for p in (second / source).glob("*.npz"))
    return [n for n in names if (first / source / n).read_bytes() != (second / source / n).read_bytes()]


def test_pstudio_rerun_reproduces_and_filters_drop_nothing(pstudio_sample, reference_run, tmp_path):
    root = pstudio_sample[0]
    first, second, third = pathlib.Path(reference_run("pstudio")), tmp_path / "second", tmp_path / "third"
    assert (
        run_main(
            ["--source", "pstudio", "--input", root, "--output", str(second), "--queries-from", str(first)]
        )
        == 0
    )
    assert same_bytes(first, second, "pstudio") == []
    # A clip drawn with the mask filter off holds floater tracks; re-annotated at the default
    # threshold, every track is kept in order and the mask verdict is still recorded.
    loose = tmp_path / "loose"
    assert (
        run_main(
            [
                "--source",
                "pstudio",
                "--input",
                root,
                "--output",
                str(loose),
                "--set",
                "pstudio.mask_min_agreement=0",
            ]
        )
        == 0
    )
    assert (
        run_main(
            ["--source", "pstudio", "--input", root, "--output", str(third), "--queries-from", str(loose)]
        )
        == 0
    )
    failing = 0
    for clip in sorted((loose / "pstudio").glob("*.npz")):
        with (
            np.load(clip, allow_pickle=False) as old,
            np.load(third / "pstudio" / clip.name, allow_pickle=False) as new,
        ):
            np.testing.assert_array_equal(old["queries_xyt"], new["queries_xyt"])
            np.testing.assert_array_equal(old["tracks_XYZ"], new["tracks_XYZ"])
        audit = pq.read_table(third / "audit" / "pstudio" / f"{clip.stem}.parquet").to_pydict()
        assert audit["output_index"] == list(range(len(audit["output_index"])))
        failing += audit["pass_mask"].count(False)
    assert failing > 0


def test_drivetrack_rerun_reproduces(sample_split, reference_run, tmp_path):
    first, second = pathlib.Path(reference_run("drivetrack")), tmp_path / "second"
    command = ["--source", "drivetrack", "--input", sample_split[0], "--output", str(second)]
    assert run_main(command + ["--queries-from", str(first)]) == 0
    assert same_bytes(first, second, "drivetrack") == []


@needs_excerpt
def test_adt_rerun_reproduces(tmp_path):
    first, second = tmp_path / "first", tmp_path / "second"
    command = ["--source", "adt", "--input", str(ADT_EXCERPT), *ADT_SETTINGS]
    assert run_main(command + ["--output", str(first)]) == 0
    assert run_main(command + ["--output", str(second), "--queries-from", str(first)]) == 0
    assert same_bytes(first, second, "adt") == []


def test_a_query_off_every_surface_fails_its_unit_with_the_reason(pstudio_sample, tmp_path):
    first, second = tmp_path / "first", tmp_path / "second"
    root = pstudio_sample[0]
    assert (
        run_main(
            ["--source", "pstudio", "--input", root, "--output", str(first), "--set", "pstudio.cameras=3"]
        )
        == 0
    )
    clip = first / "pstudio" / "dome_3.npz"
    with np.load(clip) as data:
        arrays = dict(data)
    arrays["queries_xyt"][0, :2] = [2.0, 2.0]  # the top-left corner: no splat there
    np.savez(clip, **arrays)
    command = ["--source", "pstudio", "--input", root, "--output", str(second), "--set", "pstudio.cameras=3"]
    assert run_main(command + ["--queries-from", str(first)]) == 1
    failure = (second / "failures_pstudio.jsonl").read_text()
    assert "dome/camera_3" in failure
    assert "given query 0" in failure
    assert not (second / "pstudio").exists() or not list((second / "pstudio").glob("*.npz"))
