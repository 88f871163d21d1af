"""Arrays handed to numba kernels in one type whoever calls them.

Numba compiles a kernel once per type of its arguments, and a read-only array is a type apart from
a writable one: a clip's arrays read from a file are read-only, others are not, so a kernel called
with both would be compiled (and cached) twice, seconds each on a first run.
"""

from __future__ import annotations

import numpy as np


def read_only(array: np.ndarray) -> np.ndarray:
    """A read-only, C-contiguous view of ``array`` (a read-only copy where it is not contiguous)."""
    view = np.ascontiguousarray(array).view()
    view.flags.writeable = False
    return view
