"""Run ``python -m pipeline.run`` in a subprocess, as a user would, and read what it wrote."""

from __future__ import annotations

import os
import subprocess
import sys

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def run_pipeline(source: str, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "pipeline.run", "--source", source, *args],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=600,
    )


def clip_bytes(out: str, source: str) -> dict[str, bytes]:
    """clip file name -> bytes, for every clip of ``source`` in the output folder ``out``."""
    folder = os.path.join(out, source)
    return {
        name: open(os.path.join(folder, name), "rb").read()
        for name in sorted(os.listdir(folder))
        if name.endswith(".npz")
    }
