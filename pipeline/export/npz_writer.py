"""Clips as ``.npz`` files in the released TAPVid-3D schema, byte-for-byte reproducible.

``np.savez`` stamps each zip member with the current time, so two runs would differ; this
writer uses the same container (a zip of ``.npy`` members) with a fixed timestamp.
"""

from __future__ import annotations

import dataclasses
import io
import zipfile
from collections.abc import Mapping
from typing import IO

import numpy as np

from pipeline.core.clip import ClipRecord

FIXED_ZIP_TIME = (1980, 1, 1, 0, 0, 0)


@dataclasses.dataclass(frozen=True)
class FixedWidthBytes:
    """``np.array(items, dtype=np.bytes_)`` without building it: [T] ``|S<longest>`` (at least
    ``|S1``, as NumPy makes it), each item NUL-padded to the width. ``encode_npz`` writes the
    items straight into the archive (a clip of Waymo frames is tens of MB: the array would be one
    more copy of it, made item by item)."""

    items: list[bytes]

    @property
    def width(self) -> int:
        return max(1, max((len(item) for item in self.items), default=0))

    @property
    def nbytes(self) -> int:
        return self.width * len(self.items)

    def header(self) -> dict[str, object]:
        """The ``.npy`` header fields of the array."""
        return {"descr": f"|S{self.width}", "fortran_order": False, "shape": (len(self.items),)}

    def write(self, stream: IO[bytes]) -> None:
        """The array's bytes, item by item: each item, then its NUL padding."""
        width = self.width
        padding = memoryview(bytes(width))
        for item in self.items:
            stream.write(item)
            if len(item) < width:
                stream.write(padding[: width - len(item)])

    def array(self) -> np.ndarray:
        """The array itself (read-only)."""
        buffer = io.BytesIO()
        self.write(buffer)
        return np.frombuffer(buffer.getvalue(), dtype=f"S{self.width}")


def clip_members(clip: ClipRecord) -> dict[str, np.ndarray | FixedWidthBytes]:
    """The released schema's members for a clip: frames as a fixed-width bytes array ``|S<longest>``
    [T] (what ``np.savez`` makes of the release's list of JPEG bytes; NumPy strips the NUL
    padding on read and a JPEG ends in FF D9), float32 tracks and queries, bool visibility,
    float64 intrinsics as the release writes them, float64 extrinsics (a camera 15 km from the
    world's origin is rounded by ~1 mm in float32). No object array: the file opens with a
    plain ``np.load``."""
    members: dict[str, np.ndarray | FixedWidthBytes] = {
        "images_jpeg_bytes": FixedWidthBytes(clip.images_jpeg),
        "queries_xyt": clip.queries_xyt.astype(np.float32),
        "tracks_XYZ": clip.tracks_xyz.astype(np.float32),
        "visibility": clip.visibility.astype(bool),
        "fx_fy_cx_cy": np.asarray(clip.fx_fy_cx_cy, dtype=np.float64),
    }
    if clip.extrinsics_w2c is not None:
        members["extrinsics_w2c"] = clip.extrinsics_w2c.astype(np.float64)
    return members


def clip_arrays(clip: ClipRecord) -> dict[str, np.ndarray]:
    """``clip_members`` as the arrays ``np.load`` gives back."""
    members = clip_members(clip)
    return {key: v.array() if isinstance(v, FixedWidthBytes) else v for key, v in members.items()}


def encode_npz(members: Mapping[str, np.ndarray | FixedWidthBytes], compress: bool = False) -> bytes:
    """A deterministic ``.npz`` readable by np.load: stored like ``np.savez``, or deflated like
    ``np.savez_compressed`` with ``compress``.

    Each member is written straight into the archive: saving it to a buffer of its own first, as
    ``np.savez`` does, costs two more copies of it (for a clip of Waymo frames, tens of MB, and
    40% of the encoding time). The bytes are those of that recipe (tests/export/test_export.py): the
    member's size is set before it is opened, as ``ZipFile.writestr`` sets it (it decides the
    ZIP64 headers), and its ``.npy`` header is format 1.0, as ``np.save`` writes any header
    under 64 KiB."""
    buffer = io.BytesIO()
    method = zipfile.ZIP_DEFLATED if compress else zipfile.ZIP_STORED
    with zipfile.ZipFile(buffer, "w", compression=method, allowZip64=True) as archive:
        for key in sorted(members):
            value = members[key]
            if isinstance(value, FixedWidthBytes):
                fields = value.header()
            else:
                value = np.asanyarray(value)
                fields = np.lib.format.header_data_from_array_1_0(value)
            header = io.BytesIO()
            np.lib.format.write_array_header_1_0(header, fields)
            info = zipfile.ZipInfo(f"{key}.npy", date_time=FIXED_ZIP_TIME)
            info.compress_type = method
            info.external_attr = 0o644 << 16
            info.file_size = header.tell() + value.nbytes
            with archive.open(info, "w") as member:
                if isinstance(value, FixedWidthBytes):
                    member.write(header.getvalue())
                    value.write(member)
                else:
                    np.lib.format.write_array(member, value, version=(1, 0), allow_pickle=False)
    return buffer.getvalue()
