"""Panoptic Studio clips from Dynamic 3D Gaussians (Luiten et al.), as the TAPVid-3D release built them."""

import numba

# OpenMP first: thread-safe when several Beam threads render at once, and it skips the check
# for a TBB this machine may have in a version numba refuses (with a warning on every run).
numba.config.THREADING_LAYER_PRIORITY = ["omp", "tbb", "workqueue"]
