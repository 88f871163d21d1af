"""ADT's per-frame reads on the real excerpt against their plain forms: the object poses (every posed
object's ``transform_scene_object``, converted when read) and the instance classes of a frame's ids
(one ``reader.instance`` look-up per id)."""

import numpy as np
import pytest

from pipeline.adt.frames import close_sequence, open_sequence
from pipeline.adt.records import IdRuns
from pipeline.adt.sample.excerpt import EXCERPT_SETTINGS
from pipeline.adt.settings import AdtConfig
from pipeline.core.errors import InputError
from pipeline.settings.fields import with_overrides
from pipeline.settings.run_config import RunConfig
from tests.support.adt_excerpt import SAMPLE, needs_excerpt

pytestmark = needs_excerpt


@pytest.fixture(scope="module")
def opened():
    config = with_overrides(RunConfig(), list(EXCERPT_SETTINGS))
    sequence = open_sequence(str(SAMPLE), config.section(AdtConfig))
    yield sequence
    close_sequence(sequence)


def test_object_poses_are_every_boxs_pose(opened):
    reader = opened.frames.reader
    timestamp = int(opened.stamps[0])
    boxes = reader.provider.get_object_3d_boundingboxes_by_timestamp_ns(timestamp).data()
    poses = reader.object_poses(timestamp)
    assert len(poses) == len(boxes) > 0
    assert list(poses) == list(boxes)
    for object_id, box in boxes.items():
        assert object_id in poses
        expected = np.asarray(box.transform_scene_object.to_matrix(), dtype=np.float64)
        np.testing.assert_array_equal(poses[object_id], expected)
        assert poses[object_id].dtype == np.float64 and poses[object_id] is poses[object_id]
    assert 0 not in poses
    with pytest.raises(KeyError):
        poses[0]


def plain_instances(reader, ids):
    """(human, dynamic) ids among ``ids``, one look-up each."""
    human, dynamic = set(), set()
    for instance_id in ids.tolist():
        if instance_id:
            kind, motion = reader.instance(instance_id)
            if kind == "human":
                human.add(instance_id)
            elif motion == "dynamic":
                dynamic.add(instance_id)
    return human, dynamic


def test_instances_are_each_ids_class(opened):
    frames = opened.frames
    for timestamp in opened.stamps.tolist():
        present = IdRuns.of(frames.frame(timestamp).ids).unique()
        for ids in (present, present[:5], present[-5:], present):
            got = frames.instances(ids)
            assert (got.human, got.dynamic) == plain_instances(frames.reader, ids)
        assert frames.instances(present).human and frames.instances(present).dynamic
    with pytest.raises(InputError, match="instance 12345 is not in instances.json"):
        frames.instances(np.array([0, 12345], np.uint64))
