"""Run ``python -m pipeline.run`` as a user would, and read what it wrote.

``run_pipeline`` starts the command in a subprocess: one end-to-end test per CLI, and tests about
the process itself (signals, resource limits, environment). ``run_in_process`` calls the same
``main`` in this process with stdout and stderr captured, where the process boundary is not
what a test is about: it saves the interpreter start and imports of every run.
"""

from __future__ import annotations

import contextlib
import io
import os
import subprocess
import sys

from pipeline.runner.command import main as run_main

REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def run_pipeline(source: str, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "pipeline.run", "--source", source, *args],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=600,
    )


def run_in_process(source: str, *args: str) -> subprocess.CompletedProcess:
    """``run_pipeline`` without the subprocess: the same exit code, stdout and stderr."""
    command = ["--source", source, *args]
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = run_main(command)
        except SystemExit as stop:
            code = stop.code if isinstance(stop.code, int) else 2
    return subprocess.CompletedProcess(command, code, out.getvalue(), err.getvalue())


def clip_bytes(out: str, source: str) -> dict[str, bytes]:
    """clip file name -> bytes, for every clip of ``source`` in the output folder ``out``."""
    folder = os.path.join(out, source)
    return {
        name: open(os.path.join(folder, name), "rb").read()
        for name in sorted(os.listdir(folder))
        if name.endswith(".npz")
    }
