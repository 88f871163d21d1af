"""Run ``python -m pipeline.run`` in a subprocess, as a user would."""

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
