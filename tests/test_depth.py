"""The occlusion depth lookup equals the DriveTrack generator's dense-map method."""

import numpy as np

from pipeline.drivetrack.depth import (
    camera_occluded_lidar,
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
