"""The CLI end to end on the sample world: outputs and bad settings. Clips across runners: the
DirectRunner's worker processes in tests/pstudio/test_cli.py, a Dask cluster's (both sources) in
tests/run/test_dask_runner.py."""

import json
import os

import numpy as np
import pyarrow.parquet as pq
import pytest

from pipeline.validate import main as validate_main
from tests.support.cli import run_in_process


def npz_files(folder):
    return sorted(p for p in os.listdir(os.path.join(folder, "drivetrack")) if p.endswith(".npz"))


@pytest.fixture(scope="module")
def direct_run(reference_run):
    """(output folder, completed process) of the session's end-to-end DirectRunner run."""
    return reference_run("drivetrack"), reference_run.result("drivetrack")


def test_run_writes_valid_clips_manifests_and_provenance(direct_run):
    out, result = direct_run
    assert len(npz_files(out)) == 4
    assert validate_main([out]) == 0
    minival = open(os.path.join(out, "manifests", "minival.txt")).read().split()
    full_test = open(os.path.join(out, "manifests", "full_test.txt")).read().split()
    assert sorted(minival + full_test) == sorted(f"drivetrack/{n}" for n in npz_files(out))
    record = json.load(open(os.path.join(out, "run_drivetrack.json")))
    assert record["config"]["flicker"]["max_fraction"] == 0.1
    assert record["summary"]["clips_written"] == 4
    assert record["summary"]["failures"] == 0
    assert len(record["units"]) == 3
    assert open(os.path.join(out, "failures_drivetrack.jsonl")).read() == ""
    # the summary printed at the end names the filters
    assert "dropped by filter: never_visible" in result.stdout
    audit = pq.read_table(os.path.join(out, "audit", "drivetrack"))
    assert {"visibility_flips", "mask_agreement", "pass_flicker", "output_index"} <= set(audit.column_names)
    assert (np.asarray(audit.column("output_index")) >= 0).sum() == record["summary"]["tracks_written"]


def test_unknown_setting_is_refused_before_running(tmp_path):
    result = run_in_process("drivetrack", "--input", str(tmp_path), "--set", "flicker.bogus=1")
    assert result.returncode == 2
    assert "unknown setting" in result.stderr
