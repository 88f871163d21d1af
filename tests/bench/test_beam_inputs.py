"""``--beam``'s inputs and clock: each source's entry makes, by links (no bytes copied), an input
that ``pipeline.run`` lists as exactly the groups asked for, each the size of the bench's unit; a
run's serial start is read from its checkpoints (their mtimes less the seconds they record)."""

from __future__ import annotations

import json
import os

import pytest

from benchmarks.beam import BeamRun, unit_span
from benchmarks.entry import entry
from pipeline import sources
from pipeline.core.benchmark import UnitSetup
from pipeline.runner.command import command_parser
from pipeline.settings.rule_sets import configured
from tests.support.adt_excerpt import needs_excerpt

GROUPS = 8


def setup_of(source: str, input_root: str, overrides: list[str], size: str = "quick") -> UnitSetup:
    """A setup as the source's ``prepare`` returns it, with what ``beam_input`` reads."""
    return UnitSetup(source, input_root, [], overrides, 1, [], 1, "", size=size)


def listed_groups(source: str, setup: UnitSetup, folder: str) -> dict[str, list]:
    """Group key -> its units, as ``pipeline.run`` lists them from the entry's ``beam_input`` in
    ``folder`` with the setup's settings."""
    arguments = entry(source).beam_input(setup, folder, GROUPS)
    sets = [word for setting in setup.overrides for word in ("--set", setting)]
    args = command_parser().parse_args(["--source", source, *arguments, *sets])
    plan = sources.get(source).list_units(args.input, configured(args.overrides, release_run=False), None)
    groups: dict[str, list] = {}
    for unit in plan.units:
        groups.setdefault(sources.get(source).group_key(unit), []).append(unit)
    return groups


def test_drivetrack_segments_are_the_bench_segments_files_hard_linked(tmp_path):
    from pipeline.drivetrack.bench import SEGMENT

    segment = tmp_path / "segment"
    components = ("camera_image", "lidar", "vehicle_pose")
    for number, component in enumerate(components):
        (segment / component).mkdir(parents=True)
        (segment / component / f"{SEGMENT}.parquet").write_bytes(bytes([number]) * 100)
    (segment / ".complete-v3-30f").write_text("")
    folder = tmp_path / "beam"
    folder.mkdir()
    groups = listed_groups("drivetrack", setup_of("drivetrack", str(segment), ["rules=release"]), str(folder))
    assert len(groups) == GROUPS and all(len(units) == 3 for units in groups.values())
    assert sorted(os.listdir(folder)) == sorted(components)
    for component in components:
        names = os.listdir(folder / component)
        assert len(names) == GROUPS and f"{SEGMENT}.parquet" in names
        for name in names:  # one file, GROUPS + 1 names
            assert os.path.samefile(folder / component / name, segment / component / f"{SEGMENT}.parquet")
        assert os.stat(segment / component / f"{SEGMENT}.parquet").st_nlink == GROUPS + 1


def test_pstudio_groups_are_whole_groups_of_linked_sequences(tmp_path):
    from pipeline.pstudio.bench import CAMERAS_QUICK, write_sequence
    from pipeline.pstudio.units import CAMERAS_PER_GROUP

    root = tmp_path / "sequence"
    write_sequence(str(root), {"frames": 2, "per_person": 20, "floor": 30, "wall": 30}, CAMERAS_QUICK)
    folder = tmp_path / "beam"
    folder.mkdir()
    groups = listed_groups("pstudio", setup_of("pstudio", str(root), []), str(folder))
    # 4 cameras a sequence at the quick size: one whole group of 3 each, from 8 linked sequences.
    assert len(groups) == GROUPS
    assert all([unit.camera for unit in units] == list(range(CAMERAS_PER_GROUP)) for units in groups.values())
    assert len({units[0].sequence for units in groups.values()}) == GROUPS
    for sequence in os.listdir(folder / "data"):
        assert all(os.path.islink(item.path) for item in os.scandir(folder / "data" / sequence))
        params = folder / "output" / "bench" / sequence / "params.npz"
        assert os.path.islink(params) and os.path.samefile(params, root / "output/bench/dome/params.npz")


def test_pstudio_takes_as_many_groups_from_one_full_sequence(tmp_path):
    """27 cameras a sequence at the full size: 8 groups are cameras 0-23 of one sequence (4 for
    each of two workers)."""
    from pipeline.pstudio.bench import beam_input

    for kind, name in (("data", "train_meta.json"), ("output/bench", "params.npz")):
        (tmp_path / "sequence" / kind / "dome").mkdir(parents=True)
        (tmp_path / "sequence" / kind / "dome" / name).write_text("")
    (tmp_path / "beam").mkdir()
    setup = setup_of("pstudio", str(tmp_path / "sequence"), [], size="full")
    arguments = beam_input(setup, str(tmp_path / "beam"), GROUPS)
    assert arguments[-2:] == ["--set", "pstudio.cameras=" + ",".join(str(camera) for camera in range(24))]
    assert os.listdir(tmp_path / "beam" / "data") == os.listdir(tmp_path / "beam/output/bench") == ["dome_0"]


@needs_excerpt
def test_adt_sequences_are_links_to_the_excerpt(tmp_path):
    from pipeline.adt.sample.excerpt import EXCERPT_SETTINGS, excerpt_path

    excerpt = excerpt_path()
    assert excerpt is not None
    setup = setup_of("adt", excerpt, list(EXCERPT_SETTINGS))
    groups = listed_groups("adt", setup, str(tmp_path))
    assert len(groups) == GROUPS and all(len(units) == 1 for units in groups.values())
    assert sorted(os.readlink(tmp_path / name) for name in os.listdir(tmp_path)) == [excerpt] * GROUPS


def test_the_serial_start_is_read_from_the_checkpoints(tmp_path):
    """Three units ending at 105, 107 and 112 s (their checkpoints' mtimes) after 4, 6 and 3 s of
    work: the first started at 101, the last ended at 112."""
    folder = tmp_path / "units" / "toy"
    folder.mkdir(parents=True)
    for name, end, seconds in (("a", 105.0, 4.0), ("b", 107.0, 6.0), ("c", 112.0, 3.0)):
        path = folder / f"{name}.json"
        path.write_text(json.dumps({"unit": name, "seconds": seconds}))
        os.utime(path, (end, end))
    first, last, units = unit_span(str(tmp_path), "toy")
    assert (first, last, units) == (pytest.approx(101.0), pytest.approx(112.0), 3)
    # A command from 95 s to 114 s: 6 s before the first unit, 2 s after the last.
    run = BeamRun(2, 114.0 - 95.0, first - 95.0, 114.0 - last, units)
    assert run.serial_s == pytest.approx(8.0)
    with pytest.raises(RuntimeError, match="no unit checkpoint"):
        unit_span(str(tmp_path), "adt")
