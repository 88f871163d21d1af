"""``--export-depth``: the per-frame depth each clip's visibility test read, beside the clip.

Written to ``<out>/depth/<source>/<clip>.npz`` (a deflated, deterministic npz) as

- dense (adt: the rendered depth; pstudio: the splat depth), ``kind = "dense"``:
  ``depth_mm`` uint16 [T, H, W], millimetres of z-depth, 0 where there is no surface;
- sparse (drivetrack: the projected lidar points after the parallax cleanup), ``kind = "sparse"``:
  ``uv`` float32 [M, 2] pixels, ``z`` float32 [M] metres, and ``frame_offsets`` int64 [T + 1]
  (frame t's points are rows ``frame_offsets[t]:frame_offsets[t + 1]``);

with ``frame_ids`` int64 [T] in both. Frames follow the clip's frames; pixels its stored images.
"""

from __future__ import annotations

import numpy as np

from pipeline.core.clip import DenseDepth, SparseDepth
from pipeline.export.npz_writer import encode_npz


def dense_depth_mm(depth_m: np.ndarray) -> np.ndarray:
    """Depth in metres [..., H, W] (NaN or <= 0 = none) -> uint16 millimetres (0 = none)."""
    finite = np.isfinite(depth_m) & (depth_m > 0)
    millimetres = np.where(finite, np.round(np.where(finite, depth_m, 0) * 1000.0), 0)
    return np.clip(millimetres, 0, np.iinfo(np.uint16).max).astype(np.uint16)


def dense_export(depth_mm: list[np.ndarray], frame_ids: np.ndarray) -> DenseDepth:
    """Depth images [T] x uint16 [H, W] of the clip's frames ``frame_ids`` [T]."""
    return DenseDepth(np.stack(depth_mm), np.asarray(frame_ids, np.int64))


def sparse_export(uv: list[np.ndarray], z: list[np.ndarray], frame_ids: np.ndarray) -> SparseDepth:
    """Per frame of ``frame_ids`` [T], its points' pixels [M_t, 2] and depths [M_t]."""
    offsets = np.concatenate([[0], np.cumsum([len(v) for v in z])]).astype(np.int64)
    return SparseDepth(
        np.concatenate(uv).astype(np.float32).reshape(-1, 2),
        np.concatenate(z).astype(np.float32),
        offsets,
        np.asarray(frame_ids, np.int64),
    )


def encode_depth(depth: DenseDepth | SparseDepth) -> bytes:
    """The depth file's bytes: ``kind`` and the record's arrays, in the order above."""
    if isinstance(depth, DenseDepth):
        members = {"kind": np.array("dense"), "depth_mm": depth.depth_mm, "frame_ids": depth.frame_ids}
    else:
        members = {
            "kind": np.array("sparse"),
            "uv": depth.uv,
            "z": depth.z,
            "frame_offsets": depth.frame_offsets,
            "frame_ids": depth.frame_ids,
        }
    return encode_npz(members, compress=True)
