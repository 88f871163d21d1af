"""``--queries-from DIR``: the query points of existing clips, to re-annotate exactly those.

The clip ``<DIR>/<source>/<clip>.npz`` (or ``<DIR>/<clip>.npz``) is matched by name; only its
``queries_xyt`` member is read, through ``pipeline.io.clip_reader`` (nothing unpickled, its
size bounded by the clip's own headers), so a released file or a stranger's works alike. DIR may be
an ``http(s)://`` base, such as the release's bucket: then ``<DIR>/<source>/<clip>.npz`` is read by
Range requests (its directory and that member only), and a 404 means the release has no such clip.
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np

from pipeline.core.errors import InputError
from pipeline.io.clip_reader import read_clip_file
from pipeline.io.files import exists
from pipeline.io.http import HttpError, is_http, join, shared_client, shown
from pipeline.io.npz_reader import NpzError
from pipeline.settings.run_config import HttpConfig


@dataclasses.dataclass(frozen=True)
class GivenQueries:
    """One source's clips of ``--queries-from``, looked up by clip name (``of``).

    folder: the ``--queries-from`` folder or http(s) base; "" when the run has none.
    source: the source whose clips they are (the ``<folder>/<source>/`` subfolder).
    http: how an http(s) base is read.
    """

    folder: str
    source: str
    http: HttpConfig = dataclasses.field(default_factory=HttpConfig)

    @property
    def active(self) -> bool:
        """True when the run re-annotates existing clips (then only clips found there are made)."""
        return bool(self.folder.rstrip("/"))

    def admits(self, clip: str) -> bool:
        """False when ``--queries-from`` is set and holds no clip ``clip`` (then none is made)."""
        return not self.active or self.of(clip) is not None

    def of(self, clip: str) -> np.ndarray | None:
        """Queries [N, 3] (x, y, t) of the existing clip ``clip``, or None (``given_queries``)."""
        return given_queries(self.folder, self.source, clip, self.http)


def given_queries(
    queries_from: str, source: str, clip: str, http: HttpConfig | None = None
) -> np.ndarray | None:
    """Queries [N, 3] (x, y, t) of the existing clip named ``clip``, or None if there is none (or no
    ``queries_from``) (over
    HTTP under ``http``; the last few remote lookups of a process are kept: a source may ask twice).

    InputError naming the file when it is refused or unreadable, when the queries are not a finite
    [N, 3] float array, or when a query frame t is not a non-negative integer.
    """
    root = queries_from.rstrip("/")
    if not root:
        return None
    if is_http(root):
        found = _remote_queries(join(root, f"{source}/{clip}.npz"), http or HttpConfig())
        return None if found is None else found.copy()
    for path in (f"{root}/{source}/{clip}.npz", f"{root}/{clip}.npz"):
        if exists(path):
            return _read_queries(path)
    return None


@functools.lru_cache(maxsize=8)
def _remote_queries(url: str, http: HttpConfig) -> np.ndarray | None:
    """``_read_queries`` of an HTTP(S) URL; None on 404 (not there)."""
    try:
        return _read_queries(url, http)
    except HttpError as error:
        if error.kind == "not_found":
            return None
        raise InputError(f"--queries-from {error.url}: {error}") from error


def _read_queries(path: str, http: HttpConfig | None = None) -> np.ndarray:
    """The checked queries [N, 3] float64 of the clip file at ``path``."""
    try:
        arrays = read_clip_file(path, keys=("queries_xyt",), client=shared_client(http) if http else None)
    except NpzError as error:
        raise InputError(f"--queries-from {error}") from error
    path = shown(path)
    if "queries_xyt" not in arrays:
        raise InputError(f"--queries-from {path}: no queries_xyt member")
    queries = arrays["queries_xyt"]
    if queries.dtype.kind != "f" or queries.ndim != 2 or queries.shape[1] != 3:
        raise InputError(
            f"--queries-from {path}: queries_xyt must be a float [N, 3] array, got {queries.dtype} "
            f"{queries.shape}"
        )
    queries = queries.astype(np.float64)
    if not np.isfinite(queries).all():
        raise InputError(f"--queries-from {path}: queries_xyt holds non-finite values")
    frames = queries[:, 2]
    bad = (frames != np.round(frames)) | (frames < 0)
    if bad.any():
        raise InputError(
            f"--queries-from {path}: query {int(np.flatnonzero(bad)[0])} has frame {frames[bad][0]!r}, "
            "not a frame index (a non-negative integer)"
        )
    return queries


def given_query_frames(queries: np.ndarray, num_frames: int, what: str) -> np.ndarray:
    """Query frames [N] int64 of given queries [N, 3], each checked to be one of the clip's
    ``num_frames`` frames (InputError naming ``what`` and the first query outside)."""
    frames = queries[:, 2].astype(np.int64)
    outside = (frames < 0) | (frames >= num_frames)
    if outside.any():
        k = int(np.flatnonzero(outside)[0])
        raise InputError(
            f"{what}: given query {k} has frame {frames[k]}, outside the clip's 0..{num_frames - 1}"
        )
    return frames
