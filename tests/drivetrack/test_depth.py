"""The occlusion depth lookup equals the DriveTrack generator's dense-map method."""

import numpy as np

from pipeline.drivetrack.parallax import camera_occluded_lidar
from pipeline.drivetrack.visibility import (
    dense_nearest_depth,
    max4_from_dense,
    nearest_depth_max4,
)


def test_max4_matches_dense_map_on_random_scenes():
    rng = np.random.default_rng(0)
    width, height = 97, 61
    for _ in range(5):
        lidar_uv = rng.uniform([0, 0], [width, height], size=(400, 2))
        lidar_z = rng.uniform(2, 60, size=400)
        queries = rng.uniform([-2, -2], [width + 2, height + 2], size=(300, 2))
        queries[:20] = np.round(queries[:20])  # integer pixels: floor == ceil
        dense = dense_nearest_depth(lidar_uv, lidar_z, width, height)
        np.testing.assert_array_equal(
            nearest_depth_max4(lidar_uv, lidar_z, queries, width, height), max4_from_dense(dense, queries)
        )


def test_max4_takes_the_largest_neighbour_hand_case():
    lidar_uv = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])
    lidar_z = np.array([5.0, 7.0, 3.0, 4.0])
    assert nearest_depth_max4(lidar_uv, lidar_z, np.array([[0.5, 0.5]]), 2, 2)[0] == 7.0
    assert nearest_depth_max4(lidar_uv, lidar_z, np.array([[0.0, 1.0]]), 2, 2)[0] == 3.0


def test_no_lidar_means_unknown_depth():
    assert np.isnan(nearest_depth_max4(np.zeros((0, 2)), np.zeros(0), np.array([[1.0, 1.0]]), 4, 4)).all()


def test_points_behind_a_nearer_surface_are_removed():
    # A grid of background points at 30 m with a patch of foreground points at 10 m; one
    # background point sits inside the foreground patch (seen by the lidar, not the camera).
    cols, rows = np.meshgrid(np.arange(20.0), np.arange(20.0))
    uv = np.stack([cols.ravel(), rows.ravel()], 1)
    z = np.full(len(uv), 30.0)
    patch = (uv[:, 0] >= 5) & (uv[:, 0] < 10) & (uv[:, 1] >= 5) & (uv[:, 1] < 10)
    z[patch] = 10.0
    hidden_index = np.nonzero((uv[:, 0] == 7) & (uv[:, 1] == 7))[0][0]
    z[hidden_index] = 30.0
    hidden = camera_occluded_lidar(uv, z, margin=0.05)
    assert hidden[hidden_index]
    # Foreground points are never hidden; background points touching the patch edge are
    # (they border a nearer surface), background points away from it are kept.
    assert not hidden[patch & (np.arange(len(uv)) != hidden_index)].any()
    far = (uv[:, 0] > 12) | (uv[:, 1] > 12) | (uv[:, 0] < 3) | (uv[:, 1] < 3)
    assert not hidden[far].any()


def kd_tree_occluded(lidar_uv, lidar_depth, margin, neighbours=8):
    """The occlusion test as first written: a KD-tree query of each point's neighbours."""
    from scipy.spatial import cKDTree

    distances, index = cKDTree(lidar_uv).query(lidar_uv, k=neighbours + 1)
    reach = 2.0 * np.median(distances[:, 1])
    nearer = lidar_depth[index[:, 1:]] < (1.0 - 2 * margin) * lidar_depth[:, None]
    return np.any(nearer & (distances[:, 1:] <= reach), axis=1)


def test_the_cell_grid_gives_the_kd_tree_query_answer():
    """On scenes like a projected sweep (dense below, sparse above), clustered, on a line, with ties
    on a lattice, and far apart: the same points hidden as the KD-tree query (no position shared)."""
    rng = np.random.default_rng(3)
    rows = np.repeat(np.geomspace(300, 1279, 40), 400)  # scan lines closer and closer together
    sweep = np.stack([rng.uniform(0, 1920, rows.size), rows + rng.normal(0, 0.3, rows.size)], 1)
    lattice = np.stack(np.meshgrid(np.arange(30.0), np.arange(20.0)), -1).reshape(-1, 2)
    scenes = [
        sweep,
        np.concatenate([rng.normal(0, 3, (300, 2)), rng.normal(500, 30, (300, 2))]),
        np.stack([np.linspace(0, 1000, 300), np.zeros(300)], 1),
        lattice,
        np.concatenate([rng.random((20, 2)), rng.random((20, 2)) + 1e5]),
    ]
    for uv in scenes:
        depth = rng.uniform(2, 60, len(uv))
        depth[rng.random(len(uv)) < 0.5] = 30.0  # surfaces of equal depth as well as clutter
        expected = kd_tree_occluded(uv, depth, 0.05)
        assert 0 < expected.sum() < len(uv)
        np.testing.assert_array_equal(camera_occluded_lidar(uv, depth, 0.05), expected)


def test_the_cell_grid_finds_the_kd_trees_nearest_point_near_and_far():
    """Queries among the points, in the gaps of a sparse patch and far outside the points' extent
    (the image around a lidar cluster): the nearest point is the KD-tree's."""
    from scipy.spatial import cKDTree

    from pipeline.drivetrack.visibility import depth_grid

    rng = np.random.default_rng(4)
    lidar_uv = np.concatenate([rng.normal([900, 900], [200, 40], (3000, 2)), rng.uniform(0, 1920, (30, 2))])
    queries = np.concatenate([rng.uniform(0, 1920, (500, 2)), rng.uniform(-5000, 5000, (100, 2))])
    queries[:50] = np.floor(queries[:50])  # integer pixels, as nearest_depth_max4 asks
    expected = cKDTree(lidar_uv).query(queries)[1]
    np.testing.assert_array_equal(depth_grid(lidar_uv).nearest(queries), expected)
    assert depth_grid(np.zeros((0, 2))) is None
