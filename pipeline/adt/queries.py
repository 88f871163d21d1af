"""ADT's query pixels: the pools a query may be drawn from (object surface, inside its object's
region, not the wearer), the seeded draw with a dynamic share, and the check that given queries
(``--queries-from``) still land on a posed object."""

from __future__ import annotations

import numpy as np

from pipeline.adt.records import Chunk, Frame, IdRuns, Instances
from pipeline.adt.visibility import interior
from pipeline.core.errors import InputError

# A pixel's kind in ``query_pixel_pools``: no query (no id, or the human's), static, dynamic object.
NONE, STATIC, DYNAMIC = 0, 1, 2


def query_pixel_pools(
    frame: Frame[np.ndarray], runs: IdRuns, instances: Instances
) -> tuple[np.ndarray, np.ndarray]:
    """Flat pixel indices that may hold a query: (on dynamic objects, on static objects).

    A query pixel has a surface (depth > 0), an object id (not 0, not the human) and lies
    inside its object's region (``interior``). ``runs``: the frame's ids as ``IdRuns``, expanded
    to two small images: each pixel's index among the frame's K distinct ids (``interior`` compares
    those, not the uint64 ids) and its kind (none, static, dynamic).
    """
    present, label = np.unique(runs.values, return_inverse=True)
    kind = np.where(np.isin(present, list(instances.dynamic)), DYNAMIC, STATIC).astype(np.uint8)
    kind[(present == 0) | np.isin(present, list(instances.human))] = NONE
    labels = runs.expand(label.astype(np.min_scalar_type(len(present) - 1)))
    pixel_kind = runs.expand(kind[label]) * ((frame.depth_mm > 0) & interior(labels))
    return np.flatnonzero(pixel_kind == DYNAMIC), np.flatnonzero(pixel_kind == STATIC)


def draw_query_pixels(
    dynamic_pool: np.ndarray, static_pool: np.ndarray, count: int, dynamic_share: float, rng
) -> np.ndarray:
    """``count`` distinct flat pixel indices (fewer if the pools are smaller): a share
    ``dynamic_share`` from the dynamic pool when it is not empty, the rest from the static one
    (topped up from the other pool when one runs short)."""
    want_dynamic = min(len(dynamic_pool), int(round(dynamic_share * count))) if len(dynamic_pool) else 0
    want_static = min(len(static_pool), count - want_dynamic)
    want_dynamic = min(len(dynamic_pool), count - want_static)
    chosen = [
        rng.choice(dynamic_pool, size=want_dynamic, replace=False),
        rng.choice(static_pool, size=want_static, replace=False),
    ]
    return np.concatenate(chosen).astype(np.int64)


def check_given_queries(
    chunk: Chunk,
    index: np.ndarray,
    xy: np.ndarray,
    depth: np.ndarray,
    ids: np.ndarray,
    instances: Instances,
    frame: Frame,
) -> None:
    """Given queries [K] must land on an object's surface, or the correspondence is lost."""
    bad = ~np.isfinite(depth) | (ids == 0) | np.isin(ids, list(instances.human) or [0])
    bad |= ~np.isin(ids, list(frame.world_from_object) or [0])
    if bad.any():
        k = int(np.nonzero(bad)[0][0])
        raise InputError(
            f"{chunk.unit}: given query {int(index[k])} of {chunk.name} at ({xy[k, 0]:.1f}, {xy[k, 1]:.1f}) "
            f"lands on no posed object surface (id {int(ids[k])}) in this re-annotation"
        )
