"""DriveTrack's units: (segment, camera), listed from a Waymo Open v2 split folder (on a release run,
the pairs the release names a clip of, each to make only those clips), and their names."""

from __future__ import annotations

import re
from typing import TYPE_CHECKING

from pipeline.drivetrack.reader import list_segments
from pipeline.drivetrack.records import clip_name
from pipeline.sources import UnitPlan

if TYPE_CHECKING:
    from pipeline.settings.run_config import RunConfig

# A release clip name: tapvid3d_<segment>_<camera>_<object id>, the segment named as Waymo names
# them (<context>_<start>_<ms>_<end>_<ms>); the object id may itself hold '_'.
RELEASE_NAME = re.compile(r"tapvid3d_([^_]+_\d+_\d+_\d+_\d+)_(\d+)_(.+)")


def list_units(input_root: str, config: RunConfig, release: frozenset[str] | None = None) -> UnitPlan:
    """Every (segment, camera) pair of the split folder, sorted; on a release run, the pairs the
    release names a clip of, each to make only those clips."""
    segments = list_segments(input_root)
    units = [(s, c) for s in segments for c in config.drivetrack.cameras]
    if release is None:
        return UnitPlan(units)
    expected = {
        unit_name(unit): names
        for unit in units
        if (names := tuple(sorted(n for n in release if n.startswith(clip_name(*unit, "")))))
    }
    kept = [unit for unit in units if unit_name(unit) in expected]
    made = {name for names in expected.values() for name in names}
    absent, not_made = {}, {}
    cameras = ",".join(str(c) for c in config.drivetrack.cameras)
    for name in sorted(release - made):
        parsed = RELEASE_NAME.fullmatch(name)
        if parsed is None:
            absent[name] = "not a DriveTrack clip name (tapvid3d_<segment>_<camera>_<object id>)"
        elif parsed[1] not in segments:
            absent[name] = f"segment {parsed[1]} is not in --input"
        else:
            not_made[name] = f"camera {parsed[2]} is not in drivetrack.cameras={cameras}"
    return UnitPlan(kept, expected=expected, absent=absent, not_made=not_made)


def unit_name(unit: tuple[str, int]) -> str:
    return f"{unit[0]}/camera_{unit[1]}"
