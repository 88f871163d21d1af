"""Read a TAPVid-3D clip (ours, the release's, or a stranger's prediction) within bounded resources.

Every size a reader allocates is derived from the clip itself before anything is read: T from
the frames member's header (or the tracks' when a prediction file has no frames), N from the
queries' (or the tracks'), and each member may hold at most what a clip of T frames and N tracks
needs. ``ReadLimits`` caps T, N, one JPEG and the whole clip; nothing is ever unpickled.
"""

from __future__ import annotations

import argparse
import dataclasses

import numpy as np

from pipeline.core.images import jpeg_size
from pipeline.io.files import read_bytes
from pipeline.io.http import HttpClient, is_http, open_remote, shown
from pipeline.io.npz_reader import NPY_HEADER_BYTES, NpzArchive, NpzError, SeekableFile

FRAMES = "images_jpeg_bytes"
CLIP_KEYS = (FRAMES, "queries_xyt", "tracks_XYZ", "visibility", "fx_fy_cx_cy", "extrinsics_w2c")
# Widest element a member may use per value (float64, int64): the cap is values x this.
MAX_ITEM_BYTES = 8
# A remote clip's members to be read are fetched together (a few requests in all) when they come to at
# most this by its directory (a release clip's tracks and visibility: 1-10 MB); beyond, member by member,
# each after its header's checks.
MERGED_FETCH_BYTES = 16 << 20


@dataclasses.dataclass(frozen=True)
class ReadLimits:
    """Caps on what one clip file may make a reader allocate.

    The release's largest clips are DriveTrack's: up to 300 frames of 1920x1280 JPEG (~0.5 MB
    each) and 256 tracks; ADT's 300 frames x 1024 tracks hold 7 MB of tracks. The defaults leave
    two orders of magnitude above that and stay far below this machine's memory.
    """

    max_file_bytes: int = 4 << 30
    max_frames: int = 100_000
    max_tracks: int = 1 << 20
    max_frame_bytes: int = 64 << 20
    max_clip_bytes: int = 4 << 30
    max_image_pixels: int = 100_000_000


DEFAULT_LIMITS = ReadLimits()


def add_limit_argument(parser: argparse.ArgumentParser) -> None:
    """``--limit NAME=VALUE`` (repeatable) on a command that reads clips from elsewhere."""
    names = ", ".join(field.name for field in dataclasses.fields(ReadLimits))
    parser.add_argument(
        "--limit",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help=f"raise or lower a cap on what one clip may make the reader allocate ({names}); sizes in bytes",
    )


def limits_from(assignments: list[str]) -> ReadLimits:
    """ReadLimits with ``NAME=VALUE`` assignments applied; ValueError naming a bad one."""
    values = {}
    names = [field.name for field in dataclasses.fields(ReadLimits)]
    for assignment in assignments:
        name, _, text = assignment.partition("=")
        if name not in names:
            raise ValueError(f"--limit {assignment!r}: unknown limit; valid: {', '.join(names)}")
        if not text.isdigit() or int(text) < 1:
            raise ValueError(f"--limit {assignment!r}: expected a positive integer")
        values[name] = int(text)
    return ReadLimits(**values)


def read_clip_file(
    path: str,
    limits: ReadLimits = DEFAULT_LIMITS,
    keys: tuple[str, ...] = CLIP_KEYS,
    client: HttpClient | None = None,
) -> dict[str, np.ndarray]:
    """``read_clip_bytes`` of the file at ``path``, refusing an oversized file before reading it: any
    Beam filesystem's file is read whole; an ``http(s)://`` one by Range requests for the members of
    ``keys`` only (through ``client``, or one made with the default policy). HttpError when a remote
    file cannot be fetched (kind not_found: there is none)."""
    if is_http(path):
        with open_remote(client or HttpClient(), path, limits.max_file_bytes) as remote:
            return read_clip_bytes(remote, shown(path), limits, keys)
    try:
        data = read_bytes(path, limits.max_file_bytes)
    except OSError as error:
        raise NpzError(path, f"cannot be read ({error.strerror or error})") from error
    return read_clip_bytes(data, path, limits, keys)


def read_clip_bytes(
    data: bytes | SeekableFile,
    name: str,
    limits: ReadLimits = DEFAULT_LIMITS,
    keys: tuple[str, ...] = CLIP_KEYS,
) -> dict[str, np.ndarray]:
    """The members of ``keys`` the clip (its bytes, or a seekable file) holds, as arrays (missing keys
    are absent from the result).

    Raises NpzError naming the file, the member and the cause: a member that would need pickle,
    a dtype other than bool/int/float/bytes, or a declared size beyond what T and N allow.
    """
    return read_clip_archive(NpzArchive(data, name), limits, keys)


def read_clip_archive(
    archive: NpzArchive, limits: ReadLimits = DEFAULT_LIMITS, keys: tuple[str, ...] = CLIP_KEYS
) -> dict[str, np.ndarray]:
    """``read_clip_bytes`` of an opened archive."""
    name = archive.name
    present = [key for key in keys if key in archive.keys]
    archive.prefetch(dict.fromkeys(present), MERGED_FETCH_BYTES)
    num_frames, num_tracks = clip_dimensions(archive, present)
    if num_frames > limits.max_frames or num_tracks > limits.max_tracks:
        raise NpzError(
            name,
            f"headers claim T = {num_frames} frames and N = {num_tracks} tracks; at most "
            f"{limits.max_frames} frames and {limits.max_tracks} tracks are read",
        )
    caps = member_caps(num_frames, num_tracks, limits)
    if FRAMES in present and archive.header(FRAMES).dtype.itemsize > limits.max_frame_bytes:
        raise NpzError(
            name,
            f"member {FRAMES!r} claims frames of {archive.header(FRAMES).dtype.itemsize} bytes, more "
            f"than {limits.max_frame_bytes} allowed per JPEG; refused",
        )
    why = f"a clip of T = {num_frames} frames and N = {num_tracks} tracks"
    for key in present:
        archive.check_size(key, caps.get(key, limits.max_clip_bytes), why)
    total = sum(archive.header(key).nbytes for key in present)
    if total > limits.max_clip_bytes:
        raise NpzError(name, f"members claim {total} bytes in all, more than {limits.max_clip_bytes} allowed")
    return {key: archive.read(key, caps.get(key, limits.max_clip_bytes), why) for key in present}


# The first frame's size is read from its first FRAME_HEAD_BYTES (a JPEG's frame header comes after
# its tables, within about 1 KB), else from the whole frame.
FRAME_HEAD_BYTES = 2 << 10


def first_frame_size(archive: NpzArchive, limits: ReadLimits = DEFAULT_LIMITS) -> tuple[int, int] | None:
    """(height, width) of the clip's first frame from its JPEG header, reading only the start of that
    frame (a remote clip's other frames are never fetched); None when it has no readable one."""
    if FRAMES not in archive.keys:
        return None
    archive.prefetch({FRAMES: FRAME_HEAD_BYTES}, FRAME_HEAD_BYTES + NPY_HEADER_BYTES)
    header = archive.header(FRAMES)
    if header.dtype.kind != "S" or len(header.shape) != 1 or not header.shape[0]:
        return None
    size = jpeg_size(archive.read_head(FRAMES, min(header.dtype.itemsize, FRAME_HEAD_BYTES)))
    if size is None and FRAME_HEAD_BYTES < header.dtype.itemsize <= limits.max_frame_bytes:
        size = jpeg_size(archive.read_head(FRAMES, header.dtype.itemsize))
    return size


def clip_dimensions(archive: NpzArchive, keys: list[str]) -> tuple[int, int]:
    """(T, N) as the headers of the members ``keys`` give them: T from the frames (else tracks,
    visibility), N from the queries (else tracks, visibility); 0 where none says. Members not
    asked for are not looked at."""
    shapes = {key: archive.header(key).shape for key in keys}
    frames = (shapes.get(FRAMES), shapes.get("tracks_XYZ"), shapes.get("visibility"))
    tracks = ((shapes.get("queries_xyt"), 0), (shapes.get("tracks_XYZ"), 1), (shapes.get("visibility"), 1))
    num_frames = next((shape[0] for shape in frames if shape), 0)
    num_tracks = next((shape[axis] for shape, axis in tracks if shape and len(shape) > axis), 0)
    return num_frames, num_tracks


def member_caps(num_frames: int, num_tracks: int, limits: ReadLimits) -> dict[str, int]:
    """The most bytes each member of a clip with T frames and N tracks may hold."""
    return {
        FRAMES: num_frames * limits.max_frame_bytes,
        "queries_xyt": num_tracks * 3 * MAX_ITEM_BYTES,
        "tracks_XYZ": num_frames * num_tracks * 3 * MAX_ITEM_BYTES,
        "visibility": num_frames * num_tracks * MAX_ITEM_BYTES,
        "fx_fy_cx_cy": 4 * MAX_ITEM_BYTES,
        "extrinsics_w2c": num_frames * 16 * MAX_ITEM_BYTES,
    }
