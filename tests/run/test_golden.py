"""Fresh runs against the golden fixtures (``tests/fixtures/``, written by ``tests/support/golden.py``):
each sample run's clip names, track and frame counts, and clip hashes (compared only where the
recorded library versions are the installed ones and the sample input is one recorded: a sample
world's ray casting depends on the CPU), and each sample release clip's verdict.

DriveTrack's and Panoptic Studio's sample runs are the shared ``reference_run`` (the same sample world,
read from the cache through ``--input``: the same bytes as the recorded command without it); the
release runs are the shared ``sample_release_runs``."""

from __future__ import annotations

import pytest

from tests.support import golden
from tests.support.adt_excerpt import needs_excerpt
from tests.support.cli import run_in_process

SOURCES = [
    "drivetrack",
    "pstudio",
    pytest.param("adt", marks=needs_excerpt),
]
HOW = f"if the change is meant, record it: {golden.REGENERATE} (docs/testing.md)"


@pytest.fixture(scope="module")
def sample_runs(reference_run, tmp_path_factory):
    """source -> the output folder of its sample run, made on first use."""
    made: dict[str, str] = {}

    def output(source: str) -> str:
        if source not in made:
            if source == "adt":
                out = str(tmp_path_factory.mktemp("golden_adt"))
                args = golden.concrete(golden.sample_args("adt"), out)
                result = run_in_process("adt", *args[2:])
                assert result.returncode == 0, result.stderr[-3000:]
                made[source] = out
            else:
                made[source] = reference_run(source)
        return made[source]

    return output


@pytest.fixture(scope="module")
def sample_records(sample_runs):
    """source -> (recorded, fresh) sample records."""
    made: dict[str, tuple[dict, dict]] = {}

    def records(source: str) -> tuple[dict, dict]:
        if source not in made:
            recorded = golden.read(golden.sample_path(source))
            assert recorded is not None, f"no {golden.sample_path(source)}; {HOW}"
            made[source] = recorded, golden.sample_record(sample_runs(source), source)
        return made[source]

    return records


def same_clips(recorded: set[str], fresh: set[str], what: str) -> None:
    missing, extra = sorted(recorded - fresh), sorted(fresh - recorded)
    assert not missing and not extra, f"{what}: clips missing {missing}, extra {extra}; {HOW}"


@pytest.mark.parametrize("source", ["drivetrack", "pstudio", "adt"])
def test_the_fixtures_hold_the_commands_the_regenerator_runs(source):
    recorded = golden.read(golden.sample_path(source))
    assert recorded is not None and recorded["args"] == golden.sample_args(source), HOW
    release = golden.read(golden.RELEASE_PATH)
    assert release is not None and release[source]["args"] == golden.release_args(source), HOW


@pytest.mark.parametrize("source", SOURCES)
def test_clip_names_tracks_and_frames_are_the_recorded_ones(source, sample_records):
    recorded, fresh = sample_records(source)
    same_clips(set(recorded["clips"]), set(fresh["clips"]), source)
    differ = []
    for name, entry in sorted(recorded["clips"].items()):
        counts = {key: fresh["clips"][name][key] for key in ("frames", "tracks")}
        expected = {key: entry[key] for key in ("frames", "tracks")}
        if counts != expected:
            differ.append(f"{name} {counts}, recorded {expected}")
    assert not differ, f"{source}: {'; '.join(differ)}; {HOW}"


@pytest.mark.parametrize("source", SOURCES)
def test_clip_bytes_are_the_recorded_ones(source, sample_records):
    recorded, fresh = sample_records(source)
    installed = (fresh["python"], fresh["versions"])
    if (recorded["python"], recorded["versions"]) != installed:
        differ = [
            f"{name} {recorded['versions'].get(name)} (installed {version})"
            for name, version in sorted(fresh["versions"].items())
            if recorded["versions"].get(name) != version
        ]
        if recorded["python"] != fresh["python"]:
            differ.append(f"Python {recorded['python']} (installed {fresh['python']})")
        pytest.skip(f"{source}: hashes not compared, recorded with {', '.join(differ)}")
    ((world, hashes),) = fresh["sha256"].items()
    if world not in recorded["sha256"]:
        pytest.skip(
            f"{source}: hashes not compared: this machine's sample input {world} is not a recorded one "
            f"({', '.join(sorted(recorded['sha256']))}; ray casting the sample world depends on the CPU); "
            f"{golden.REGENERATE} adds it"
        )
    expected = recorded["sha256"][world]
    same_clips(set(expected), set(hashes), source)
    changed = [name for name, digest in expected.items() if digest != hashes[name]]
    assert not changed, f"{source}: clip bytes differ from the recorded ones: {changed}; {HOW}"


@pytest.mark.parametrize("source", SOURCES)
def test_release_verdicts_are_the_recorded_ones(source, sample_release_runs):
    result = sample_release_runs(source)
    assert result.returncode == 0, result.stderr[-3000:]
    recorded = golden.read(golden.RELEASE_PATH)
    assert recorded is not None and source in recorded, f"no {source} in {golden.RELEASE_PATH}; {HOW}"
    expected, fresh = recorded[source]["clips"], golden.verdicts_of(str(sample_release_runs.out), source)
    same_clips(set(expected), set(fresh), f"{source} release")
    differ = [
        f"{clip}: {fresh[clip]}, recorded {entry}" for clip, entry in expected.items() if entry != fresh[clip]
    ]
    assert not differ, f"{source} release verdicts: {'; '.join(differ)}; {HOW}"
