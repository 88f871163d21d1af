"""Write a sample input once into a folder, atomically, and reuse it on later runs."""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Callable


def write_once(folder: str, version: str, write: Callable[[str], object]) -> str:
    """Call ``write(staging)`` in a hidden folder beside ``folder``, then rename it into place.

    A folder already marked complete for ``version`` is reused as it is; an interrupted write
    never leaves a half-written ``folder`` (its staging folder is removed on errors). Writers
    racing on the same ``folder`` (two processes) each write their own staging folder; the
    first rename wins and the others reuse the winner's folder (renaming onto a non-empty
    folder fails), so a complete ``folder`` is never deleted nor written into. Only a folder
    that is not complete for ``version`` (an older version) is moved aside and replaced.
    """
    marker = os.path.join(folder, f".complete-v{version}")
    if os.path.exists(marker):
        return folder
    parent = os.path.dirname(os.path.abspath(folder))
    os.makedirs(parent, exist_ok=True)
    staging = tempfile.mkdtemp(prefix=".sample-", dir=parent)
    try:
        write(staging)
        open(os.path.join(staging, f".complete-v{version}"), "w").close()
        if os.path.exists(folder) and not os.path.exists(marker):
            _discard(folder, parent)
        try:
            os.rename(staging, folder)
        except OSError:
            if not os.path.exists(marker):
                raise
            # Another writer finished first: its folder is complete, and ours is dropped.
    finally:
        if os.path.exists(staging):
            shutil.rmtree(staging, ignore_errors=True)
    return folder


def _discard(folder: str, parent: str) -> None:
    """Move an incomplete or older ``folder`` aside in one rename, then delete it."""
    aside = tempfile.mkdtemp(prefix=".stale-", dir=parent)
    try:
        os.rename(folder, os.path.join(aside, "old"))
    except FileNotFoundError:
        pass  # another writer moved it already
    finally:
        shutil.rmtree(aside, ignore_errors=True)
