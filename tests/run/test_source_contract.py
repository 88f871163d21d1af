"""One contract for every source (``Source.annotate_group``, pipeline/sources.py): each hands its
units on one by one as an iterator; each makes only the clips the run wants (``RunChoices.wants``:
a release run's names, and those ``--queries-from`` holds); and a wanted clip a unit does not make
gets its reason from shared code, in the same words whatever the source."""

from __future__ import annotations

import inspect

import numpy as np
import pytest

from pipeline import sources
from pipeline.core.errors import InputError
from pipeline.core.outcomes import UnitClips
from pipeline.drivetrack.sample.waymo_world import SEGMENT
from pipeline.drivetrack.units import SegmentCamera
from pipeline.io.given_queries import GivenQueries
from pipeline.pstudio import annotate as studio
from pipeline.pstudio.sample.dynamic3dgs_files import SEQUENCE
from pipeline.pstudio.units import SequenceCamera
from pipeline.runner.stages import UnitJob, annotate_group, only_wanted
from pipeline.runner.verdicts import unmade_reason
from pipeline.settings.run_config import RunConfig
from tests.support.toy.source import TOY, write_sample


@pytest.mark.parametrize("name", sources.BUILT_IN)
def test_every_source_hands_its_units_on_one_by_one(name):
    assert inspect.isgeneratorfunction(sources.get(name).annotate_group)


@pytest.fixture
def toy():
    sources.register(TOY)
    yield TOY
    sources.unregister(TOY.name)


def test_a_wanted_name_a_unit_neither_made_nor_explained_gets_the_shared_reason(toy, tmp_path):
    """The toy makes ``toy_walk`` and says nothing of ``toy_gone``: the run says why, as it would for
    any source; a name the unit explained keeps its source's words."""
    root = write_sample(str(tmp_path / "in"))
    job = UnitJob(TOY, root, RunConfig(), str(tmp_path / "out"), expected={"walk": ("toy_walk", "toy_gone")})
    ((made,),) = [list(annotate_group(job, TOY.list_units(root, RunConfig()).units))]
    assert [clip.name for clip in made.clips] == ["toy_walk"]
    assert made.not_made == {"toy_gone": "unit walk made no clip of this name"}
    explained = UnitClips((), {"toy_gone": "its own reason", "toy_other": "not wanted"})
    kept = only_wanted(explained, frozenset({"toy_gone", "toy_walk"}), unmade_reason("walk"))
    assert kept.not_made == {"toy_gone": "its own reason", "toy_walk": "unit walk made no clip of this name"}


def test_a_name_queries_from_lacks_is_said_so(tmp_path):
    (tmp_path / "given" / "toy").mkdir(parents=True)
    reason = unmade_reason("walk", GivenQueries(str(tmp_path / "given"), "toy"))
    assert reason("toy_walk") == "--queries-from holds no clip of this name"
    assert unmade_reason("walk", GivenQueries("", "toy"))("toy_walk") == "unit walk made no clip of this name"


def test_panoptic_studio_annotates_only_the_cameras_whose_clip_is_wanted(pstudio_sample, monkeypatch):
    root, _ = pstudio_sample
    units = [SequenceCamera(SEQUENCE, 3), SequenceCamera(SEQUENCE, 8)]
    made = []
    candidate = studio.candidate_clip
    monkeypatch.setattr(
        studio, "candidate_clip", lambda unit, *rest: made.append(unit.camera_id) or candidate(unit, *rest)
    )
    results = list(studio.annotate_group(root, units, RunConfig(), [frozenset({"dome_3"}), frozenset()]))
    assert made == [3]
    assert [clip.name for clip in results[0].clips] == ["dome_3"] and results[1] == UnitClips(())


def test_drivetrack_tracks_only_the_wanted_objects(sample_split):
    unit = SegmentCamera(SEGMENT, 1)
    (nothing,) = sources.get("drivetrack").annotate_group(sample_split[0], [unit], RunConfig(), [frozenset()])
    assert nothing.clips == () and nothing.not_made == {}


def test_an_unreadable_queries_from_clip_fails_its_unit_alone(pstudio_sample, tmp_path):
    """A ``--queries-from`` clip that would need pickle fails the unit whose clip it is; the group's
    other unit goes on (its clip is not in --queries-from: it makes none)."""
    root, _ = pstudio_sample
    given = tmp_path / "given" / "pstudio"
    given.mkdir(parents=True)
    np.savez(given / "dome_3.npz", queries_xyt=np.array([object()], dtype=object))  # a pickled member
    config = RunConfig(queries_from=str(tmp_path / "given"))
    units = [SequenceCamera(SEQUENCE, 3), SequenceCamera(SEQUENCE, 8)]
    failed, other = studio.annotate_group(root, units, config, [None, None])
    assert isinstance(failed, InputError) and "object array" in str(failed)
    assert other == UnitClips(())
