"""Clips as ``.npz`` files in the released TAPVid-3D schema, byte-for-byte reproducible.

``np.savez`` stamps each zip member with the current time, so two runs would differ; this
writer uses the same container (a zip of ``.npy`` members) with a fixed timestamp.
"""

from __future__ import annotations

import io
import zipfile

import numpy as np

from pipeline.core.clip import ClipRecord

FIXED_ZIP_TIME = (1980, 1, 1, 0, 0, 0)


def fixed_width_bytes(items: list[bytes]) -> np.ndarray:
    """``np.array(items, dtype=np.bytes_)``: [T] ``|S<longest>``, each item NUL-padded, built with
    one copy of each item (NumPy's own conversion ran four times slower on JPEG-sized items)."""
    width = max((len(item) for item in items), default=0)
    if width == 0:
        return np.array(list(items), dtype=np.bytes_)
    buffer = bytearray(width * len(items))
    for i, item in enumerate(items):
        buffer[i * width : i * width + len(item)] = item
    return np.frombuffer(buffer, dtype=f"S{width}")


def clip_arrays(clip: ClipRecord) -> dict[str, np.ndarray]:
    """The released schema's arrays for a clip: frames as a fixed-width bytes array ``|S<longest>``
    [T] (what ``np.savez`` makes of the release's list of JPEG bytes; NumPy strips the NUL
    padding on read and a JPEG ends in FF D9), float32 tracks and queries, bool visibility,
    float64 intrinsics as the release writes them, float64 extrinsics (a camera 15 km from the
    world's origin is rounded by ~1 mm in float32). No object array: the file opens with a
    plain ``np.load``."""
    arrays = {
        "images_jpeg_bytes": fixed_width_bytes(clip.images_jpeg),
        "queries_xyt": clip.queries_xyt.astype(np.float32),
        "tracks_XYZ": clip.tracks_xyz.astype(np.float32),
        "visibility": clip.visibility.astype(bool),
        "fx_fy_cx_cy": np.asarray(clip.fx_fy_cx_cy, dtype=np.float64),
    }
    if clip.extrinsics_w2c is not None:
        arrays["extrinsics_w2c"] = clip.extrinsics_w2c.astype(np.float64)
    return arrays


def encode_npz(arrays: dict[str, np.ndarray], compress: bool = False) -> bytes:
    """A deterministic ``.npz`` readable by np.load: stored like ``np.savez``, or deflated like
    ``np.savez_compressed`` with ``compress``.

    Each member is written straight into the archive: saving it to a buffer of its own first, as
    ``np.savez`` does, costs two more copies of it (for a clip of Waymo frames, tens of MB, and
    40% of the encoding time). The bytes are those of that recipe (tests/test_export.py): the
    member's size is set before it is opened, as ``ZipFile.writestr`` sets it (it decides the
    ZIP64 headers), and its ``.npy`` header is format 1.0, as ``np.save`` writes any header
    under 64 KiB."""
    buffer = io.BytesIO()
    method = zipfile.ZIP_DEFLATED if compress else zipfile.ZIP_STORED
    with zipfile.ZipFile(buffer, "w", compression=method, allowZip64=True) as archive:
        for key in sorted(arrays):
            array = np.asanyarray(arrays[key])
            header = io.BytesIO()
            np.lib.format.write_array_header_1_0(header, np.lib.format.header_data_from_array_1_0(array))
            info = zipfile.ZipInfo(f"{key}.npy", date_time=FIXED_ZIP_TIME)
            info.compress_type = method
            info.external_attr = 0o644 << 16
            info.file_size = header.tell() + array.nbytes
            with archive.open(info, "w") as member:
                np.lib.format.write_array(member, array, version=(1, 0), allow_pickle=False)
    return buffer.getvalue()
