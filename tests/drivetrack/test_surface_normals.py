"""Fitted normals under millimetres: a box's corner sampled by several noisy sweeps, each moved by
1 mm in its own direction (as boxes rounded to a millimetre place them). Beside the crease a
millimetre decides which plane a point's neighbours vote for; with votes that fall smoothly with a
point's distance to a plane (``surface_normals``) about 13% of the normals there turn by more than 2
degrees, with votes that count the points within 5 mm 27%."""

import numpy as np

from pipeline.drivetrack.surface_normals import fitted_normals


def corner_sweeps(rng: np.random.Generator, sweeps: int = 6) -> tuple[np.ndarray, np.ndarray]:
    """Points [P, 3] of two faces meeting at a right angle along the z axis (x = 0 for y > 0, y = 0
    for x > 0), each sweep a 4 cm grid at its own offset, off its face by a range noise of 3 mm (sd),
    and each point's sweep [P]."""
    points, labels = [], []
    for sweep in range(sweeps):
        du, dz = rng.uniform(0.0, 0.04, 2)
        u = np.arange(du, 0.5, 0.04)
        z = np.arange(dz, 0.4, 0.04)
        uu, zz = (a.ravel() for a in np.meshgrid(u, z))
        face_a = np.stack([rng.normal(0.0, 0.003, len(uu)), uu, zz], 1)
        face_b = np.stack([uu, rng.normal(0.0, 0.003, len(uu)), zz], 1)
        points += [face_a, face_b]
        labels += [np.full(2 * len(uu), sweep)]
    return np.concatenate(points), np.concatenate(labels)


def test_a_millimetre_does_not_turn_the_normals_beside_a_crease():
    rng = np.random.default_rng(0)
    points, sweep = corner_sweeps(rng)
    # Tracked: points 2-10 cm from the crease, away from the patch's other edges.
    beside = (np.minimum(np.abs(points[:, 0]), np.abs(points[:, 1])) < 0.015) & (
        np.maximum(points[:, 0], points[:, 1]) > 0.02
    )
    beside &= (np.maximum(points[:, 0], points[:, 1]) < 0.1) & (points[:, 2] > 0.1) & (points[:, 2] < 0.3)
    tracked = np.flatnonzero(beside)
    towards = np.tile([1.0, 1.0, 0.0], (len(tracked), 1))  # a lidar looking into the corner
    before = fitted_normals(points, tracked, towards)
    truth = np.where(
        (np.abs(points[tracked, 0]) < np.abs(points[tracked, 1]))[:, None], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]
    )
    assert np.mean(np.einsum("ni,ni->n", before, truth) > 0.95) > 0.85
    turned = []
    for seed in range(1, 6):
        nudges = np.random.default_rng(seed).normal(size=(sweep.max() + 1, 3))
        nudges *= 1e-3 / np.linalg.norm(nudges, axis=1, keepdims=True)
        after = fitted_normals(points + nudges[sweep], tracked, towards)
        turned.append(np.mean(np.einsum("ni,ni->n", before, after) < np.cos(np.radians(2.0))))
    print(f"normals turned by more than 2 degrees by a 1 mm nudge: {np.round(turned, 4).tolist()}")
    assert np.mean(turned) < 0.18
