"""A family of driving worlds drawn from a seed, for measuring DriveTrack's visibility on worlds it
was not tuned on: cars, vans, trucks, walkers and cyclists, parked and moving, crossing and
oncoming, 5-70 m ahead; an ego on a straight road or a curve at 0-20 m/s; a 900- or 600-column
TOP lidar. Written like the stress worlds (real Waymo v2 Parquet, 20 frames, half-size camera
images: only the clips' frames read them).

Every actor's label box holds its mesh with 10-15 cm to spare (as real boxes do: a mesh filling its
box would leave no point inside the box shrunk by ``drivetrack.box_shrink_m``), and no two actors'
boxes, nor an actor's and the ego's, come within 0.4 m of each other over the segment.
"""

from __future__ import annotations

import dataclasses
from typing import cast

import numpy as np
import trimesh

from pipeline.drivetrack.sample import driving_world as driving
from pipeline.drivetrack.sample.waymo_world import write_split

SEGMENT = "family000000000000001_0_000_8_000"
FRAMES = 20
OVERRIDES = ["drivetrack.min_contiguous_frames=10"]
CLEARANCE_M = 0.4
CYCLIST_SIZE = (1.8, 0.6, 1.7)
KINDS = ("car", "car", "van", "truck", "walker", "cyclist")
BOX_SIZES = {"van": (5.0, 2.0, 2.5), "truck": (8.5, 2.5, 3.4)}


@dataclasses.dataclass(frozen=True)
class Boxy(driving.Actor):
    """A van or a truck: a cargo box and a lower cab in front of it, inside its box ``extents``."""

    extents: tuple[float, float, float] = BOX_SIZES["van"]

    def shape(self) -> tuple[trimesh.Trimesh, np.ndarray]:
        length, width, height = self.extents
        cab = min(2.0, 0.3 * length)
        cargo = trimesh.creation.box(extents=(length - cab - 0.3, width - 0.25, height - 0.3))
        cargo.apply_translation((-cab / 2, 0.0, 0.0))
        front = trimesh.creation.box(extents=(cab, width - 0.3, 0.75 * height - 0.3))
        front.apply_translation(((length - 0.3) / 2 - cab / 2, 0.0, -0.125 * height))
        return cast(trimesh.Trimesh, trimesh.util.concatenate([cargo, front])), np.array(self.extents)

    @property
    def size(self) -> np.ndarray:
        return np.array(self.extents)


@dataclasses.dataclass(frozen=True)
class Cyclist(driving.Actor):
    """A bicycle (a thin slab) and its rider (an upright cylinder)."""

    def shape(self) -> tuple[trimesh.Trimesh, np.ndarray]:
        bike = trimesh.creation.box(extents=(1.7, 0.12, 0.9))
        bike.apply_translation((0.0, 0.0, -0.4))
        rider = trimesh.creation.cylinder(radius=0.22, height=0.9, sections=16)
        rider.apply_translation((0.0, 0.0, 0.4))
        return cast(trimesh.Trimesh, trimesh.util.concatenate([bike, rider])), np.array(CYCLIST_SIZE)

    @property
    def size(self) -> np.ndarray:
        return np.array(CYCLIST_SIZE)


class Ego(driving.Ego):
    """The sample's ego, also on a straight road (yaw rate 0) or standing still (speed 0)."""

    def world_from_vehicle(self, t):
        if self.yaw_rate == 0.0:
            t = np.asarray(t, np.float64)
            return driving.pose_matrix(0.0 * t, np.stack([self.speed * t, 0.0 * t, 0.0 * t], -1))
        return super().world_from_vehicle(t)


def footprint(xy: np.ndarray, heading: float, size: np.ndarray) -> np.ndarray:
    """Corners [4, 2] of a box's ground rectangle grown by CLEARANCE_M."""
    c, s = np.cos(heading), np.sin(heading)
    hx, hy = size[0] / 2 + CLEARANCE_M, size[1] / 2 + CLEARANCE_M
    local = np.array([[hx, hy], [-hx, hy], [-hx, -hy], [hx, -hy]])
    return local @ np.array([[c, s], [-s, c]]) + xy


def overlap(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether two convex quadrilaterals [4, 2] overlap (no separating axis among their edges')."""
    for quad in (a, b):
        for i in range(4):
            edge = quad[(i + 1) % 4] - quad[i]
            axis = np.array([-edge[1], edge[0]])
            if (a @ axis).max() < (b @ axis).min() or (b @ axis).max() < (a @ axis).min():
                return False
    return True


def ground_boxes(pose_of, size: np.ndarray, times: np.ndarray) -> list[np.ndarray]:
    """A box's grown ground rectangle [4, 2] at each time, its pose from ``pose_of(t)`` [4, 4]."""
    boxes = []
    for t in times:
        pose = pose_of(t)
        boxes.append(footprint(pose[:2, 3], float(np.arctan2(pose[1, 0], pose[0, 0])), size))
    return boxes


def draw_actor(rng: np.random.Generator, index: int, ego_speed: float) -> driving.Actor:
    """One actor: its kind, lane or crossing path, heading, speed and colour."""
    kind = str(rng.choice(KINDS))
    x = float(rng.uniform(5.0, 60.0)) + 0.5 * ego_speed
    lane = float(rng.choice([-7.0, -3.5, 0.0, 3.5, 7.0]) + rng.normal(0.0, 0.3))
    moving = rng.random() < 0.6
    if kind == "walker":
        heading, speed = float(rng.choice([np.pi / 2, -np.pi / 2, 0.0])), float(rng.uniform(0.8, 3.0))
    elif kind == "cyclist":
        heading, speed = float(rng.choice([0.0, np.pi])), float(rng.uniform(3.0, 7.0))
    else:
        heading = float(rng.choice([0.0, np.pi, np.pi / 2, -np.pi / 2], p=[0.45, 0.3, 0.125, 0.125]))
        heading += float(rng.normal(0.0, 0.05))
        speed = float(rng.uniform(2.0, 18.0))
    speed = speed if moving else 0.0
    if speed and abs(np.sin(heading)) > 0.7:  # crossing: from one side of the road
        lane = float(-np.sign(np.sin(heading)) * rng.uniform(8.0, 20.0))
    name = f"{kind}{index}_".ljust(24, "ABCDEFGHIJKLMNOPQRSTUVWXYZ"[index])
    red, green, blue = (float(c) for c in rng.uniform(0.1, 0.9, 3))
    color = (red, green, blue)
    place = (name, {"walker": 2, "cyclist": 4}.get(kind, 1), (x, lane), heading, speed, color)
    if kind in BOX_SIZES:
        return Boxy(*place, extents=BOX_SIZES[kind])
    if kind == "cyclist":
        return Cyclist(*place)
    return driving.Actor(*place, pedestrian=kind == "walker")


def family_world(seed: int) -> tuple[driving.DrivingWorld, int]:
    """(world, lidar columns) of seed ``seed``: 8-12 actors drawn one after another, each kept when
    its box stays clear of the others' and the ego's over the segment."""
    rng = np.random.default_rng(seed)
    speed = float(rng.uniform(0.0, 20.0))
    yaw_rate = float(rng.choice([0.0, rng.uniform(-0.06, 0.06)]))
    ego = Ego(speed=speed, yaw_rate=yaw_rate) if speed > 0.1 else Ego(speed=0.0, yaw_rate=0.0)
    times = np.arange(FRAMES + 1) * driving.FRAME_PERIOD_S
    ego_size = np.array([5.0, 2.2])
    ego_boxes = ground_boxes(
        lambda t: ego.world_from_vehicle(t) @ driving.pose_matrix(0.0, (1.5, 0.0, 0.0)), ego_size, times
    )
    wanted = int(rng.integers(8, 13))
    actors: list[driving.Actor] = []
    placed: list[list[np.ndarray]] = [ego_boxes]
    for _ in range(80):
        if len(actors) == wanted:
            break
        actor = draw_actor(rng, len(actors), speed)
        boxes = ground_boxes(actor.world_from_body, actor.size, times)
        if not any(overlap(a, b) for other in placed for a, b in zip(boxes, other, strict=True)):
            placed.append(boxes)
            actors.append(actor)
    columns = int(rng.choice([900, 900, 600]))
    return driving.DrivingWorld(actors=tuple(actors), ego=ego), columns


def write_family_split(folder: str, seed: int) -> None:
    """The world of ``seed`` written as a split folder (one segment, ``SEGMENT``), its camera images
    ray cast at half size."""
    world, columns = family_world(seed)
    write_split(folder, SEGMENT, FRAMES, world, lidar_columns=columns, keep_points=False, render_scale=2)
