"""Read ``.npz`` files from strangers: never unpickle, never allocate what a header merely claims.

An ``.npz`` is a zip of ``.npy`` members. ``np.load`` trusts both layers: an object member runs
pickle code once pickles are allowed, and a member's header or the zip entry may claim sizes
that exhaust memory (a few MB of deflate can declare 20 GB). Here each member's ``.npy`` header
is parsed first (dtype, shape), object and structured dtypes are refused by name, the declared
size is checked against the zip entry and against a cap the caller derives from the clip, and
only then are exactly those bytes read (zipfile never inflates past the entry's declared size,
and the CRC is checked at the end).
"""

from __future__ import annotations

import dataclasses
import io
import math
import stat
import struct
import zipfile
from typing import Protocol

import numpy as np

# Kinds a TAPVid-3D file may hold: bool, integers, floats, fixed-width bytes (the JPEG frames).
SAFE_KINDS = frozenset("biufS")
# A member's local zip header: 30 bytes, its name, and an extra field (np.savez writes a 20-byte
# zip64 one); a ``.npy`` header: usually 128 bytes. What a remote read fetches ahead for them.
LOCAL_HEADER_FIXED = 30
LOCAL_HEADER_BYTES = LOCAL_HEADER_FIXED + 64
NPY_HEADER_BYTES = 256
# Spans of a remote file to be read that lie at most this far apart are fetched in one request.
MERGE_GAP_BYTES = 64 << 10
# A member's data is read this much at a time into its array (NumPy's own ``.npy`` reads take
# 256 KiB): each piece's CRC and copy run while it is in cache, and no read allocates the whole.
READ_CHUNK_BYTES = 256 << 10


class NpzError(ValueError):
    """A file or member that is refused or unreadable: ``str()`` is ``"<file>: <cause>"``."""

    def __init__(self, name: str, cause: str):
        super().__init__(f"{name}: {cause}")
        self.name = name
        self.cause = cause


@dataclasses.dataclass(frozen=True)
class ArrayHeader:
    """What a member's ``.npy`` header claims: dtype, shape, memory order and data size in bytes."""

    dtype: np.dtype
    shape: tuple[int, ...]
    fortran_order: bool
    nbytes: int
    data_offset: int


class SeekableFile(Protocol):
    """What an archive is read through: a seekable binary file (an open local file, ``io.BytesIO``,
    ``pipeline.io.http.RemoteFile``)."""

    def read(self, size: int = -1, /) -> bytes: ...

    def seek(self, offset: int, whence: int = io.SEEK_SET, /) -> int: ...

    def tell(self) -> int: ...


class NpzArchive:
    """The members of one ``.npz`` (its bytes, or a seekable binary file), read header first. On a
    remote file (``pipeline.io.http.RemoteFile``) each member's span is fetched in one request."""

    def __init__(self, data: bytes | SeekableFile, name: str, max_members: int = 64):
        self.name = name
        self._file = io.BytesIO(data) if isinstance(data, bytes) else data
        try:
            self._zip = zipfile.ZipFile(self._file)
        except (zipfile.BadZipFile, OSError, ValueError) as error:
            raise NpzError(name, f"not an .npz archive ({error})") from error
        infos = self._zip.infolist()
        if len(infos) > max_members:
            raise NpzError(name, f"{len(infos)} members, more than the {max_members} a clip can hold")
        for info in infos:
            _check_member(name, info)
        names = [info.filename for info in infos]
        if len(set(names)) < len(names):
            twice = next(member for member in names if names.count(member) > 1)
            raise NpzError(name, f"member {twice!r} appears more than once; refused")
        self._infos = {
            info.filename[: -len(".npy")]: info for info in infos if info.filename.endswith(".npy")
        }
        self._headers: dict[str, ArrayHeader] = {}

    @property
    def keys(self) -> list[str]:
        return sorted(self._infos)

    def header(self, key: str) -> ArrayHeader:
        """The member's header, checked: a safe dtype, and a data size equal to the zip entry's."""
        if key not in self._headers:
            self._headers[key] = self._read_header(key)
        return self._headers[key]

    def prefetch(self, wanted: dict[str, int | None], max_bytes: int) -> None:
        """On a remote file that can (``RemoteFile.prefetch``), fetch what reading ``wanted`` (member ->
        how many of its data bytes will be read, None: all of them) needs in as few requests as it
        takes (spans at most ``MERGE_GAP_BYTES`` apart merged), when that is at most ``max_bytes``
        in all by the directory's sizes; else each read fetches its own span, after its header's
        checks. Members not in the archive are skipped."""
        fetch = getattr(self._file, "prefetch", None)
        if fetch is None:
            return
        spans = []
        for key, count in wanted.items():
            info = self._infos.get(key)
            if info is not None:
                size = (
                    info.compress_size if count is None else min(info.compress_size, NPY_HEADER_BYTES + count)
                )
                spans.append(_member_span(info, size))
        merged: list[list[int]] = []
        for start, stop in sorted(spans):
            if merged and start <= merged[-1][1] + MERGE_GAP_BYTES:
                merged[-1][1] = max(merged[-1][1], stop)
            else:
                merged.append([start, stop])
        if sum(stop - start for start, stop in merged) <= max_bytes:
            for start, stop in merged:
                fetch(start, stop)

    def _prefetch(self, key: str, data_bytes: int) -> None:
        """On a remote file that can (``RemoteFile.prefetch``), fetch the member's local header and its
        first ``data_bytes`` bytes (its ``.npy`` header included) in one request."""
        prefetch = getattr(self._file, "prefetch", None)
        if prefetch is not None:
            prefetch(*_member_span(self._infos[key], data_bytes))

    def _read_header(self, key: str) -> ArrayHeader:
        info = self._infos[key]
        where = f"member {key!r}"
        self._prefetch(key, NPY_HEADER_BYTES)
        try:
            with self._zip.open(info) as member:
                version = np.lib.format.read_magic(member)
                if version == (1, 0):
                    shape, fortran, dtype = np.lib.format.read_array_header_1_0(member)
                elif version == (2, 0):
                    shape, fortran, dtype = np.lib.format.read_array_header_2_0(member)
                else:
                    raise NpzError(self.name, f"{where}: .npy format version {version} is not read here")
                offset = member.tell()
        except NpzError:
            raise
        except (ValueError, OSError, zipfile.BadZipFile, EOFError, SyntaxError) as error:
            raise NpzError(self.name, f"{where}: unreadable .npy header ({error})") from error
        if dtype.hasobject:
            raise NpzError(self.name, f"{where} is an object array: loading it would need pickle; refused")
        if dtype.kind not in SAFE_KINDS or dtype.fields is not None or dtype.subdtype is not None:
            raise NpzError(
                self.name, f"{where} has dtype {dtype}; only bool, integer, float and bytes arrays are read"
            )
        nbytes = math.prod(shape) * dtype.itemsize
        if info.file_size != offset + nbytes:
            raise NpzError(
                self.name,
                f"{where}: header claims shape {shape} of {dtype} ({nbytes} bytes) but the entry holds "
                f"{info.file_size - offset} bytes of data",
            )
        return ArrayHeader(dtype, tuple(shape), fortran, nbytes, offset)

    def check_size(self, key: str, max_bytes: int, why: str = "") -> None:
        """NpzError when the member's header claims more than ``max_bytes`` of data (``why`` says
        where the cap comes from)."""
        header = self.header(key)
        if header.nbytes > max_bytes:
            limit = f" ({why})" if why else ""
            raise NpzError(
                self.name,
                f"member {key!r} claims shape {header.shape} of {header.dtype} = {_size(header.nbytes)}, "
                f"more than the {_size(max_bytes)} allowed{limit}; refused",
            )

    def read_head(self, key: str, count: int) -> bytes:
        """The first ``count`` bytes (at most the member's) of the member's data, e.g. the start of
        the first JPEG of a frames member, without reading the rest (a stored member's bytes are read
        straight from the archive: exactly those, no read-ahead)."""
        header = self.header(key)
        info = self._infos[key]
        count = min(count, header.nbytes)
        self._prefetch(key, header.data_offset + count)
        try:
            if info.compress_type == zipfile.ZIP_STORED:
                self._file.seek(info.header_offset)
                local = self._file.read(LOCAL_HEADER_FIXED)
                if len(local) != LOCAL_HEADER_FIXED or local[:4] != b"PK\x03\x04":
                    raise zipfile.BadZipFile("bad local file header")
                name_length, extra_length = struct.unpack("<HH", local[26:30])
                self._file.seek(info.header_offset + LOCAL_HEADER_FIXED + name_length + extra_length)
                self._file.seek(header.data_offset, io.SEEK_CUR)
                return self._file.read(count)
            with self._zip.open(info) as member:
                member.read(header.data_offset)
                return member.read(count)
        except (OSError, zipfile.BadZipFile, EOFError, ValueError, struct.error) as error:
            raise NpzError(self.name, f"member {key!r}: unreadable ({error})") from error

    def read(self, key: str, max_bytes: int, why: str = "", writable: bool = True) -> np.ndarray:
        """The member as an array of its own, refused before reading when its data exceed
        ``max_bytes``; ``writable=False`` makes it read-only (for large members that are only
        read, such as a sequence's Gaussians). Read READ_CHUNK_BYTES at a time straight into the
        array: no copy of the whole member is ever made."""
        self.check_size(key, max_bytes, why)
        header = self.header(key)
        where = f"member {key!r}"
        self._prefetch(key, header.data_offset + header.nbytes)
        # A bytearray, not np.empty: NumPy asks the kernel for huge pages for large arrays, whose
        # first touches may stall on memory compaction (the bench's params.npz on a busy machine:
        # 0.22-0.78 s read into np.empty arrays, 0.26-0.36 s into bytearrays).
        data = np.frombuffer(bytearray(header.nbytes), np.uint8)
        filled = 0
        try:
            with self._zip.open(self._infos[key]) as member:
                member.read(header.data_offset)
                while filled < header.nbytes:
                    piece = member.read(min(READ_CHUNK_BYTES, header.nbytes - filled))
                    if not piece:
                        break
                    data[filled : filled + len(piece)] = np.frombuffer(piece, np.uint8)
                    filled += len(piece)
                member.read(1)  # reach the end: zipfile checks the CRC there
        except (OSError, zipfile.BadZipFile, EOFError, ValueError) as error:
            raise NpzError(self.name, f"{where}: unreadable ({error})") from error
        if filled != header.nbytes:
            raise NpzError(self.name, f"{where}: {filled} bytes of data, its header claims {header.nbytes}")
        array = np.frombuffer(data, dtype=header.dtype)
        array = array.reshape(header.shape, order="F" if header.fortran_order else "C")
        array.flags.writeable = writable
        return array


# What np.savez and np.savez_compressed write: members stored or deflated, nothing else.
READ_METHODS = frozenset({zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED})


def _member_span(info: zipfile.ZipInfo, data_bytes: int) -> tuple[int, int]:
    """The byte span [start, stop) of a member's local header and its first ``data_bytes`` bytes."""
    start = info.header_offset
    return start, start + LOCAL_HEADER_BYTES + len(info.orig_filename.encode()) + data_bytes


def _check_member(name: str, info: zipfile.ZipInfo) -> None:
    """NpzError naming the member when it is encrypted, compressed by a method an ``.npz`` never uses,
    a symlink, or named with an absolute path or ``..``."""
    member = info.filename
    if info.flag_bits & 0x1:
        raise NpzError(name, f"member {member!r} is encrypted; refused")
    if info.compress_type not in READ_METHODS:
        raise NpzError(
            name,
            f"member {member!r} uses compression method {info.compress_type}; only stored and deflated "
            "members (what np.savez writes) are read",
        )
    if stat.S_ISLNK(info.external_attr >> 16):
        raise NpzError(name, f"member {member!r} is a symlink; refused")
    if member.startswith("/") or ".." in member.replace("\\", "/").split("/"):
        raise NpzError(name, f"member {member!r} has an absolute or '..' path; refused")


def _size(nbytes: int) -> str:
    for unit, scale in (("GiB", 1 << 30), ("MiB", 1 << 20), ("KiB", 1 << 10)):
        if nbytes >= scale:
            return f"{nbytes / scale:.1f} {unit}"
    return f"{nbytes} bytes"
