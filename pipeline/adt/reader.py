"""Aria Digital Twin access through projectaria-tools: sequences, frames, images, poses, instances.

Everything projectaria-tools returns is checked here and turned into NumPy; a problem raises
``InputError`` naming the sequence and the cause. Poses are [4, 4] float64 matrices
``world_from_*`` (ADT's "scene" frame is our world frame).

Files of a sequence folder (SOURCES.md section 4): ``video.vrs`` (RGB stream 214-1),
``depth_images[_with_skeleton].vrs``, ``segmentations[_with_skeleton].vrs``,
``aria_trajectory.csv``, ``scene_objects.csv``, ``3d_bounding_box.csv``, ``instances.json``,
``metadata.json``.
"""

from __future__ import annotations

import contextlib
import json
import os
import re

import numpy as np

from pipeline.core.errors import InputError

RGB_STREAM = "214-1"
RGB_LABEL = "camera-rgb"
# Files whose presence makes a folder an ADT sequence (any one of them).
SEQUENCE_MARKERS = ("metadata.json", "video.vrs", "scene_objects.csv", "aria_trajectory.csv")


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


def _se3(transform) -> np.ndarray:
    return np.asarray(transform.to_matrix(), dtype=np.float64)


class SequenceReader:
    """One ADT sequence through ``AriaDigitalTwinDataProvider``.

    Args:
      folder: the sequence folder.
      with_skeleton: read the depth and segmentation that render the wearer's body.
      max_offset_ns: the largest |time offset| accepted between an RGB frame and the depth,
        segmentation and pose samples the provider returns for it (CLOSEST query).
    """

    def __init__(self, folder: str, with_skeleton: bool = True, max_offset_ns: int = 5_000_000):
        self.folder = os.path.normpath(folder)
        self.name = os.path.basename(self.folder)
        self.with_skeleton = with_skeleton
        self.max_offset_ns = int(max_offset_ns)
        missing = [f for f in required_files(with_skeleton) if not os.path.isfile(os.path.join(folder, f))]
        if missing:
            raise InputError(f"{self.name}: missing {', '.join(missing)}")
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
        if not self.provider.has_depth_images() or not self.provider.has_segmentation_images():
            raise InputError(f"{self.name}: no depth or segmentation images")
        calibration = self.provider.get_aria_camera_calibration(self.stream)
        if calibration is None:
            raise InputError(f"{self.name}: video.vrs has no {RGB_LABEL} calibration (stream {RGB_STREAM})")
        self.calibration = calibration
        self.device_from_camera = _se3(self.provider.get_aria_transform_device_camera(self.stream))
        self._instances: dict[int, tuple[str, str]] = {}

    # ----------------------------------------------------------------- frames and time window

    def gt_window_ns(self) -> tuple[int, int]:
        return int(self.provider.get_start_time_ns()), int(self.provider.get_end_time_ns())

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
        if abs(int(result.dt_ns())) > self.max_offset_ns:
            raise InputError(
                f"{self.name}: the nearest {what} to the RGB frame at t={timestamp} ns is "
                f"{abs(int(result.dt_ns())) / 1e6:.1f} ms away (limit {self.max_offset_ns / 1e6:.1f} ms)"
            )

    def rgb(self, timestamp: int) -> np.ndarray:
        """The fisheye RGB frame [H, W, 3] uint8."""
        result = self.provider.get_aria_image_by_timestamp_ns(int(timestamp), self.stream)
        self._check_offset("RGB image", timestamp, result)
        image = result.data().to_numpy_array()
        if image.ndim != 3 or image.shape[2] != 3:
            raise InputError(f"{self.name}: RGB frame at t={timestamp} ns has shape {image.shape}")
        return image

    def depth_mm(self, timestamp: int) -> np.ndarray:
        """The fisheye depth image [H, W] uint16 millimetres (0 = no surface)."""
        result = self.provider.get_depth_image_by_timestamp_ns(int(timestamp), self.stream)
        self._check_offset("depth image", timestamp, result)
        return result.data().to_numpy_array()

    def ids(self, timestamp: int) -> np.ndarray:
        """The fisheye instance-id image [H, W] uint64 (0 = none)."""
        result = self.provider.get_segmentation_image_by_timestamp_ns(int(timestamp), self.stream)
        self._check_offset("segmentation image", timestamp, result)
        return result.data().to_numpy_array()

    # ----------------------------------------------------------------- poses

    def world_from_device(self, timestamp: int) -> np.ndarray:
        """``transform_scene_device`` at the frame [4, 4]."""
        result = self.provider.get_aria_3d_pose_by_timestamp_ns(int(timestamp))
        self._check_offset("device pose", timestamp, result)
        return _se3(result.data().transform_scene_device)

    def world_from_camera(self, timestamp: int) -> np.ndarray:
        """The RGB camera's pose at the frame: ``transform_scene_device`` x device-from-camera [4, 4]."""
        return self.world_from_device(timestamp) @ self.device_from_camera

    def object_poses(self, timestamp: int) -> dict[int, np.ndarray]:
        """``transform_scene_object`` [4, 4] of every object with a pose at the frame."""
        result = self.provider.get_object_3d_boundingboxes_by_timestamp_ns(int(timestamp))
        self._check_offset("object poses", timestamp, result)
        return {int(key): _se3(box.transform_scene_object) for key, box in result.data().items()}

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
