"""The unit ledger (``pipeline/runner/ledger.py``): a finished unit resumes on its checkpoint's record
of its clip files (size and SHA-256) without decoding a clip, a clip whose bytes changed is redone
even at the same size, an earlier version's checkpoint without sizes is checked by its hashes and
gains them, and the deep check, when asked, decodes every clip."""

from __future__ import annotations

import dataclasses
import json
import os

import pytest

from pipeline import sources
from pipeline.export import invariants
from pipeline.export.layout import audit_path, checkpoint_path, clip_path
from pipeline.io import clip_reader
from pipeline.runner.checkpoint import UnitCheckpoint
from pipeline.runner.stages import UnitJob, run_group
from pipeline.settings.fields import with_overrides
from pipeline.settings.run_config import RunConfig
from tests.support.toy.source import TOY, SpecFile, write_sample

UNIT, CLIP = "walk", "toy_walk"


@pytest.fixture
def finished(tmp_path):
    """A job of the toy source whose one unit an earlier run finished; the job is a new run's."""
    sources.register(TOY)
    root = write_sample(str(tmp_path / "in"))
    job = UnitJob(TOY, root, RunConfig(), str(tmp_path / "out"), run_id="first")
    (outcome,) = run_group(job, [SpecFile(UNIT)])
    assert outcome.reports[0].written and not outcome.resumed
    yield dataclasses.replace(job, run_id="second")
    sources.unregister(TOY.name)


def record(job: UnitJob) -> dict:
    return json.load(open(checkpoint_path(job.output, "toy", UNIT)))


def never(*args, **kwargs):
    raise AssertionError("a clip was decoded")


def test_a_finished_unit_resumes_without_decoding_its_clips(finished, monkeypatch):
    monkeypatch.setattr(invariants, "inspect_clip_bytes", never)
    monkeypatch.setattr(clip_reader, "read_clip_archive", never)
    data = open(clip_path(finished.output, "toy", CLIP), "rb").read()
    (outcome,) = run_group(finished, [SpecFile(UNIT)])
    assert outcome.resumed
    stamped = record(finished)
    assert (stamped["run"], stamped["resumed"]) == ("second", True)
    assert stamped["sizes"] == {CLIP: len(data)}


def test_a_clip_changed_on_disk_at_the_same_size_is_redone(finished):
    path = clip_path(finished.output, "toy", CLIP)
    good = open(path, "rb").read()
    changed = bytearray(good)
    changed[len(good) // 2] ^= 0xFF
    open(path, "wb").write(changed)
    assert finished.ledger.resume(UNIT, None) is None
    (outcome,) = run_group(finished, [SpecFile(UNIT)])
    assert not outcome.resumed
    assert open(path, "rb").read() == good


@pytest.mark.parametrize("damage", ["longer", "no audit table"])
def test_a_clip_of_another_size_or_without_its_audit_table_is_redone(finished, damage):
    if damage == "longer":
        open(clip_path(finished.output, "toy", CLIP), "ab").write(b"\0")
    else:
        os.remove(audit_path(finished.output, "toy", CLIP))
    assert finished.ledger.resume(UNIT, None) is None


def test_a_checkpoint_without_sizes_is_checked_by_its_hashes_and_gains_them(finished):
    path = checkpoint_path(finished.output, "toy", UNIT)
    earlier = record(finished)
    sizes = earlier.pop("sizes")
    open(path, "w").write(json.dumps(earlier))
    assert finished.ledger.resume(UNIT, None) is not None
    assert record(finished)["sizes"] == sizes

    open(path, "w").write(json.dumps(earlier))
    clip = clip_path(finished.output, "toy", CLIP)
    changed = bytearray(open(clip, "rb").read())
    changed[-40] ^= 0xFF
    open(clip, "wb").write(changed)
    assert finished.ledger.resume(UNIT, None) is None


def test_the_deep_check_decodes_every_clip(finished, monkeypatch):
    checked = []

    def spy(data, *args, **kwargs):
        checked.append(len(data))
        return ["a violation, for the test"], {}

    monkeypatch.setattr(invariants, "inspect_clip_bytes", spy)
    asked = dataclasses.replace(finished, config=with_overrides(RunConfig(), ["resume_decode=true"]))
    deep = asked.ledger  # the run-wide setting asks for it
    assert deep.deep and deep.resume(UNIT, None) is None
    assert checked == [record(finished)["sizes"][CLIP]]
    assert finished.ledger.resume(UNIT, None) is not None  # not asked: not decoded
    assert len(checked) == 1


@pytest.mark.parametrize("sizes", [[], {CLIP: -1}, {CLIP: True}, {CLIP: "12"}])
def test_a_checkpoint_with_malformed_sizes_is_refused(finished, sizes):
    malformed = record(finished) | {"sizes": sizes}
    with pytest.raises(ValueError, match="sizes"):
        UnitCheckpoint.from_json(malformed)
    open(checkpoint_path(finished.output, "toy", UNIT), "w").write(json.dumps(malformed))
    assert finished.ledger.read(UNIT) is None
