"""Panoptic Studio clips from Dynamic 3D Gaussians (Luiten et al.), as the TAPVid-3D release built them."""

import numba

# OpenMP first: thread-safe when several Beam threads render at once, and it skips the check
# for a TBB this machine may have in a version numba refuses (with a warning on every run).
# numba.config sets its settings at import time from the environment (into globals()), so its type
# information declares none of them.
numba.config.THREADING_LAYER_PRIORITY = ["omp", "tbb", "workqueue"]  # type: ignore[attr-defined]
