"""Aria Digital Twin access through projectaria-tools: sequences, frames, images, poses, instances.

Everything projectaria-tools returns is checked here and turned into NumPy; a problem raises
``InputError`` naming the sequence and the cause. Poses are [4, 4] float64 matrices
``world_from_*`` (ADT's "scene" frame is our world frame).

Files of a sequence folder (docs/formats.md, section 4): ``video.vrs`` (RGB stream 214-1),
``depth_images[_with_skeleton].vrs``, ``segmentations[_with_skeleton].vrs``,
``aria_trajectory.csv``, ``scene_objects.csv``, ``3d_bounding_box.csv``, ``instances.json``,
``metadata.json``. They are checked before projectaria-tools opens them (``check_file``): it
silently drops the records past the end of a truncated VRS file, reads an aria_trajectory.csv
holding text or NaN as an empty trajectory and passes NaN poses on.
"""

from __future__ import annotations

import contextlib
import csv
import functools
import json
import os
import re
import struct
from collections.abc import Iterator, Mapping

import numpy as np

from pipeline.core.errors import InputError

RGB_STREAM = "214-1"
RGB_LABEL = "camera-rgb"
# Files whose presence makes a folder an ADT sequence (any one of them).
SEQUENCE_MARKERS = ("metadata.json", "video.vrs", "scene_objects.csv", "aria_trajectory.csv")
# Ground-truth CSVs: the columns naming a row in messages, the translation and the quaternion
# (w, x, y, z) of its pose. Every column but graph_uid must hold finite numbers.
CSV_COLUMNS = {
    "aria_trajectory.csv": (
        ("tracking_timestamp_us",),
        ("tx_world_device", "ty_world_device", "tz_world_device"),
        ("qw_world_device", "qx_world_device", "qy_world_device", "qz_world_device"),
    ),
    "scene_objects.csv": (
        ("object_uid", "timestamp[ns]"),
        ("t_wo_x[m]", "t_wo_y[m]", "t_wo_z[m]"),
        ("q_wo_w", "q_wo_x", "q_wo_y", "q_wo_z"),
    ),
    "3d_bounding_box.csv": (("object_uid", "timestamp[ns]"), (), ()),
}
TEXT_COLUMNS = ("graph_uid",)


def required_files(with_skeleton: bool) -> tuple[str, ...]:
    """Files a sequence must hold for the annotation (depth and ids with or without the body)."""
    suffix = "_with_skeleton" if with_skeleton else ""
    return (
        "video.vrs",
        f"depth_images{suffix}.vrs",
        f"segmentations{suffix}.vrs",
        "aria_trajectory.csv",
        "scene_objects.csv",
        "3d_bounding_box.csv",
        "instances.json",
        "metadata.json",
    )


def is_sequence(folder: str) -> bool:
    return os.path.isdir(folder) and any(os.path.exists(os.path.join(folder, m)) for m in SEQUENCE_MARKERS)


def list_sequences(root: str) -> list[str]:
    """Sequence folders: ``root`` itself when it is one, else its sub-folders that are, sorted."""
    if "://" in root:
        raise InputError(f"{root}: ADT is read with projectaria-tools from a local (or mounted) folder")
    if not os.path.isdir(root):
        raise InputError(f"{root}: not a folder")
    if is_sequence(root):
        return [os.path.normpath(root)]
    found = sorted(
        os.path.join(root, name) for name in os.listdir(root) if is_sequence(os.path.join(root, name))
    )
    if not found:
        raise InputError(
            f"{root}: no ADT sequence folder in it (a folder holding {' or '.join(SEQUENCE_MARKERS)})"
        )
    return found


def read_serial(folder: str) -> str:
    """The device serial from ``metadata.json`` ('' when absent or unreadable)."""
    try:
        with open(os.path.join(folder, "metadata.json")) as handle:
            return str(json.load(handle).get("serial", ""))
    except (OSError, ValueError, AttributeError):
        return ""


def v1_name(folder: str) -> str:
    """The release's (v1) sequence name: the folder name without its trailing ``_<serial suffix>``.

    ADT v2 folders are ``<v1 name>_<suffix>`` where the suffix is the tail of the recording
    device's serial (``M1292``, ``61283``, ``71292`` in the release); the suffix is removed only
    when ``metadata.json``'s serial ends with it, so other names are kept whole.
    """
    name = os.path.basename(os.path.normpath(folder))
    head, sep, tail = name.rpartition("_")
    serial = read_serial(folder)
    if sep and head and tail and re.fullmatch(r"[0-9A-Za-z]{4,}", tail) and serial.endswith(tail):
        return head
    return name


@contextlib.contextmanager
def quiet_native_output():
    """Silence the C++ log lines projectaria-tools prints on file descriptors 1 and 2."""
    saved = []
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
    except OSError:
        yield
        return
    try:
        for fd in (1, 2):
            try:
                saved.append((fd, os.dup(fd)))
                os.dup2(devnull, fd)
            except OSError:
                pass
        yield
    finally:
        for fd, copy in saved:
            os.dup2(copy, fd)
            os.close(copy)
        os.close(devnull)


def check_vrs(path: str) -> None:
    """A VRS file must start with the VRS header and its records, each with a 32-byte header
    giving its size and the previous record's, must chain to the exact end of the file."""
    name, size = os.path.basename(path), os.path.getsize(path)
    with open(path, "rb") as handle:
        header = handle.read(80)
        if len(header) < 80 or header[:8] != b"VisionRe" or header[72:76] != b"cord":
            raise InputError(f"{name} is not a VRS file (no VRS file header in its first 80 bytes)")
        record_header_size, _, description, first_record = struct.unpack_from("<Iqqq", header, 20)
        offset, previous = first_record or description, None
        if offset >= size:
            raise InputError(f"{name} is truncated: its records start at byte {offset}, it has {size} bytes")
        while offset < size:
            handle.seek(offset)
            fields = handle.read(8)
            if len(fields) < 8:
                raise InputError(f"{name} is truncated: it ends inside the record header at byte {offset}")
            record_size, previous_size = struct.unpack("<II", fields)
            if record_size < record_header_size or previous not in (None, previous_size):
                raise InputError(f"{name} is corrupt: the record header at byte {offset} is not valid")
            if offset + record_size > size:
                raise InputError(
                    f"{name} is truncated or corrupt: the record at byte {offset} takes {record_size} bytes, "
                    f"the file ends {size - offset} bytes later"
                )
            offset, previous = offset + record_size, record_size


def check_csv(path: str) -> None:
    """A ground-truth CSV (``CSV_COLUMNS``) must have its columns, rows, finite numbers and unit
    quaternions (any other is no rotation)."""
    name = os.path.basename(path)
    label, translation, quaternion = CSV_COLUMNS[name]
    try:
        with open(path, newline="") as handle:
            rows = list(csv.reader(handle))
    except (csv.Error, UnicodeDecodeError) as error:
        raise InputError(f"{name} is not a readable CSV ({error})") from None
    header = rows[0] if rows else []
    missing = [column for column in (*label, *translation, *quaternion) if column not in header]
    if missing:
        raise InputError(f"{name} has no column {', '.join(missing)}")
    if len(rows) < 2:
        raise InputError(f"{name} has no row below its header")
    numeric = [i for i, column in enumerate(header) if column not in TEXT_COLUMNS]

    def where(line: int) -> str:
        row = rows[line - 1]
        return f"{name} line {line} ({', '.join(f'{c}={row[header.index(c)]}' for c in label)})"

    values = np.empty((len(rows) - 1, len(numeric)))
    for line, row in enumerate(rows[1:], start=2):
        if len(row) != len(header):
            raise InputError(f"{name} line {line} has {len(row)} fields, the header {len(header)}")
        try:
            values[line - 2] = [float(row[i]) for i in numeric]
        except ValueError:
            i = next(i for i in numeric if not _is_number(row[i]))
            raise InputError(f"{where(line)}: {header[i]} is {row[i]!r}, not a number") from None
    bad = np.argwhere(~np.isfinite(values))
    if len(bad):
        line, i = int(bad[0, 0]) + 2, numeric[bad[0, 1]]
        raise InputError(f"{where(line)}: {header[i]} is {rows[line - 1][i]!r}, not a finite number")
    if quaternion:
        norms = np.linalg.norm(values[:, [numeric.index(header.index(c)) for c in quaternion]], axis=1)
        off = np.flatnonzero(np.abs(norms - 1) > 1e-3)
        if len(off):
            raise InputError(
                f"{where(int(off[0]) + 2)}: the quaternion ({', '.join(quaternion)}) has norm "
                f"{norms[off[0]]:.3g}, not 1: not a rotation"
            )


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def check_json(path: str) -> None:
    """A JSON file of the sequence must hold a non-empty JSON object."""
    name = os.path.basename(path)
    try:
        with open(path, "rb") as handle:
            value = json.load(handle)
    except ValueError as error:
        raise InputError(f"{name} is not valid JSON ({error})") from None
    if not isinstance(value, dict) or not value:
        raise InputError(f"{name} holds no JSON object with entries")


@functools.lru_cache(maxsize=256)
def _check_file_version(path: str, size: int, mtime_ns: int) -> None:
    """``size`` and ``mtime_ns`` only key the cache: a changed file is checked again."""
    name = os.path.basename(path)
    if name.endswith(".vrs"):
        check_vrs(path)
    elif name.endswith(".json"):
        check_json(path)
    elif name in CSV_COLUMNS:
        check_csv(path)


def check_file(path: str) -> None:
    """Check a VRS, JSON or ground-truth CSV file before projectaria-tools reads it (each version
    of a file once per process)."""
    stat = os.stat(path)
    _check_file_version(path, stat.st_size, stat.st_mtime_ns)


def _se3(transform) -> np.ndarray:
    return np.asarray(transform.to_matrix(), dtype=np.float64)


class ObjectPoses(Mapping[int, np.ndarray]):
    """Object id -> ``transform_scene_object`` [4, 4] of every object with a pose at a frame, each
    pose converted from projectaria-tools' box when first read (a frame poses every object of the
    scene, a few hundred; the annotation reads those its tracks are on)."""

    def __init__(self, boxes: dict):
        self._boxes = boxes
        self._poses: dict[int, np.ndarray] = {}

    def __getitem__(self, object_id: int) -> np.ndarray:
        pose = self._poses.get(object_id)
        if pose is None:
            pose = self._poses[object_id] = _se3(self._boxes[object_id].transform_scene_object)
        return pose

    def __contains__(self, object_id: object) -> bool:
        return object_id in self._boxes

    def __iter__(self) -> Iterator[int]:
        return iter(self._boxes)

    def __len__(self) -> int:
        return len(self._boxes)


class SequenceReader:
    """One ADT sequence through ``AriaDigitalTwinDataProvider``.

    Args:
      folder: the sequence folder.
      with_skeleton: read the depth and segmentation that render the wearer's body.
      max_offset_ns: the largest |time offset| accepted between an RGB frame and the depth,
        segmentation and pose samples the provider returns for it (CLOSEST query); 0: any.
    """

    def __init__(self, folder: str, with_skeleton: bool = True, max_offset_ns: int = 5_000_000):
        self.folder = os.path.normpath(folder)
        self.name = os.path.basename(self.folder)
        self.with_skeleton = with_skeleton
        self.max_offset_ns = int(max_offset_ns)
        files = required_files(with_skeleton)
        missing = [f for f in files if not os.path.isfile(os.path.join(folder, f))]
        if missing:
            raise InputError(f"{self.name}: missing {', '.join(missing)}")
        try:
            for file in files:
                check_file(os.path.join(self.folder, file))
        except OSError as error:
            raise InputError(f"{self.name}: cannot read {error.filename} ({error.strerror})") from error
        except InputError as error:
            raise InputError(f"{self.name}: {error}") from error
        from projectaria_tools.core.stream_id import StreamId
        from projectaria_tools.projects import adt

        self._adt = adt
        self.stream = StreamId(RGB_STREAM)
        try:
            with quiet_native_output():
                paths = adt.AriaDigitalTwinDataPathsProvider(self.folder).get_datapaths_by_device_num(
                    0, with_skeleton
                )
                if paths is None:
                    raise InputError(f"{self.name}: projectaria-tools found no device data paths")
                self.provider = adt.AriaDigitalTwinDataProvider(paths)
        except InputError:
            raise
        except Exception as error:  # noqa: BLE001 - projectaria-tools raises plain RuntimeErrors
            raise InputError(f"{self.name}: projectaria-tools cannot open the sequence ({error})") from error
        if not self.provider.has_aria_data():
            raise InputError(f"{self.name}: video.vrs has no Aria data")
        if not self.provider.has_depth_images():
            raise InputError(f"{self.name}: {files[1]} has no depth images")
        if not self.provider.has_segmentation_images():
            raise InputError(f"{self.name}: {files[2]} has no segmentation images")
        calibration = self.provider.get_aria_camera_calibration(self.stream)
        if calibration is None:
            raise InputError(f"{self.name}: video.vrs has no {RGB_LABEL} calibration (stream {RGB_STREAM})")
        self.calibration = calibration
        width, height = (int(n) for n in calibration.get_image_size())
        self.image_shape = (height, width)
        self.device_from_camera = _se3(self.provider.get_aria_transform_device_camera(self.stream))
        self._instances: dict[int, tuple[str, str]] = {}

    # ----------------------------------------------------------------- frames and time window

    def gt_window_ns(self) -> tuple[int, int]:
        return int(self.provider.get_start_time_ns()), int(self.provider.get_end_time_ns())

    def close(self) -> None:
        """Release projectaria-tools' provider (its open VRS files and loaded tables); the reader
        reads nothing after this."""
        self.provider = None

    def frame_timestamps(self) -> np.ndarray:
        """RGB capture timestamps strictly inside the ground-truth window [K] int64 (the release's rule)."""
        stamps = np.asarray(self.provider.get_aria_device_capture_timestamps_ns(self.stream), dtype=np.int64)
        start, end = self.gt_window_ns()
        inside = stamps[(stamps > start) & (stamps < end)]
        if len(inside) == 0:
            raise InputError(
                f"{self.name}: no RGB frame inside the ground-truth window [{start}, {end}] ns "
                f"({len(stamps)} RGB frame(s) in video.vrs)"
            )
        return inside

    def _check_offset(self, what: str, timestamp: int, result) -> None:
        if not result.is_valid():
            raise InputError(f"{self.name}: no {what} for the RGB frame at t={timestamp} ns")
        if self.max_offset_ns and abs(int(result.dt_ns())) > self.max_offset_ns:
            raise InputError(
                f"{self.name}: the nearest {what} to the RGB frame at t={timestamp} ns is "
                f"{abs(int(result.dt_ns())) / 1e6:.1f} ms away (limit {self.max_offset_ns / 1e6:.1f} ms)"
            )

    def _image(self, what: str, timestamp: int, result, shape: tuple[int, ...], dtype) -> np.ndarray:
        """The image of a provider result, which must be the calibration's size and ``dtype``."""
        self._check_offset(what, timestamp, result)
        image = result.data().to_numpy_array()
        if image.shape != shape or image.dtype != dtype:
            raise InputError(
                f"{self.name}: the {what} at t={timestamp} ns is {image.shape} {image.dtype}, "
                f"not {shape} {np.dtype(dtype)} (the {RGB_LABEL} calibration's size)"
            )
        return image

    def rgb(self, timestamp: int) -> np.ndarray:
        """The fisheye RGB frame [H, W, 3] uint8."""
        result = self.provider.get_aria_image_by_timestamp_ns(int(timestamp), self.stream)
        return self._image("RGB image", timestamp, result, (*self.image_shape, 3), np.uint8)

    def depth_mm(self, timestamp: int) -> np.ndarray:
        """The fisheye depth image [H, W] uint16 millimetres (0 = no surface)."""
        result = self.provider.get_depth_image_by_timestamp_ns(int(timestamp), self.stream)
        return self._image("depth image", timestamp, result, self.image_shape, np.uint16)

    def ids(self, timestamp: int) -> np.ndarray:
        """The fisheye instance-id image [H, W] uint64 (0 = none)."""
        result = self.provider.get_segmentation_image_by_timestamp_ns(int(timestamp), self.stream)
        return self._image("segmentation image", timestamp, result, self.image_shape, np.uint64)

    # ----------------------------------------------------------------- poses

    def world_from_device(self, timestamp: int) -> np.ndarray:
        """``transform_scene_device`` at the frame [4, 4]."""
        result = self.provider.get_aria_3d_pose_by_timestamp_ns(int(timestamp))
        self._check_offset("device pose", timestamp, result)
        return _se3(result.data().transform_scene_device)

    def world_from_camera(self, timestamp: int) -> np.ndarray:
        """The RGB camera's pose at the frame: ``transform_scene_device`` x device-from-camera [4, 4]."""
        return self.world_from_device(timestamp) @ self.device_from_camera

    def object_poses(self, timestamp: int) -> ObjectPoses:
        """``transform_scene_object`` [4, 4] of every object with a pose at the frame."""
        result = self.provider.get_object_3d_boundingboxes_by_timestamp_ns(int(timestamp))
        self._check_offset("object poses", timestamp, result)
        return ObjectPoses(result.data())

    # ----------------------------------------------------------------- instances

    def instance(self, instance_id: int) -> tuple[str, str]:
        """(instance_type, motion_type) of an id, lower-case ('object'/'human', 'static'/'dynamic')."""
        instance_id = int(instance_id)
        if instance_id not in self._instances:
            if not self.provider.has_instance_id(instance_id):
                raise InputError(f"{self.name}: instance {instance_id} is not in instances.json")
            info = self.provider.get_instance_info_by_id(instance_id)
            kind = str(info.instance_type).rsplit(".", 1)[-1].lower()
            motion = str(info.motion_type).rsplit(".", 1)[-1].lower()
            self._instances[instance_id] = (kind, motion)
        return self._instances[instance_id]
