"""The records a Panoptic Studio unit's annotation reads: the sequence's cameras, its Gaussians, one
camera's unit input, and what a group of cameras of one sequence shares."""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable

import numpy as np

from pipeline.pstudio.splats import GaussianConstants, gaussian_constants


@dataclasses.dataclass
class Views:
    """The sequence's static cameras (C of them): ids [C], fx_fy_cx_cy [C, 4], w2c [C, 4, 4]."""

    camera_ids: np.ndarray
    fx_fy_cx_cy: np.ndarray
    w2c: np.ndarray
    width: int
    height: int

    def index(self, camera_id: int) -> int:
        return int(np.nonzero(self.camera_ids == camera_id)[0][0])


@dataclasses.dataclass
class Gaussians:
    """Dynamic 3D Gaussians: means [T, N, 3], quaternions [T, N, 4] (w, x, y, z, unnormalised),
    scales [N, 3], opacities [N], foreground [N] bool; ``constants`` (what no frame changes) is
    computed on first use, once for every frame and camera."""

    means: np.ndarray
    quaternions: np.ndarray
    scales: np.ndarray
    opacities: np.ndarray
    foreground: np.ndarray

    @property
    def num_frames(self) -> int:
        return int(self.means.shape[0])

    @functools.cached_property
    def constants(self) -> GaussianConstants:
        return gaussian_constants(self.scales, self.opacities)


def clip_name(sequence: str, camera: int) -> str:
    """The release's Panoptic Studio clip name."""
    return f"{sequence}_{camera}"


@dataclasses.dataclass
class UnitInput:
    """Everything one unit reads. ``mask(view, t)`` returns camera ``view``'s foreground mask
    [H, W] bool at frame t; ``frames_jpeg`` are the unit camera's T frames."""

    sequence: str
    camera_id: int
    views: Views
    gaussians: Gaussians
    frames_jpeg: list[bytes]
    mask: Callable[[int, int], np.ndarray]

    @property
    def clip_name(self) -> str:
        return clip_name(self.sequence, self.camera_id)
