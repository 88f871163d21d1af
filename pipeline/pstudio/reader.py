"""Dynamic 3D Gaussians' files: ``data/<seq>/train_meta.json``, ``ims/``, ``seg/`` and
``output/<exp>/<seq>/params.npz``, read through Beam's FileSystems.

Every problem raises InputError naming the file and the cause.
"""

from __future__ import annotations

import json

import numpy as np
from apache_beam.io.filesystems import FileSystems

from pipeline.core.errors import InputError
from pipeline.core.images import check_jpeg_decodes
from pipeline.io.files import open_binary, read_input
from pipeline.io.npz_reader import NpzArchive, NpzError
from pipeline.pstudio.mask_cache import MASKS
from pipeline.pstudio.records import Gaussians, SequenceMeta, Views
from pipeline.pstudio.settings import PstudioConfig

# More Gaussians than any Dynamic 3D Gaussians scene holds (a few hundred thousand): a header claiming
# more is refused before anything is allocated.
MAX_GAUSSIANS = 20_000_000
PARAMS_SHAPES: dict[str, tuple[str | int, ...]] = {  # member -> shape with T, N symbolic
    "means3D": ("T", "N", 3),
    "unnorm_rotations": ("T", "N", 4),
    "log_scales": ("N", 3),
    "logit_opacities": ("N", 1),
    "seg_colors": ("N", 3),
}


def data_root(input_root: str) -> str:
    """The folder holding ``<seq>/train_meta.json``: ``<input>/data`` if present, else ``<input>``.
    The listing stops at the first match (the whole of data/, every image and mask, otherwise)."""
    candidate = FileSystems.join(input_root, "data")
    pattern = FileSystems.join(candidate, "*", "train_meta.json")
    return candidate if FileSystems.match([pattern], [1])[0].metadata_list else input_root


def sequence_folder(input_root: str, sequence: str) -> str:
    """``<data root>/<sequence>`` (``data_root``): ``<input>/data/<sequence>`` when it holds a
    train_meta.json (the data root is then ``<input>/data``), found without listing anything;
    else through ``data_root``'s listing."""
    candidate = FileSystems.join(input_root, "data", sequence)
    if FileSystems.exists(FileSystems.join(candidate, "train_meta.json")):
        return candidate
    return FileSystems.join(data_root(input_root), sequence)


def list_sequences(input_root: str) -> list[str]:
    """Sequence names (folders with a train_meta.json), sorted."""
    root = data_root(input_root)
    matches = FileSystems.match([FileSystems.join(root, "*", "train_meta.json")])[0].metadata_list
    names = sorted(m.path.rstrip("/").split("/")[-2] for m in matches)
    if not names:
        raise InputError(
            f"no sequences: no {root}/<sequence>/train_meta.json; --input must hold Dynamic 3D "
            "Gaussians' data/<sequence>/ folders (and output/<exp>/<sequence>/params.npz)"
        )
    return names


def params_path(input_root: str, sequence: str, config: PstudioConfig) -> str:
    """``<params_dir>/<seq>/params.npz``; params_dir defaults to the one experiment in <input>/output."""
    if config.params_dir:
        return FileSystems.join(config.params_dir, sequence, "params.npz")
    pattern = FileSystems.join(input_root, "output", "*", sequence, "params.npz")
    found = sorted(m.path for m in FileSystems.match([pattern])[0].metadata_list)
    if len(found) != 1:
        what = "no" if not found else f"{len(found)}"
        raise InputError(
            f"{sequence}: {what} params.npz matching {pattern}; set pstudio.params_dir to the folder "
            "holding <sequence>/params.npz"
        )
    return found[0]


def read_views(input_root: str, sequence: str) -> SequenceMeta:
    """The sequence's cameras from train_meta.json (checked static) and its image names."""
    path = FileSystems.join(sequence_folder(input_root, sequence), "train_meta.json")
    try:
        meta = json.loads(read_input(path))
        width, height = int(meta["w"]), int(meta["h"])
        k = np.asarray(meta["k"], dtype=np.float64)
        w2c = np.asarray(meta["w2c"], dtype=np.float64)
        camera_ids = np.asarray(meta["cam_id"], dtype=np.int64)
        names = meta["fn"]
        frames = len(names)
    except InputError:
        raise
    except (KeyError, ValueError, TypeError) as error:
        raise InputError(
            f"{path}: not a Dynamic 3D Gaussians train_meta.json ({type(error).__name__}: {error})"
        ) from error
    cameras = camera_ids.shape[1] if camera_ids.ndim == 2 else -1
    if (
        k.shape != (frames, cameras, 3, 3)
        or w2c.shape != (frames, cameras, 4, 4)
        or camera_ids.shape != (frames, cameras)
        or any(not isinstance(row, list) or len(row) != cameras for row in names)
    ):
        raise InputError(
            f"{path}: k, w2c, fn and cam_id disagree in shape ({k.shape}, {w2c.shape}, {camera_ids.shape})"
        )
    for row in names:
        for name in row:
            if not isinstance(name, str) or name.startswith("/") or "\\" in name or ".." in name.split("/"):
                raise InputError(f"{path}: fn entry {name!r} is not a file inside the sequence's ims/ folder")
    for key, matrices in (("k", k), ("w2c", w2c)):
        finite = np.isfinite(matrices).all(axis=(0, 2, 3))
        if not finite.all():
            raise InputError(f"{path}: {key} of camera {camera_ids[0][~finite][0]} holds non-finite values")
    if (camera_ids != camera_ids[0]).any():
        raise InputError(f"{path}: the camera list changes between frames")
    if np.abs(k - k[0]).max() > 1e-6 or np.abs(w2c - w2c[0]).max() > 1e-6:
        raise InputError(f"{path}: cameras move between frames; Panoptic Studio clips assume static cameras")
    rotations = w2c[0, :, :3, :3]
    rigid = (
        (np.abs(rotations @ rotations.transpose(0, 2, 1) - np.eye(3)).max(axis=(1, 2)) < 1e-3)
        & (np.linalg.det(rotations) > 0)
        & (np.abs(w2c[0, :, 3] - [0, 0, 0, 1]).max(axis=1) < 1e-6)
    )
    if not rigid.all():
        raise InputError(
            f"{path}: w2c of camera {camera_ids[0][~rigid][0]} is not a rigid transform "
            "(rotation not orthonormal, or last row not 0 0 0 1)"
        )
    focal = (k[0, :, 0, 0] > 0) & (k[0, :, 1, 1] > 0)
    if not focal.all():
        raise InputError(f"{path}: k of camera {camera_ids[0][~focal][0]} has a non-positive focal length")
    intrinsics = np.stack([k[0, :, 0, 0], k[0, :, 1, 1], k[0, :, 0, 2], k[0, :, 1, 2]], axis=1)
    views = Views(camera_ids[0], intrinsics, w2c[0], width, height)
    return SequenceMeta(views, tuple(tuple(row) for row in names))


def read_gaussians(path: str, frames: int) -> Gaussians:
    """The Gaussians of params.npz, checked against T = ``frames`` and N = the Gaussians of
    ``means3D`` from the members' headers before anything is read (``pipeline.io.npz_reader``:
    no pickled objects, no allocation a header merely claims)."""
    if not FileSystems.exists(path):
        raise InputError(f"missing file {path}")
    try:
        with open_binary(path) as handle:
            if handle.read(6) == b"\x93NUMPY":
                raise InputError(f"{path}: a single .npy array, not an npz archive")
            handle.seek(0)
            archive = NpzArchive(handle, path)
            missing = [name for name in PARAMS_SHAPES if name not in archive.keys]
            if missing:
                raise InputError(f"{path}: no {missing[0]!r} member (has {archive.keys})")
            shapes = {name: archive.header(name).shape for name in PARAMS_SHAPES}
            count = shapes["means3D"][1] if len(shapes["means3D"]) == 3 else -1
            if count > MAX_GAUSSIANS:
                raise InputError(f"{path}: means3D claims {count} Gaussians, more than {MAX_GAUSSIANS} read")
            sizes = {"T": frames, "N": count}
            for name, shape in PARAMS_SHAPES.items():
                expected = tuple(sizes[d] if isinstance(d, str) else d for d in shape)
                if shapes[name] != expected:
                    raise InputError(
                        f"{path}: {name} has shape {shapes[name]}, expected {expected} "
                        f"(T = {frames} frames in train_meta.json, N = {count} Gaussians in means3D)"
                    )
                if archive.header(name).dtype.kind != "f":
                    raise InputError(
                        f"{path}: {name} has dtype {archive.header(name).dtype}, expected floats"
                    )
            # Read-only: the Gaussians are never written to.
            arrays = {
                name: archive.read(name, archive.header(name).nbytes, writable=False)
                for name in PARAMS_SHAPES
            }
    except NpzError as error:
        raise InputError(str(error)) from error
    except OSError as error:
        raise InputError(f"{path}: unreadable ({error})") from error
    for name in PARAMS_SHAPES:
        bad = non_finite_count(arrays[name])
        if bad:
            raise InputError(f"{path}: {name} holds {bad} non-finite value(s) (NaN or inf)")
    if not (arrays["seg_colors"][:, 0] > 0.5).any():
        raise InputError(
            f"{path}: no foreground Gaussians ({count} in all; foreground = seg_colors[:, 0] > 0.5)"
        )
    return Gaussians(
        means=arrays["means3D"],
        quaternions=arrays["unnorm_rotations"],
        scales=np.exp(arrays["log_scales"].astype(np.float64)),
        opacities=1.0 / (1.0 + np.exp(-arrays["logit_opacities"][:, 0].astype(np.float64))),
        foreground=arrays["seg_colors"][:, 0] > 0.5,
    )


def non_finite_count(values: np.ndarray) -> int:
    """How many of the floats ``values`` [...] are NaN or infinite. One pass and no temporary array
    when there are none: a NaN or an infinity makes the sum non-finite, so a finite sum proves
    every value finite (a sum that overflows is counted exactly, as one that does not prove it)."""
    with np.errstate(over="ignore", invalid="ignore"):
        if np.isfinite(np.add.reduce(values, axis=None)):
            return 0
    return int(np.count_nonzero(~np.isfinite(values)))


class SequenceFiles:
    """Images and masks of one sequence, by (camera column, frame) as train_meta's ``fn`` names them.
    Each mask file is read once per opened sequence (the units of a group share it), and decoded
    once per process (``pipeline.pstudio.mask_cache``); masks are handed on bit-packed."""

    def __init__(self, input_root: str, sequence: str, meta: SequenceMeta):
        self.folder = sequence_folder(input_root, sequence)
        self.names = meta.image_names
        self.views = meta.views
        self._masks: dict[tuple[int, int], np.ndarray] = {}  # (view, t) -> the cache's packed mask

    def image(self, view: int, t: int) -> bytes:
        """The frame's JPEG as it is (the clip passes it through), checked complete and decodable."""
        path = FileSystems.join(self.folder, "ims", self.names[t][view])
        data = read_input(path)
        check_jpeg_decodes(data, self.views.width, self.views.height, path)
        return data

    def packed_mask(self, view: int, t: int) -> np.ndarray:
        """Foreground mask (seg PNG, non-zero = foreground), bit-packed (``MaskCache.packed``)."""
        packed = self._masks.get((view, t))
        if packed is None:
            path = FileSystems.join(self.folder, "seg", self.names[t][view].rsplit(".", 1)[0] + ".png")
            data = read_input(path)
            packed = self._masks[view, t] = MASKS.packed(data, self.views.width, self.views.height, path)
        return packed
