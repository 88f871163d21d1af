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


def test_nearest_within_a_bound_is_the_kd_trees_answer_cut_at_the_bound():
    """With ``within``, centres that cannot be that near any point are skipped before comparing:
    the answer must still be the nearest centre (ties to the first candidate) wherever it is
    within the bound, inf and -1 elsewhere; on lattices, where many centres are at exactly the
    same distance and the bound falls on cell edges, as on scattered centres."""
    rng = np.random.default_rng(1)
    for trial in range(120):
        if trial % 2:
            centres = (np.round(rng.normal(size=(2_000, 3)) * 3) / 3).astype(np.float32)
            points = np.round(rng.normal(size=(40, 3)) * 3) / 3 + 1 / 6  # equidistant from 8 centres
        else:
            centres = rng.normal(size=(2_000, 3)).astype(np.float32)
            points = centres[:20].astype(np.float64) + rng.normal(0, 0.05, (20, 3))
            points = np.concatenate([points, rng.uniform(-4, 4, (20, 3))])
        points[0] = np.nan
        candidates = np.sort(rng.choice(len(centres), 1_500, replace=False))
        within = (0.03, 0.1, np.sqrt(3) / 6, 0.5)[trial % 4]
        distance, position = nearest_centres(centres, candidates, points, within)
        tree_distance, tree_position = cKDTree(centres[candidates].astype(np.float64)).query(points[1:], k=8)
        near = tree_distance[:, 0] <= within
        first = np.where(tree_distance == tree_distance[:, :1], tree_position, len(candidates)).min(axis=1)
        np.testing.assert_array_equal(position[1:], np.where(near, first, -1))
        np.testing.assert_array_equal(distance[1:], np.where(near, tree_distance[:, 0], np.inf))
        assert position[0] == -1
        assert distance[0] == np.inf
