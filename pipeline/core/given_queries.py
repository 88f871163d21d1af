"""``--queries-from DIR``: the query points of existing clips, to re-annotate exactly those.

The clip ``<DIR>/<source>/<clip>.npz`` (or ``<DIR>/<clip>.npz``) is matched by name; only its
``queries_xyt`` member is read, without unpickling anything (the JPEG member needs pickle and
is never touched).
"""

from __future__ import annotations

import io

import numpy as np
from apache_beam.io.filesystem import CompressionTypes
from apache_beam.io.filesystems import FileSystems

from pipeline.core.errors import InputError


def given_queries(queries_from: str, source: str, clip: str) -> np.ndarray | None:
    """Queries [N, 3] (x, y, t) of the existing clip named ``clip``, or None if there is none."""
    root = queries_from.rstrip("/")
    for path in (f"{root}/{source}/{clip}.npz", f"{root}/{clip}.npz"):
        if not FileSystems.exists(path):
            continue
        with FileSystems.open(path, compression_type=CompressionTypes.UNCOMPRESSED) as handle:
            data = handle.read()
        try:
            with np.load(io.BytesIO(data), allow_pickle=False) as archive:
                queries = np.asarray(archive["queries_xyt"], dtype=np.float64)
        except (KeyError, ValueError, OSError) as error:
            raise InputError(f"--queries-from {path}: no readable queries_xyt ({error})") from error
        if queries.ndim != 2 or queries.shape[1] != 3 or not np.isfinite(queries).all():
            raise InputError(f"--queries-from {path}: queries_xyt must be finite [N, 3], got {queries.shape}")
        return queries
    return None
