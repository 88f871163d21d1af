"""An ADT sequence opened for annotation: its reader, its ground-truth frame timestamps, and each
frame in the stored camera (re-rendered RGB as JPEG, depth, ids, poses), read one at a time."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np

from pipeline.adt.reader import SequenceReader
from pipeline.adt.records import Frame, Instances
from pipeline.adt.rectify import Rectifier, stored_cam_from_world
from pipeline.adt.settings import AdtConfig

JPEG_QUALITY = 95


def open_reader(sequence: str, settings: AdtConfig) -> SequenceReader:
    return SequenceReader(sequence, settings.with_skeleton, int(settings.max_gt_offset_ms * 1e6))


def encode_jpeg(image_rgb: np.ndarray) -> bytes:
    """RGB [H, W, 3] uint8 -> JPEG bytes (OpenCV, deterministic for a given build). The channels are
    swapped by ``cvtColor`` (a reversed view, ``[..., ::-1]``, is copied pixel by pixel by OpenCV's
    binding, for the same bytes)."""
    bgr = cv2.cvtColor(image_rgb, cv2.COLOR_RGB2BGR)
    ok, data = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    if not ok:
        raise RuntimeError("JPEG encoding failed")
    return data.tobytes()


class SequenceFrames:
    """A sequence's frames in the stored camera, read one at a time (the callables annotate uses);
    the re-rendering tables are built on construction (once per calibration per process)."""

    def __init__(self, reader: SequenceReader, settings: AdtConfig):
        self.reader = reader
        self.rectifier = Rectifier(reader.calibration, settings.image_size, settings.focal)
        # The ids looked up so far (``reader.instance``), and those of them human / dynamic.
        self._known: set[int] = set()
        self._human: set[int] = set()
        self._dynamic: set[int] = set()

    def frame(self, timestamp: int) -> Frame[np.ndarray]:
        return Frame(
            depth_mm=self.rectifier.depth_mm(self.reader.depth_mm(timestamp)),
            ids=self.rectifier.ids(self.reader.ids(timestamp)),
            cam_from_world=stored_cam_from_world(self.reader.world_from_camera(timestamp)),
            world_from_object=self.reader.object_poses(timestamp),
            timestamp=int(timestamp),
        )

    def jpeg(self, timestamp: int) -> bytes:
        return encode_jpeg(self.rectifier.rgb(self.reader.rgb(timestamp)))

    def instances(self, ids: np.ndarray) -> Instances:
        """Which of the distinct ids [K] (0 = none) are human / dynamic: set intersections with the
        sequence's ids classified so far, each new id looked up once (in ascending order)."""
        present = set(ids.tolist())
        present.discard(0)
        for instance_id in sorted(present - self._known):
            kind, motion = self.reader.instance(instance_id)
            if kind == "human":
                self._human.add(instance_id)
            elif motion == "dynamic":
                self._dynamic.add(instance_id)
            self._known.add(instance_id)
        return Instances(frozenset(present & self._human), frozenset(present & self._dynamic))


@dataclasses.dataclass(frozen=True)
class OpenedSequence:
    """What a sequence's chunks share: its frame timestamps [F] (the ground-truth window) and its
    frames in the stored camera (the reader and the re-rendering tables)."""

    path: str
    stamps: np.ndarray
    frames: SequenceFrames


def open_sequence(sequence: str, settings: AdtConfig) -> OpenedSequence:
    """Open a sequence: its reader, frame timestamps and re-rendering tables."""
    reader = open_reader(sequence, settings)
    return OpenedSequence(sequence, reader.frame_timestamps(), SequenceFrames(reader, settings))


def close_sequence(opened: OpenedSequence) -> None:
    """Release an opened sequence's reader when its chunks are done (a group's one closing, as its
    one opening)."""
    opened.frames.reader.close()
