"""Hostile ``.npz`` files, as a stranger could send them: pickle payloads, deflate bombs, shape bombs.

``marker`` files prove a payload never ran: unpickling a payload member creates its marker.
"""

from __future__ import annotations

import io
import struct
import zlib

import numpy as np


class MarkerPayload:
    """Unpickling this object calls ``open(marker, "w")``: the marker file appears."""

    def __init__(self, marker: str):
        self.marker = marker

    def __reduce__(self):
        return (open, (self.marker, "w"))


def npy_bytes(array: np.ndarray) -> bytes:
    member = io.BytesIO()
    np.lib.format.write_array(member, array, allow_pickle=True)
    return member.getvalue()


def with_payload(arrays: dict[str, np.ndarray], key: str, marker: str) -> dict[str, np.ndarray]:
    """``arrays`` with member ``key`` replaced by an object array whose unpickling creates ``marker``."""
    payload = np.empty(2, dtype=object)
    payload[:] = [MarkerPayload(marker), b"\xff\xd8"]
    return {**arrays, key: payload}


def savez_bytes(arrays: dict[str, np.ndarray]) -> bytes:
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    return buffer.getvalue()


def npy_header(dtype: np.dtype, shape: tuple[int, ...]) -> bytes:
    """A version 1.0 ``.npy`` header claiming ``shape`` of ``dtype`` (no data)."""
    member = io.BytesIO()
    header = {"descr": np.lib.format.dtype_to_descr(np.dtype(dtype)), "fortran_order": False, "shape": shape}
    np.lib.format.write_array_header_1_0(member, header)
    return member.getvalue()


def zip_members(members: dict[str, tuple[bytes, int, int, int]]) -> bytes:
    """A zip64 archive of raw deflate members: name -> (compressed bytes, uncompressed size, crc32,
    method). Written by hand so a member may declare a size it was never compressed from."""
    out, central = io.BytesIO(), []
    for name, (data, size, crc, method) in members.items():
        offset = out.tell()
        encoded = name.encode()
        extra = struct.pack("<HHQQ", 1, 16, size, len(data))
        out.write(
            struct.pack(
                "<IHHHHHIIIHH",
                0x04034B50,
                45,
                0,
                method,
                0,
                0x21,
                crc,
                0xFFFFFFFF,
                0xFFFFFFFF,
                len(encoded),
                len(extra),
            )
        )
        out.write(encoded + extra + data)
        extra = struct.pack("<HHQQQ", 1, 24, size, len(data), offset)
        central.append(
            struct.pack(
                "<IHHHHHHIIIHHHHHII",
                0x02014B50,
                45,
                45,
                0,
                method,
                0,
                0x21,
                crc,
                0xFFFFFFFF,
                0xFFFFFFFF,
                len(encoded),
                len(extra),
                0,
                0,
                0,
                0,
                0xFFFFFFFF,
            )
            + encoded
            + extra
        )
    start = out.tell()
    for entry in central:
        out.write(entry)
    size = out.tell() - start
    end = out.tell()
    count = len(central)
    out.write(struct.pack("<IQHHIIQQQQ", 0x06064B50, 44, 45, 45, 0, 0, count, count, size, start))
    out.write(struct.pack("<IIQI", 0x07064B50, 0, end, 1))
    out.write(struct.pack("<IHHHHIIH", 0x06054B50, 0, 0, 0xFFFF, 0xFFFF, 0xFFFFFFFF, 0xFFFFFFFF, 0))
    return out.getvalue()


def stored(data: bytes) -> tuple[bytes, int, int, int]:
    return data, len(data), zlib.crc32(data), 0


def deflate_bomb(header: bytes, zeros: int) -> tuple[bytes, int, int, int]:
    """A member that inflates to ``header`` + ``zeros`` zero bytes from about zeros / 1000 bytes: one
    compressed MiB of zeros, fully flushed (byte-aligned, no back-references across it), repeated.
    Its CRC is left 0: a reader that inflates it all has allocated the bomb before it can notice."""
    chunk = 1 << 20
    compressor = zlib.compressobj(9, zlib.DEFLATED, -15)
    head = compressor.compress(header) + compressor.flush(zlib.Z_FULL_FLUSH)
    block = compressor.compress(bytes(chunk)) + compressor.flush(zlib.Z_FULL_FLUSH)
    last = zlib.compressobj(9, zlib.DEFLATED, -15)  # the remainder, ending in the final block
    tail = last.compress(bytes(zeros % chunk)) + last.flush(zlib.Z_FINISH)
    return head + block * (zeros // chunk) + tail, len(header) + zeros, 0, 8


def bomb_clip(clip: dict[str, np.ndarray], key: str, gib: int = 20) -> bytes:
    """``clip`` as an .npz whose member ``key`` inflates to ``gib`` GiB (its header claiming as much)."""
    dtype = clip[key].dtype
    rows = (gib << 30) // (dtype.itemsize * int(np.prod(clip[key].shape[1:])))
    header = npy_header(dtype, (rows, *clip[key].shape[1:]))
    members = {f"{name}.npy": stored(npy_bytes(array)) for name, array in clip.items() if name != key}
    members[f"{key}.npy"] = deflate_bomb(header, rows * (dtype.itemsize * int(np.prod(clip[key].shape[1:]))))
    return zip_members(members)


def shape_bomb_clip(clip: dict[str, np.ndarray], key: str, shape: tuple[int, ...]) -> bytes:
    """``clip`` as an .npz whose member ``key`` claims ``shape`` in its header but holds a few bytes."""
    members = {f"{name}.npy": stored(npy_bytes(array)) for name, array in clip.items() if name != key}
    members[f"{key}.npy"] = stored(npy_header(clip[key].dtype, shape) + bytes(64))
    return zip_members(members)
