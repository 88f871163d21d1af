"""DriveTrack (Waymo Open v2) as a Source: (segment, camera) units, one clip per vehicle; the
cameras of a segment are annotated together (one read of its lidar)."""

from __future__ import annotations

import operator

from pipeline.drivetrack.annotate import annotate_group
from pipeline.drivetrack.settings import DriveTrackConfig
from pipeline.drivetrack.units import SegmentCamera, clip_scene, list_units, scene_of
from pipeline.sources import Licence, Source


def sample_input(folder: str) -> str:
    """Write (once) the embedded sample world, a Waymo v2 split folder; returns its path."""
    from pipeline.drivetrack.sample.waymo_world import write_sample_split

    return write_sample_split(folder)


SOURCE: Source[SegmentCamera] = Source(
    name="drivetrack",
    bench="pipeline.drivetrack.bench",
    list_units=list_units,
    annotate_group=annotate_group,
    sample_input=sample_input,
    mask_min_agreement=lambda config: config.section(DriveTrackConfig).mask_min_agreement,
    sweepable=("drivetrack.mask_min_agreement",),
    settings=DriveTrackConfig,
    group_of=operator.attrgetter("group"),
    scene_of=scene_of,
    clip_scene=clip_scene,
    licence=Licence(
        "Waymo Open Dataset License Agreement for Non-Commercial Use: non-commercial use only",
        ("https://waymo.com/open/terms/",),
    ),
)
