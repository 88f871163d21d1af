"""The brute-force nearest centre (pipeline/pstudio/nearest.py) against scipy's cKDTree, which the
queries were attached with before: the same centres and bit-identical distances."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from pipeline.pstudio.nearest import nearest_centres


def test_nearest_centres_match_a_kd_tree():
    rng = np.random.default_rng(0)
    centres = rng.normal(size=(5_000, 3)).astype(np.float32)  # float32, as params.npz stores them
    candidates = np.sort(rng.choice(len(centres), 3_000, replace=False))
    points = np.concatenate(
        [
            centres[candidates[:200]] + rng.normal(0, 0.01, (200, 3)),
            centres[candidates[200:210]].astype(np.float64),  # on a centre: distance 0
            rng.uniform(-6, 6, (50, 3)),  # far from all
        ]
    )
    distance, position = nearest_centres(centres, candidates, points)
    expected_distance, expected_position = cKDTree(centres[candidates].astype(np.float64)).query(points)
    np.testing.assert_array_equal(position, expected_position)
    np.testing.assert_array_equal(distance, expected_distance)
    assert (distance[200:210] == 0).all()
