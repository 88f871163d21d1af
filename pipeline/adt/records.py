"""The records an ADT unit's annotation reads: its chunk, and each stored frame's geometry."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Generic, TypeVar

import numpy as np

# A frame's instance ids: the image as read, or its runs (``IdRuns``) in the frames pass 2 keeps.
Ids = TypeVar("Ids", np.ndarray, "IdRuns")


@dataclasses.dataclass
class Frame(Generic[Ids]):
    """One stored frame's geometry (S = image size).

    depth_mm: [S, S] float32 z-depth in millimetres (0 = no surface), as re-rendered.
    ids: [S, S] uint64 instance ids (0 = none), as an image or as ``IdRuns``.
    cam_from_world: [4, 4] world-to-stored-camera.
    world_from_object: object id -> [4, 4] pose (``transform_scene_object``).
    timestamp: the frame's RGB timestamp (ns), for messages.
    """

    depth_mm: np.ndarray
    ids: Ids
    cam_from_world: np.ndarray
    world_from_object: Mapping[int, np.ndarray]
    timestamp: int

    def with_runs(self, runs: IdRuns) -> Frame[IdRuns]:
        """This frame with its ids as runs (``IdRuns.of(self.ids)``)."""
        return Frame(self.depth_mm, runs, self.cam_from_world, self.world_from_object, self.timestamp)

    def depth_m(self) -> np.ndarray:
        """[S, S] float64 z-depth in metres (0 = no surface)."""
        return self.depth_mm.astype(np.float64) / 1000.0


@dataclasses.dataclass(frozen=True)
class DepthMetres:
    """A depth image in millimetres [S, S] read in metres at given pixels: ``depth[rows, cols]``
    gives float64 [N], the values of ``Frame.depth_m()`` there, converting only those pixels.

    depth_mm: [S, S] float32 millimetres (0 = no surface).
    """

    depth_mm: np.ndarray

    @property
    def shape(self) -> tuple[int, ...]:
        return self.depth_mm.shape

    def __getitem__(self, index: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
        return self.depth_mm[index].astype(np.float64) / 1000.0


@dataclasses.dataclass(frozen=True)
class IdRuns:
    """An id image [S, S] as runs of one id along its rows, row-major (a few thousand runs on
    ADT's segmentation). ``runs[rows, cols]`` reads ids [N] like the image.

    starts: [R] int64 flat index of each run's first pixel (starts[0] = 0); values: [R] its id;
    shape: the image's (S, S).
    """

    starts: np.ndarray
    values: np.ndarray
    shape: tuple[int, int]

    @classmethod
    def of(cls, ids: np.ndarray) -> IdRuns:
        flat = ids.reshape(-1)
        starts = np.concatenate([[0], np.flatnonzero(flat[1:] != flat[:-1]) + 1])
        return cls(starts, flat[starts], ids.shape)

    def unique(self) -> np.ndarray:
        """The sorted distinct ids [K] (``np.unique`` of the image)."""
        return np.unique(self.values)

    def expand(self, per_run: np.ndarray) -> np.ndarray:
        """[S, S] image of one value per run ``per_run`` [R] (``expand(values)`` is the id image)."""
        lengths = np.diff(np.append(self.starts, self.shape[0] * self.shape[1]))
        return np.repeat(per_run, lengths).reshape(self.shape)

    def __getitem__(self, index: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
        rows, cols = index
        flat = np.asarray(rows, np.int64) * self.shape[1] + np.asarray(cols, np.int64)
        return self.values[np.searchsorted(self.starts, flat, side="right") - 1]


@dataclasses.dataclass(frozen=True)
class Instances:
    """Which ids are the wearer (human) and which objects move (dynamic)."""

    human: frozenset[int]
    dynamic: frozenset[int]


@dataclasses.dataclass(frozen=True)
class Chunk:
    """What one unit annotates: the clip's name, its unit, its frames' timestamps [T]."""

    name: str
    unit: str
    timestamps: np.ndarray
