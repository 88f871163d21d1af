"""The records a Panoptic Studio unit's annotation reads: the sequence's cameras and image names, its
Gaussians, one camera's unit input, and what a group of cameras of one sequence shares."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

from pipeline.core.windows import Window
from pipeline.pstudio.mask_cache import unpack_mask


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


@dataclasses.dataclass(frozen=True)
class SequenceMeta:
    """What a sequence's train_meta.json says (T frames, C cameras): its static cameras, and
    image_names [T][C], each frame's image per camera column as ``fn`` names it (relative to the
    sequence's ``ims/``; its mask the same name, ``.png``, in ``seg/``)."""

    views: Views
    image_names: tuple[tuple[str, ...], ...]

    @property
    def num_frames(self) -> int:
        return len(self.image_names)


@dataclasses.dataclass
class Gaussians:
    """Dynamic 3D Gaussians: means [T, N, 3], quaternions [T, N, 4] (w, x, y, z, unnormalised),
    scales [N, 3], opacities [N], foreground [N] bool."""

    means: np.ndarray
    quaternions: np.ndarray
    scales: np.ndarray
    opacities: np.ndarray
    foreground: np.ndarray

    @property
    def num_frames(self) -> int:
        return int(self.means.shape[0])


@dataclasses.dataclass(frozen=True)
class GaussianConstants:
    """Per-Gaussian quantities no frame changes (N Gaussians), float64: scales [N, 3], opacity [N],
    reach [N] = 2 ln(255 opacity), the squared Mahalanobis radius where alpha falls to 1/255,
    max_variance [N], the largest scale squared, and cutoff [N] = ln(1 / (255 opacity)), the
    exponent below which alpha falls under 1/255 (render.py skips a splat there; computed as the
    rasterizer writes it, not as -reach / 2, which may round differently)."""

    scales: np.ndarray
    opacity: np.ndarray
    reach: np.ndarray
    max_variance: np.ndarray
    cutoff: np.ndarray


@dataclasses.dataclass
class UnitInput:
    """Everything one unit reads. ``constants``: the Gaussians' (``splats.gaussian_constants``, once
    per sequence); ``packed_mask(view, t)`` returns camera ``view``'s foreground mask at frame t
    bit-packed, ``np.packbits`` of the [H, W] bools row-major ([ceil(H W / 8)] uint8; ``mask``
    unpacks it); ``frames_jpeg`` are the unit camera's T frames. ``window``: the clip of a cut
    sequence these T frames are (``in_window``); None: the camera's whole sequence."""

    sequence: str
    camera_id: int
    views: Views
    gaussians: Gaussians
    constants: GaussianConstants
    frames_jpeg: list[bytes]
    packed_mask: Callable[[int, int], np.ndarray]
    window: Window | None = None

    def mask(self, view: int, t: int) -> np.ndarray:
        """Camera ``view``'s foreground mask [H, W] bool at frame t."""
        return unpack_mask(self.packed_mask(view, t), self.views.width, self.views.height)

    def in_window(self, window: Window) -> UnitInput:
        """The unit of ``window``'s frames of this whole sequence: its Gaussians' means and
        quaternions, frames and masks from the window's first frame on (views, no copies)."""
        g, start, stop = self.gaussians, window.start, window.stop
        gaussians = Gaussians(
            g.means[start:stop], g.quaternions[start:stop], g.scales, g.opacities, g.foreground
        )

        def packed_mask(view: int, t: int) -> np.ndarray:
            return self.packed_mask(view, start + t)

        frames = self.frames_jpeg[start:stop]
        return dataclasses.replace(
            self, gaussians=gaussians, frames_jpeg=frames, packed_mask=packed_mask, window=window
        )
