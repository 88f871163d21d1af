"""The family of driving worlds (tests/support/driving_family.py) that DriveTrack's visibility is
measured on: each world is its seed's alone, its actors never collide, and the family spans what
real segments hold (every kind of actor, parked and moving, straight roads and curves, ego speeds
from standing to 20 m/s, both lidar densities). Drawing the worlds writes nothing: this is cheap."""

from __future__ import annotations

import numpy as np

from pipeline.drivetrack.sample.driving_world import FRAME_PERIOD_S
from tests.support import driving_family

SEEDS = range(20)
TIMES = np.arange(driving_family.FRAMES + 1) * FRAME_PERIOD_S


def kind(actor) -> str:
    return actor.object_id.split("_")[0].rstrip("0123456789")


def test_a_world_is_its_seeds_alone():
    first, _ = driving_family.family_world(3)
    again, _ = driving_family.family_world(3)
    other, _ = driving_family.family_world(4)
    assert list(first.actors.values()) == list(again.actors.values())
    assert list(first.actors.values()) != list(other.actors.values())


def test_no_two_actors_nor_an_actor_and_the_ego_come_within_the_clearance():
    for seed in SEEDS:
        world, _ = driving_family.family_world(seed)
        boxes = [driving_family.ground_boxes(a.world_from_body, a.size, TIMES) for a in world.actors.values()]
        for i, mine in enumerate(boxes):
            for theirs in boxes[i + 1 :]:
                assert not any(driving_family.overlap(a, b) for a, b in zip(mine, theirs, strict=True)), seed


def test_the_family_spans_what_real_segments_hold():
    worlds = [driving_family.family_world(seed) for seed in SEEDS]
    actors = [actor for world, _ in worlds for actor in world.actors.values()]
    assert {kind(actor) for actor in actors} == {"car", "van", "truck", "walker", "cyclist"}
    assert any(actor.speed == 0 for actor in actors) and any(actor.speed > 10 for actor in actors)
    crossing = [a for a in actors if a.speed and abs(np.sin(a.heading)) > 0.7]
    oncoming = [a for a in actors if a.speed and np.cos(a.heading) < -0.7]
    assert crossing and oncoming
    speeds = [world.ego.speed for world, _ in worlds]
    assert min(speeds) < 3 and max(speeds) > 17
    assert {world.ego.yaw_rate == 0 for world, _ in worlds} == {True, False}  # straight roads and curves
    assert {columns for _, columns in worlds} == {600, 900}
    ahead = [a.start_xy[0] for a in actors]
    assert min(ahead) < 10 and max(ahead) > 55
    assert all(8 <= len(world.actors) <= 12 for world, _ in worlds)
