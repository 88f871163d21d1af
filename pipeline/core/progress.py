"""Progress lines on stderr, from whichever process runs a step."""

from __future__ import annotations

import sys
import time


def progress(message: str) -> None:
    """One timestamped line on stderr (Beam's worker log forwarding would hide logging records on
    some runners)."""
    print(f"{time.strftime('%H:%M:%S')} {message}", file=sys.stderr, flush=True)
