"""Units annotated in groups (``Source.group_of`` / ``annotate_group``, DriveTrack's segments): the
graph hands each group to one call, each unit keeps its own outcome and record, a unit's failure
stays its own, and resume re-annotates only the unfinished units of a group. (That DriveTrack's
segment group decodes its lidar once: ``tests/drivetrack/test_truth.py``.)"""

from __future__ import annotations

import dataclasses
import json
import os

import pytest

from pipeline import sources
from pipeline.core.errors import InputError
from pipeline.core.outcomes import Failure, UnitClips
from pipeline.export.layout import clip_path, failures_path
from pipeline.pstudio.units import SequenceCamera
from pipeline.runner.command import main as run_main
from pipeline.runner.stages import UnitJob, run_group
from pipeline.settings.run_config import RunConfig
from tests.support.toy.source import TOY, SpecFile, annotate, write_sample

CALLS: list[list[str]] = []


def made(input_root: str, unit: SpecFile, config: RunConfig) -> UnitClips:
    return UnitClips(tuple(annotate(input_root, unit, config)))


def annotate_group(input_root: str, units: list[SpecFile], config: RunConfig, wanted: list) -> list:
    """The toy's clips per unit; a unit named ``*_bad`` fails with an InputError."""
    CALLS.append([unit.name for unit in units])
    return [
        InputError(f"{unit.name}: bad on purpose")
        if unit.name.endswith("_bad")
        else made(input_root, unit, config)
        for unit in units
    ]


def specs(*names: str) -> list[SpecFile]:
    return [SpecFile(name) for name in names]


GROUPED = dataclasses.replace(
    TOY, group_of=lambda unit: unit.name.split("_")[0], annotate_group=annotate_group
)


@pytest.fixture
def grouped(tmp_path):
    """The grouped toy registered as ``toy``, over units a_1, a_2, b_1, b_bad; CALLS emptied."""
    root = tmp_path / "in"
    write_sample(str(root))
    walk = (root / "walk.json").read_text()
    os.remove(root / "walk.json")
    for unit in ("a_1", "a_2", "b_1", "b_bad"):
        (root / f"{unit}.json").write_text(walk)
    CALLS.clear()
    sources.register(GROUPED)
    yield str(root)
    sources.unregister(GROUPED.name)


def test_the_graph_annotates_each_group_in_one_call(grouped, tmp_path, capsys):
    out = tmp_path / "out"
    assert run_main(["--source", "toy", "--input", grouped, "--output", str(out)]) == 1  # b_bad failed
    assert sorted(CALLS) == [["a_1", "a_2"], ["b_1", "b_bad"]]
    for unit in ("a_1", "a_2", "b_1"):
        assert os.path.exists(clip_path(str(out), "toy", f"toy_{unit}"))
    assert not os.path.exists(clip_path(str(out), "toy", "toy_b_bad"))
    (line,) = open(failures_path(str(out), "toy")).read().splitlines()
    assert json.loads(line) == {
        "unit": "b_bad",
        "stage": "annotate",
        "error": "InputError: b_bad: bad on purpose",
    }
    record = json.loads((out / "run_toy.json").read_text())
    assert record["metrics"]["units_read"] == 4
    assert record["metrics"]["units_failed"] == 1
    capsys.readouterr()


def test_resume_annotates_only_a_groups_unfinished_units(grouped, tmp_path):
    job = UnitJob(GROUPED, grouped, RunConfig(), str(tmp_path / "out"))
    first = run_group(job, specs("a_1", "a_2"))
    assert CALLS == [["a_1", "a_2"]]
    assert [o.name for o in first] == ["a_1", "a_2"]
    assert all(not o.resumed and not o.failures and o.reports for o in first)
    os.remove(clip_path(job.output, "toy", "toy_a_2"))  # a_2 is no longer finished
    second = run_group(job, specs("a_1", "a_2"))
    assert CALLS == [["a_1", "a_2"], ["a_2"]]
    assert [o.resumed for o in second] == [True, False]
    assert second[1].reports == first[1].reports
    assert os.path.exists(clip_path(job.output, "toy", "toy_a_2"))


def test_a_failed_unit_leaves_its_groups_other_units_finished(grouped, tmp_path):
    job = UnitJob(GROUPED, grouped, RunConfig(), str(tmp_path / "out"))
    good, bad = run_group(job, specs("b_1", "b_bad"))
    assert good.reports
    assert not good.failures
    assert bad.failures == (Failure("b_bad", "annotate", "InputError: b_bad: bad on purpose"),)
    again = run_group(job, specs("b_1", "b_bad"))  # the failed unit is redone, its finished neighbour not
    assert CALLS[-1] == ["b_bad"]
    assert again[0].resumed
    assert again[1].failures == bad.failures


def interrupted_in_a_kernel() -> SystemError:
    """The error numba has handed back for a Ctrl-C taken during a kernel's call."""
    try:
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as interrupt:
            message = "CPUDispatcher(<function kernel>) returned a result with an exception set"
            raise SystemError(message) from interrupt
    except SystemError as error:
        return error


def test_ctrl_c_inside_a_kernel_stops_the_run_instead_of_failing_the_unit(grouped, tmp_path, capsys):
    def interrupted(input_root, units, config, wanted):
        return [interrupted_in_a_kernel() if u.name == "b_1" else made(input_root, u, config) for u in units]

    sources.register(dataclasses.replace(GROUPED, annotate_group=interrupted))
    out = tmp_path / "out"
    assert run_main(["--source", "toy", "--input", grouped, "--output", str(out)]) == 130
    assert "interrupted:" in capsys.readouterr().err
    failures = failures_path(str(out), "toy")
    assert not os.path.exists(failures) or "b_1" not in open(failures).read()


def test_a_group_finished_earlier_is_not_annotated_again(grouped, tmp_path):
    job = UnitJob(GROUPED, grouped, RunConfig(), str(tmp_path / "out"))
    run_group(job, specs("a_1", "a_2"))
    again = run_group(job, specs("a_1", "a_2"))
    assert CALLS == [["a_1", "a_2"]]
    assert all(outcome.resumed for outcome in again)


def test_a_generator_groups_units_are_written_one_by_one(grouped, tmp_path):
    """A source whose annotate_group is a generator has each unit written (clip and record) before
    the next unit of its group is annotated: a killed run keeps the units already made."""
    output = str(tmp_path / "out")
    seen_on_disk = []

    def one_by_one(input_root, units, config, wanted):
        for unit in units:
            seen_on_disk.append([os.path.exists(clip_path(output, "toy", f"toy_{u.name}")) for u in units])
            yield made(input_root, unit, config)

    job = UnitJob(dataclasses.replace(GROUPED, annotate_group=one_by_one), grouped, RunConfig(), output)
    outcomes = run_group(job, specs("a_1", "a_2", "b_1"))
    assert all(o.reports and not o.failures for o in outcomes)
    assert seen_on_disk == [[False, False, False], [True, False, False], [True, True, False]]


def test_panoptic_groups_are_three_cameras_of_one_sequence():
    """A Panoptic Studio sequence's cameras go to workers three by three (ids 0-2, 3-5, ...): one
    read of the Gaussians per group, yet the ~27 cameras of a sequence still spread over workers."""
    source = sources.get("pstudio")
    keys = {camera: source.group_key(SequenceCamera("dome", camera)) for camera in range(31)}
    assert len(set(keys.values())) == 11
    for camera in range(31):
        together = {other for other in range(31) if keys[other] == keys[camera]}
        assert together == set(range(camera - camera % 3, min(camera - camera % 3 + 3, 31)))
    assert source.group_key(SequenceCamera("dome", 4)) != source.group_key(SequenceCamera("hall", 4))
