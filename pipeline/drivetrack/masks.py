"""DriveTrack's object mask per clip frame, for the mask filter: the object's lidar silhouette
(its projected lidar points, closed with OpenCV morphology), or the user's masks
(``drivetrack.masks_dir``)."""

from __future__ import annotations

import cv2
import numpy as np
from apache_beam.io.filesystems import FileSystems
from scipy.spatial import cKDTree

from pipeline.core.geometry import in_image, transform_points
from pipeline.core.images import decode_image
from pipeline.drivetrack.camera_model import UnitCamera
from pipeline.drivetrack.lidar import LidarEvidence
from pipeline.drivetrack.objects import ObjectRun
from pipeline.drivetrack.records import UnitInput
from pipeline.drivetrack.settings import DriveTrackConfig
from pipeline.drivetrack.units import clip_name
from pipeline.io.files import read_input

MAX_CLOSING_PX = 63


def adaptive_closing_px(points_uv: np.ndarray) -> int:
    """Closing kernel (odd, pixels) that bridges the gaps between lidar scan lines: twice the
    median distance from a projected point [M, 2] to its nearest point on a lower line."""
    if len(points_uv) < 2:
        return 3
    distances, index = cKDTree(points_uv).query(points_uv, k=min(16, len(points_uv)))
    below = points_uv[index, 1] - points_uv[:, None, 1] > 0.5
    gaps = np.where(below, distances, np.inf).min(axis=1)
    gap = np.median(gaps[np.isfinite(gaps)]) if np.isfinite(gaps).any() else distances[:, 1].max()
    size = int(np.ceil(2.0 * max(gap, np.median(distances[:, 1])))) | 1
    return int(np.clip(size, 3, MAX_CLOSING_PX))


def silhouette_mask(points_uv: np.ndarray, width: int, height: int, closing_px: int) -> np.ndarray:
    """Object mask [H, W] bool from its projected points [M, 2]: the points' pixels, closed
    with an elliptical kernel of ``closing_px`` (0 = adaptive), then grown by half a kernel
    so surface points just beyond the outermost scan line still count as on the object."""
    mask = np.zeros((height, width), bool)
    pixels = np.floor(points_uv).astype(np.int64)
    inside = in_image(pixels, width, height)
    if not inside.any():
        return mask
    xs, ys = pixels[inside, 0], pixels[inside, 1]
    size = closing_px or adaptive_closing_px(points_uv[inside])
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size))
    grow = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size // 2 | 1, size // 2 | 1))
    # Only the points' bounding box, padded by a kernel's size, can change: working on it alone
    # gives the same mask as the whole image (a vehicle is a small part of a frame). The closing is
    # non-zero within r = size // 2 of a point, growing adds less than r; the erosion, which takes
    # what lies past the box's edge for 1, reads r around a pixel within r of a point: 2r < size.
    pad = size
    x0, x1 = max(xs.min() - pad, 0), min(xs.max() + pad + 1, width)
    y0, y1 = max(ys.min() - pad, 0), min(ys.max() + pad + 1, height)
    box = np.zeros((y1 - y0, x1 - x0), np.uint8)
    box[ys - y0, xs - x0] = 1
    mask[y0:y1, x0:x1] = cv2.dilate(cv2.morphologyEx(box, cv2.MORPH_CLOSE, kernel), grow) > 0
    return mask


def read_mask_png(path: str, width: int, height: int) -> np.ndarray | None:
    """A user-supplied mask [H, W] bool (non-zero = object), or None when the file is absent."""
    if not FileSystems.exists(path):
        return None
    return decode_image(read_input(path), width, height, f"mask {path}", noun="mask") > 0


def object_masks(
    unit: UnitInput,
    run: ObjectRun,
    evidence: LidarEvidence,
    camera: UnitCamera,
    rules: DriveTrackConfig,
) -> tuple[list[np.ndarray | None], np.ndarray]:
    """Object mask per clip frame ([H, W] bool, or None where there is none) and [T] has-mask
    flags: ``<masks_dir>/<clip name>/<frame id>.png`` when ``drivetrack.masks_dir`` is set (a
    window's: its object's whole run's clip name), else the silhouette of the object's lidar points
    of that frame, where they appear in the stored frame (placed by the run's boxes)."""
    calibration = unit.calibration
    frames = range(run.start, run.stop)
    if rules.masks_dir:
        folder = f"{rules.masks_dir.rstrip('/')}/{clip_name(unit.segment, unit.camera, run.object_id)}"
        masks = [
            read_mask_png(f"{folder}/{unit.frames.timestamps[t]}.png", calibration.width, calibration.height)
            for t in frames
        ]
    else:
        found = evidence.bodies[run.object_id]
        bodies = [found[t].points if t in found else np.zeros((0, 3)) for t in frames]
        world = [transform_points(run.world_from_box[i], body) for i, body in enumerate(bodies)]
        uvs = [seen.pixels[seen.in_view] for seen in camera.project_frames(frames, world)]
        closing = rules.mask_closing_px
        masks = [
            silhouette_mask(uv, calibration.width, calibration.height, closing) if len(uv) else None
            for uv in uvs
        ]
    return masks, np.array([mask is not None for mask in masks])
