"""ADT chunks annotated in groups (``pipeline.adt.annotate.annotate_group``): a group opens its
sequence once (and closes it once, after its last chunk) and makes, chunk by chunk, the clips each
chunk makes alone; an unreadable sequence fails every chunk of the group, each error naming its own
unit."""

import numpy as np

from pipeline import sources
from pipeline.adt import annotate
from pipeline.adt import units as adt_units
from pipeline.adt.units import SequenceChunk
from pipeline.core.errors import InputError
from pipeline.settings.fields import with_overrides
from pipeline.settings.run_config import RunConfig
from tests.support.adt_excerpt import SAMPLE, needs_excerpt

# The excerpt's ground-truth window holds two frames: one chunk each.
ONE_FRAME_CHUNKS = ("adt.chunk_frames=1", "adt.min_frames=1", "adt.max_gt_offset_ms=40")


def _count_openings_and_closings(monkeypatch) -> tuple[list, list]:
    """(opened, closed): the sequences ``open_sequence`` returns and ``close_sequence`` is given."""
    opened, closed = [], []
    open_sequence, close_sequence = annotate.open_sequence, annotate.close_sequence

    def counted_open(*args):
        opened.append(open_sequence(*args))
        return opened[-1]

    def counted_close(sequence):
        closed.append(sequence)
        close_sequence(sequence)

    monkeypatch.setattr(annotate, "open_sequence", counted_open)
    monkeypatch.setattr(annotate, "close_sequence", counted_close)
    return opened, closed


@needs_excerpt
def test_a_group_opens_its_sequence_once_and_makes_each_chunks_own_clip(monkeypatch):
    config = with_overrides(RunConfig(), list(ONE_FRAME_CHUNKS))
    units = adt_units.list_units(str(SAMPLE), config).units
    assert len(units) == 2
    assert len({unit.group for unit in units}) == 1
    opened, closed = _count_openings_and_closings(monkeypatch)
    alone = [list(annotate.annotate_group(str(SAMPLE), [unit], config, [None]))[0].clips for unit in units]
    assert len(opened) == 2
    assert closed == opened  # a unit alone opens and closes its sequence
    del opened[:], closed[:]
    made = annotate.annotate_group(str(SAMPLE), units, config, [None] * len(units))
    together = [next(made)]
    assert len(opened) == 1
    assert not closed  # still open for the group's next chunk
    together += list(made)
    assert len(opened) == 1
    assert closed == opened
    assert opened[0].frames.reader.provider is None
    for (one,), (grouped,) in zip(alone, [made.clips for made in together], strict=True):
        assert grouped.name == one.name
        assert grouped.images_jpeg == one.images_jpeg
        for field in ("tracks_xyz", "visibility", "queries_xyt", "extrinsics_w2c", "frame_ids"):
            np.testing.assert_array_equal(getattr(grouped, field), getattr(one, field))


@needs_excerpt
def test_a_group_stopped_early_still_closes_its_sequence(monkeypatch):
    config = with_overrides(RunConfig(), list(ONE_FRAME_CHUNKS))
    opened, closed = _count_openings_and_closings(monkeypatch)
    units = adt_units.list_units(str(SAMPLE), config).units
    made = annotate.annotate_group(str(SAMPLE), units, config, [None] * len(units))
    next(made)
    made.close()  # the caller stops after the first chunk (a Ctrl-C, a failed write)
    assert len(opened) == 1
    assert closed == opened


def test_an_unreadable_sequence_fails_each_chunk_under_its_own_name(tmp_path):
    sequence = tmp_path / "Apartment_release_broken_seq001"
    sequence.mkdir()
    units = [SequenceChunk(str(sequence), chunk) for chunk in range(3)]
    results = list(annotate.annotate_group(str(tmp_path), units, RunConfig(), [None] * len(units)))
    assert len(results) == 3
    for unit, result in zip(units, results, strict=True):
        assert isinstance(result, InputError)
        assert str(result).startswith(f"{unit.name}: ")


def test_groups_are_three_chunks_of_one_sequence():
    key = sources.get("adt").group_key
    assert key(SequenceChunk("/data/seq_a", 0)) == key(SequenceChunk("/data/seq_a", 2))
    assert key(SequenceChunk("/data/seq_a", 2)) != key(SequenceChunk("/data/seq_a", 3))
    assert key(SequenceChunk("/data/seq_a", 3)) == key(SequenceChunk("/data/seq_a", 5))
    assert key(SequenceChunk("/data/seq_a", 0)) != key(SequenceChunk("/data/seq_b", 0))
