"""Where DriveTrack's visibility disagrees with the ray-cast truth on the worlds of ``driving_family``,
by category, under one rule set:

- ``covered, called visible``: another object truly covers the point (nearer by at least the
  occlusion margin) and the clip calls it visible;
- ``visible, called covered, another object near``: truly visible, called invisible, and another
  object's surface passes within 0.25 m (at 40 m, in proportion to the distance) of the ray;
- ``visible, called covered, none near``: the same with no other object that near;
- ``own surface hides, called visible``: the object's own surface truly hides the point;
- ``covered by the ground, called visible``.

    python -m tests.support.visibility_errors --seeds 0,2,8,11 --rules refined
"""

from __future__ import annotations

import collections
import os
import sys

import numpy as np

from pipeline.commandline import StrictParser
from pipeline.drivetrack.sample.waymo_world import FIRST_TIMESTAMP_MICROS, frame_time
from pipeline.settings.fields import with_overrides, with_rules
from pipeline.settings.run_config import RunConfig
from tests.support import driving_family
from tests.support.cli import REPO
from tests.support.units import drivetrack_segment_clips
from tests.support.visibility_family import RULES, world_split
from tests.support.waymo_truth import seen, true_tracks

# Another object is near a ray when it crosses one of eight rays aimed this far (at 40 m, in
# proportion to the distance) around the point.
NEAR_M_AT_40 = 0.25


def hit_objects(hits: dict[str, np.ndarray], names: list[str]) -> np.ndarray:
    """[M] the object id each ray of ``DrivingWorld.cast`` hit first ('' the ground, '-' nothing)."""
    return np.array([names[g] if g < len(names) else "-" for g in hits["geometry_ids"]])


def other_object_near(world, scene, names, eyes, points, own: str) -> np.ndarray:
    """[N] bool: another object's surface crosses a ray from eyes [N, 3] aimed NEAR_M_AT_40 (scaled)
    around points [N, 3] (world) before it reaches them."""
    offsets = points - eyes
    unit = offsets / np.linalg.norm(offsets, axis=1, keepdims=True)
    side = np.cross(unit, [0.0, 0.0, 1.0])
    side /= np.linalg.norm(side, axis=1, keepdims=True)
    up = np.cross(unit, side)
    radius = NEAR_M_AT_40 * np.linalg.norm(offsets, axis=1) / 40.0
    near = np.zeros(len(points), bool)
    for angle in np.linspace(0.0, 2.0 * np.pi, 8, endpoint=False):
        target = points + (np.cos(angle) * side + np.sin(angle) * up) * radius[:, None]
        length = np.linalg.norm(target - eyes, axis=1)
        hits = world.cast(scene, eyes, (target - eyes) / length[:, None])
        hit = hit_objects(hits, names)
        near |= (hits["t_hit"] < 0.97 * length) & (hit != own) & (hit != "") & (hit != "-")
    return near


def clip_errors(world, clip, camera: int) -> collections.Counter:
    """The clip's disagreeing (frame, track) pairs by category (module docstring)."""
    _, _, body, truth, object_id = true_tracks(world, clip, camera)
    first = (int(clip.frame_ids[0]) - FIRST_TIMESTAMP_MICROS) // 100_000
    found: collections.Counter = collections.Counter()
    for i in range(clip.num_frames):
        wrong = np.flatnonzero(clip.visibility[i] != truth[i])
        if not len(wrong):
            continue
        t = frame_time(first + i)
        pose = world.actors[object_id].world_from_body(t)
        points = (body @ pose[:3, :3].T + pose[:3, 3])[wrong]
        _, _, eyes = seen(world, camera, first + i, points)
        scene, names = world.scene(t)
        distance = np.linalg.norm(points - eyes, axis=1)
        hits = world.cast(scene, eyes, (points - eyes) / distance[:, None])
        hit = hit_objects(hits, names)
        near = other_object_near(world, scene, names, eyes, points, object_id)
        for k, called_visible in enumerate(clip.visibility[i, wrong]):
            if not called_visible:
                found["visible, called covered, " + ("another object near" if near[k] else "none near")] += 1
            elif hit[k] == object_id:
                found["own surface hides, called visible"] += 1
            elif hit[k] == "":
                found["covered by the ground, called visible"] += 1
            else:
                found["covered, called visible"] += 1
    return found


def world_errors(folder: str, seed: int, rules: str) -> tuple[collections.Counter, int]:
    """The world's disagreeing pairs by category, and its candidate pairs."""
    world, _ = driving_family.family_world(seed)
    config = with_overrides(with_rules(RunConfig(), rules), driving_family.OVERRIDES)
    found: collections.Counter = collections.Counter()
    pairs = 0
    for camera, clips in drivetrack_segment_clips(folder, driving_family.SEGMENT, (1, 2, 3), config).items():
        for clip in clips:
            found += clip_errors(world, clip, camera)
            pairs += clip.visibility.size
    return found, pairs


def main(argv: list[str] | None = None) -> int:
    parser = StrictParser(prog="python -m tests.support.visibility_errors", description=__doc__)
    parser.add_argument("--seeds", default="0,2,8,11", help="a list of seeds (default %(default)s)")
    parser.add_argument("--rules", choices=RULES, default="refined")
    parser.add_argument("--workdir", default=os.path.join(REPO, ".cache", "family"))
    args = parser.parse_args(argv)
    total: collections.Counter = collections.Counter()
    pairs = 0
    for seed in (int(s) for s in args.seeds.split(",")):
        found, count = world_errors(world_split(args.workdir, seed), seed, args.rules)
        total += found
        pairs += count
        print(f"seed {seed}: {sum(found.values())} of {count} pairs disagree", file=sys.stderr, flush=True)
    print(f"rules={args.rules}, seeds {args.seeds}: {pairs} pairs")
    for category, count in total.most_common():
        print(f"  {category}: {count}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
