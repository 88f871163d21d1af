"""DriveTrack's units: one camera of one segment (``SegmentCamera``), listed from a Waymo Open v2
split folder (on a release run, the pairs the release names a clip of, each to make only those
clips)."""

from __future__ import annotations

import dataclasses
import re
from typing import TYPE_CHECKING

from pipeline.drivetrack.reader import list_segments
from pipeline.drivetrack.settings import DriveTrackConfig
from pipeline.sources import UnitPlan

if TYPE_CHECKING:
    from pipeline.settings.run_config import RunConfig

# A release clip name: tapvid3d_<segment>_<camera>_<object id>, the segment named as Waymo names
# them (<context>_<start>_<ms>_<end>_<ms>); the object id may itself hold '_'.
RELEASE_NAME = re.compile(r"tapvid3d_([^_]+_\d+_\d+_\d+_\d+)_(\d+)_(.+)")


def clip_name(segment: str, camera: int, object_id: str) -> str:
    """The release's DriveTrack clip name."""
    return f"tapvid3d_{segment}_{camera}_{object_id}"


def clip_scene(name: str) -> str | None:
    """The scene of a DriveTrack clip name: its Waymo segment; None for a name not shaped as
    ``RELEASE_NAME``."""
    parsed = RELEASE_NAME.fullmatch(name)
    return parsed[1] if parsed else None


def scene_of(unit: SegmentCamera) -> str:
    """A unit's scene: its Waymo segment (every camera of a segment is one scene)."""
    return unit.segment


@dataclasses.dataclass(frozen=True, order=True)
class SegmentCamera:
    """A DriveTrack unit: the clips of one camera of one segment. The cameras of a segment share its
    lidar, so they are annotated together (``group``)."""

    segment: str
    camera: int

    @property
    def name(self) -> str:
        return f"{self.segment}/camera_{self.camera}"

    @property
    def group(self) -> str:
        return self.segment


def list_units(
    input_root: str, config: RunConfig, release: frozenset[str] | None = None
) -> UnitPlan[SegmentCamera]:
    """Every (segment, camera) pair of the split folder, sorted; on a release run, the pairs the
    release names a clip of, each to make only those clips."""
    segments = list_segments(input_root)
    units = [SegmentCamera(s, c) for s in segments for c in config.section(DriveTrackConfig).cameras]
    if release is None:
        return UnitPlan(units)
    expected = {
        unit.name: names
        for unit in units
        if (
            names := tuple(
                sorted(n for n in release if n.startswith(clip_name(unit.segment, unit.camera, "")))
            )
        )
    }
    kept = [unit for unit in units if unit.name in expected]
    made = {name for names in expected.values() for name in names}
    absent, not_made = {}, {}
    cameras = ",".join(str(c) for c in config.section(DriveTrackConfig).cameras)
    for name in sorted(release - made):
        parsed = RELEASE_NAME.fullmatch(name)
        if parsed is None:
            absent[name] = "not a DriveTrack clip name (tapvid3d_<segment>_<camera>_<object id>)"
        elif parsed[1] not in segments:
            absent[name] = f"segment {parsed[1]} is not in --input"
        else:
            not_made[name] = f"camera {parsed[2]} is not in drivetrack.cameras={cameras}"
    return UnitPlan(kept, expected=expected, absent=absent, not_made=not_made)
