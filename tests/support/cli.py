"""Run ``python -m pipeline.run`` as a user would, and read what it wrote.

``run_pipeline`` starts the command in a subprocess: one end-to-end test per CLI, and tests about
the process itself (signals, resource limits, environment, what a new interpreter prints).
``run_in_process`` calls the same ``main`` in this process with stdout and stderr captured, where
the process boundary is not what a test is about: it saves the interpreter start and imports of
every run; ``command_in_process`` does the same for any command (``python -m <name>``).
"""

from __future__ import annotations

import contextlib
import importlib
import io
import logging
import os
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable

REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


RUN_TIMEOUT_S = 600


def pipeline_command(source: str, *args: str) -> list[str]:
    """The command line of ``python -m pipeline.run --source <source> <args>`` in this interpreter."""
    return [sys.executable, "-m", "pipeline.run", "--source", source, *args]


def run_pipeline(source: str, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        pipeline_command(source, *args), cwd=REPO, capture_output=True, text=True, timeout=RUN_TIMEOUT_S
    )


def run_pipeline_timed(source: str, *args: str) -> tuple[subprocess.CompletedProcess, float]:
    """``run_pipeline``, and the seconds from its launch until its stdout's last line arrived (the
    command's own end, before the interpreter's shutdown; the whole wall when it printed nothing)."""
    started = time.monotonic()
    with tempfile.TemporaryFile("w+") as errors:
        process = subprocess.Popen(
            pipeline_command(source, *args), cwd=REPO, stdout=subprocess.PIPE, stderr=errors, text=True
        )
        watchdog = threading.Timer(RUN_TIMEOUT_S, process.kill)
        watchdog.start()
        lines, last = [], None
        try:
            assert process.stdout is not None
            for line in process.stdout:
                lines.append(line)
                last = time.monotonic() - started
            code = process.wait()
        finally:
            watchdog.cancel()
        errors.seek(0)
        completed = subprocess.CompletedProcess(process.args, code, "".join(lines), errors.read())
    return completed, time.monotonic() - started if last is None else last


def run_in_process(source: str, *args: str) -> subprocess.CompletedProcess:
    """``run_pipeline`` without the subprocess: the same exit code, stdout and stderr."""
    from pipeline.runner.command import main as run_main

    return call_main(run_main, ["--source", source, *args])


# python -m <name> -> the module whose main(argv) it runs (benchmarks/__main__.py calls benchmarks.cli's)
MAIN_MODULES = {
    "pipeline.run": "pipeline.runner.command",
    "pipeline.audit": "pipeline.audit.__main__",
    "pipeline.viz": "pipeline.viz.__main__",
    "benchmarks": "benchmarks.cli",
}


def command_in_process(name: str, *args: str) -> subprocess.CompletedProcess:
    """``python -m <name> <args>`` as its ``main(argv)`` in this process, with stdout and stderr
    captured: the same exit status and output, save what only a new interpreter shows (its
    imports' output; the tests that start one check that)."""
    return call_main(importlib.import_module(MAIN_MODULES.get(name, name)).main, list(args))


def call_main(main: Callable[[list[str]], int], argv: list[str]) -> subprocess.CompletedProcess:
    """``main(argv)`` with stdout and stderr captured, its SystemExit an exit status as Python gives
    it; the root logger without handlers meanwhile, as in a new interpreter (a warning logged before
    the command sets up its logging goes to stderr)."""
    out, err = io.StringIO(), io.StringIO()
    root = logging.getLogger()
    handlers = root.handlers[:]
    root.handlers.clear()
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                code = main(argv)
            except SystemExit as stop:
                if stop.code is None or isinstance(stop.code, int):
                    code = stop.code or 0
                else:  # a message: Python prints it and exits with 1
                    print(stop.code, file=sys.stderr)
                    code = 1
    finally:
        root.handlers[:] = handlers
    return subprocess.CompletedProcess(argv, code, out.getvalue(), err.getvalue())


def clip_bytes(out: str, source: str) -> dict[str, bytes]:
    """clip file name -> bytes, for every clip of ``source`` in the output folder ``out``."""
    folder = os.path.join(out, source)
    return {
        name: open(os.path.join(folder, name), "rb").read()
        for name in sorted(os.listdir(folder))
        if name.endswith(".npz")
    }
