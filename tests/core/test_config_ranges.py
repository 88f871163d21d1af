"""Every config field has a declared range; ``--set`` values outside it are refused before any work."""

from __future__ import annotations

import dataclasses

import pytest

from pipeline.adt.settings import AdtConfig
from pipeline.settings.fields import check_ranges, config_from_dict, settings_items, with_overrides
from pipeline.settings.run_config import RunConfig
from tests.support.cli import run_in_process

REFUSED = [
    # (assignments, the whole message): one row per kind of rule.
    (["adt.image_size=0"], "--set adt.image_size=0: must be an integer in [2, 8192] and even"),
    (["adt.image_size=511"], "--set adt.image_size=511: must be an integer in [2, 8192] and even"),
    (["adt.focal=-280"], "--set adt.focal=-280: must be a number in (0, 100000]"),
    (["flicker.max_fraction=1.5"], "--set flicker.max_fraction=1.5: must be a number in [0, 1]"),
    (
        ["drivetrack.mask_min_agreement=-0.1"],
        "--set drivetrack.mask_min_agreement=-0.1: must be a number in [0, 1]",
    ),
    (["drivetrack.occlusion_margin=1"], "--set drivetrack.occlusion_margin=1: must be a number in [0, 1)"),
    (
        ["drivetrack.tracks_per_clip=0"],
        "--set drivetrack.tracks_per_clip=0: must be an integer in [1, 100000]",
    ),
    (["pstudio.tracks_per_clip=-5"], "--set pstudio.tracks_per_clip=-5: must be an integer in [1, 100000]"),
    (
        ["drivetrack.oversample=2.5"],
        "--set drivetrack.oversample=2.5: expected int; must be an integer in [1, 10000]",
    ),
    (["adt.oversample=1e3"], "--set adt.oversample=1e3: expected int; must be an integer in [1, 10000]"),
    (["seed=true"], "--set seed=true: expected int; must be an integer in [0, 4294967295]"),
    (["adt.depth_delta_m=nan"], "--set adt.depth_delta_m=nan: must be a number in (0, 10]"),
    (["pstudio.depth_delta_m=inf"], "--set pstudio.depth_delta_m=inf: must be a number in (0, 10]"),
    (["adt.max_gt_offset_ms=-1"], "--set adt.max_gt_offset_ms=-1: must be a number in [0, 1000]"),
    (
        ["pstudio.max_attach_distance_m=-0.5"],
        "--set pstudio.max_attach_distance_m=-0.5: must be a number in [0, 10]",
    ),
    (["rules=released"], "--set rules=released: must be one of release, refined"),
    (
        ["flicker.max_fraction=lots"],
        "--set flicker.max_fraction=lots: expected float; must be a number in [0, 1]",
    ),
    (
        ["drivetrack.cameras=7"],
        "--set drivetrack.cameras=7: must be one or more distinct integers in [1, 5]",
    ),
    (
        ["drivetrack.cameras=1,1"],
        "--set drivetrack.cameras=1,1: must be one or more distinct integers in [1, 5]",
    ),
    (
        ["drivetrack.object_types="],
        "--set drivetrack.object_types=: must be one or more distinct integers in [1, 4]",
    ),
    (["pstudio.cameras=-1"], "--set pstudio.cameras=-1: must be distinct integers in [0, 999]"),
    (
        ["pstudio.cameras=a"],
        "--set pstudio.cameras=a: expected comma-separated ints; must be distinct integers in [0, 999]",
    ),
    (["seed=-1"], "--set seed=-1: must be an integer in [0, 4294967295]"),
    (
        ["drivetrack.mask_closing_px=-1"],
        "--set drivetrack.mask_closing_px=-1: must be an integer in [0, 1000]",
    ),
    (
        ["adt.chunk_frames=100", "adt.min_frames=200"],
        "--set adt.min_frames=200: must be an integer in [1, adt.chunk_frames=100]",
    ),
    # A rule broken by a value the user did not set is named without --set.
    (["adt.chunk_frames=100"], "adt.min_frames=300: must be an integer in [1, adt.chunk_frames=100]"),
    (["adt.with_skeleton=maybe"], "--set adt.with_skeleton=maybe: expected bool; must be true or false"),
    # Every violation is reported, in field order, on one line.
    (
        ["adt.focal=0", "seed=-1"],
        "--set seed=-1: must be an integer in [0, 4294967295]; "
        "--set adt.focal=0: must be a number in (0, 100000]",
    ),
]

ALLOWED = [
    "flicker.max_fraction=0",
    "flicker.max_fraction=1",
    "drivetrack.mask_min_agreement=0",
    "pstudio.mask_min_agreement=1",
    "pstudio.mask_min_agreement=0",
    "drivetrack.occlusion_margin=0",
    "drivetrack.mask_closing_px=0",
    "drivetrack.cameras=1,2,3,4,5",
    "drivetrack.object_types=1,2,3,4",
    "pstudio.cameras=",
    "pstudio.cameras=0",
    "adt.image_size=2",
    "adt.image_size=8192",
    "adt.focal=100000",
    "adt.oversample=1",
    "minival_per_source=0",
    "seed=4294967295",
]


@pytest.mark.parametrize("assignments, message", REFUSED)
def test_a_value_outside_its_range_is_refused_with_the_range(assignments, message):
    with pytest.raises(ValueError) as error:
        with_overrides(RunConfig(), assignments)
    assert str(error.value) == message


def test_the_defaults_are_in_range():
    check_ranges(RunConfig())
    assert with_overrides(RunConfig(), []) == RunConfig()


@pytest.mark.parametrize("assignment", ALLOWED)
def test_boundary_values_are_accepted(assignment):
    check_ranges(with_overrides(RunConfig(), [assignment]))


def test_min_frames_may_equal_chunk_frames():
    config = with_overrides(RunConfig(), ["adt.chunk_frames=2", "adt.min_frames=2"])
    adt = config.section(AdtConfig)
    assert (adt.chunk_frames, adt.min_frames) == (2, 2)


def test_every_number_and_tuple_field_declares_a_range():
    def fields(node):
        declared = {field.name: field for field in dataclasses.fields(node)}
        for name, value, kind in settings_items(node):
            if dataclasses.is_dataclass(kind):
                yield from fields(value)  # a section, the sources' ones included
            elif kind not in (bool, str):
                yield f"{type(node).__name__}.{name}", declared[name].metadata.get("range")

    found = dict(fields(RunConfig()))
    assert {"AdtConfig.chunk_frames", "DriveTrackConfig.cameras", "PstudioConfig.oversample"} <= set(found)
    assert [name for name, rule in found.items() if rule is None] == []


def test_a_config_rebuilt_from_a_run_record_is_checked_too():
    record = RunConfig().to_dict()
    record["seed"] = True
    record["adt"]["image_size"] = 512.0
    record["pstudio"]["mask_min_agreement"] = float("nan")
    record["drivetrack"]["cameras"] = [1, 6]
    with pytest.raises(ValueError) as error:
        check_ranges(config_from_dict(RunConfig, record))
    assert str(error.value) == (
        "seed=true: must be an integer in [0, 4294967295]; "
        "drivetrack.cameras=1,6: must be one or more distinct integers in [1, 5]; "
        "adt.image_size=512.0: must be an integer in [2, 8192] and even; "
        "pstudio.mask_min_agreement=nan: must be a number in [0, 1]"
    )
    check_ranges(config_from_dict(RunConfig, RunConfig().to_dict()))


def test_the_cli_refuses_a_bad_setting_before_any_work(tmp_path):
    result = run_in_process("pstudio", "--set", "adt.image_size=0", "--output", str(tmp_path / "out"))
    assert result.returncode == 2
    # Beam may log an import warning first; the refusal is the last line (run.py may prefix it).
    message = "--set adt.image_size=0: must be an integer in [2, 8192] and even"
    assert result.stderr.splitlines()[-1].endswith(message)
    assert "Traceback" not in result.stdout + result.stderr
    assert list(tmp_path.iterdir()) == []
