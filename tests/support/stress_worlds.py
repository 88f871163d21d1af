"""Driving worlds that stress DriveTrack's visibility, written like the sample world (real Waymo v2
Parquet, ``pipeline.drivetrack.sample.waymo_world.write_split``) but short: 16 frames (clips need 10
contiguous frames: ``OVERRIDES``).

- ``brief``: brief occlusions by thin and small objects. A parked car on the right seen past a
  thin pole (16 cm) that the ego's motion sweeps across it, and a pedestrian running across in front
  of it (each of the car's points hidden for one or two frames); a car passing the other way
  behind a lead car. The TOP lidar has the sample's 900 columns.
- ``fast``: a fast ego (18 m/s) and far objects: a lead car at 40 m, a parked car at 60 m that a
  running pedestrian and an overtaking van (taller than the camera) pass in front of, an oncoming
  car from 90 m. The lidar is sparse: 600 columns (0.6 degrees).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import trimesh

from pipeline.drivetrack.sample import driving_world as driving
from pipeline.drivetrack.sample.waymo_world import write_split

SEGMENT = "stress0000000000000001_0_000_8_000"
FRAMES = 16
OVERRIDES = ["drivetrack.min_contiguous_frames=10"]
POLE_SIZE = (0.16, 0.16, 3.0)
VAN_SIZE = (5.0, 2.0, 2.6)


@dataclasses.dataclass(frozen=True)
class Pole(driving.Actor):
    """A thin upright cylinder (a sign post): 16 cm across, 3 m tall."""

    def shape(self) -> tuple[trimesh.Trimesh, np.ndarray]:
        return trimesh.creation.cylinder(radius=0.08, height=3.0, sections=12), np.array(POLE_SIZE)

    @property
    def size(self) -> np.ndarray:
        return np.array(POLE_SIZE)


@dataclasses.dataclass(frozen=True)
class Van(driving.Actor):
    """A box-shaped van, 2.6 m tall: taller than the cameras (1.9 m)."""

    def shape(self) -> tuple[trimesh.Trimesh, np.ndarray]:
        return trimesh.creation.box(extents=VAN_SIZE), np.array(VAN_SIZE)

    @property
    def size(self) -> np.ndarray:
        return np.array(VAN_SIZE)


def brief_world() -> driving.DrivingWorld:
    """Brief occlusions of a parked car by a thin pole and a running pedestrian (module docstring)."""
    actor = driving.Actor
    return driving.DrivingWorld(
        actors=(
            actor("parked_target_AAAAAAAAAAAAAAAA", 1, (22.0, -5.5), 0.05, 0.0, (0.8, 0.15, 0.1)),
            actor("runner_BBBBBBBBBBBBBBBBBBBBBBBB", 2, (16.0, -10.0), np.pi / 2, 3.0, (0.9, 0.5, 0.4), True),
            Pole("pole_CCCCCCCCCCCCCCCCCCCCCCCCCC", 3, (13.0, -3.2), 0.0, 0.0, (0.3, 0.3, 0.3)),
            actor("passing_car_DDDDDDDDDDDDDDDDDD", 1, (45.0, -2.2), np.pi, 7.0, (0.1, 0.3, 0.85)),
            actor("lead_car_EEEEEEEEEEEEEEEEEEEEEE", 1, (14.0, 0.4), 0.0, 6.0, (0.2, 0.7, 0.3)),
        ),
        ego=driving.Ego(speed=6.0, yaw_rate=0.002),
    )


def fast_world() -> driving.DrivingWorld:
    """A fast ego among far objects (module docstring)."""
    actor = driving.Actor
    return driving.DrivingWorld(
        actors=(
            actor("far_lead_AAAAAAAAAAAAAAAAAAAAAA", 1, (40.0, 0.3), 0.0, 17.0, (0.8, 0.15, 0.1)),
            actor("far_parked_BBBBBBBBBBBBBBBBBBBB", 1, (60.0, -6.0), 0.02, 0.0, (0.2, 0.7, 0.3)),
            actor("oncoming_CCCCCCCCCCCCCCCCCCCCCC", 1, (90.0, 4.0), np.pi, 12.0, (0.9, 0.8, 0.1)),
            actor("runner_DDDDDDDDDDDDDDDDDDDDDDDD", 2, (50.0, -1.5), -np.pi / 2, 3.0, (0.9, 0.5, 0.4), True),
            Van("overtaking_van_EEEEEEEEEEEEEEEE", 1, (8.0, -3.4), 0.0, 24.0, (0.1, 0.3, 0.85)),
        ),
        ego=driving.Ego(speed=18.0, yaw_rate=-0.01),
    )


WORLDS = {"brief": (brief_world, 900), "fast": (fast_world, 600)}


def write_stress_split(folder: str, name: str) -> None:
    """The world ``name`` of ``WORLDS`` written as a split folder (one segment, ``SEGMENT``). Its camera
    images are ray cast at half size (a third of the writing time): only the clips' frames depend on
    them, not their tracks, queries or visibility."""
    make_world, columns = WORLDS[name]
    write_split(
        folder, SEGMENT, FRAMES, make_world(), lidar_columns=columns, keep_points=False, render_scale=2
    )
