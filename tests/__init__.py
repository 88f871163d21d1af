"""The test suite. Its processes use one BLAS thread each: the xdist workers already take every core,
and OpenBLAS's idle threads spin on them (a quarter of a sample writer's CPU). Set here, before
NumPy is first imported (this package's ``conftest`` imports it), and inherited by every process
the tests start."""

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
