"""What a worker says while it runs: nothing, unless the run asked for ``--verbose``; and the notes it
leaves for the user.

The main process reports every unit as its checkpoint appears (``pipeline/runner/monitor.py``), on
every runner; a worker's own lines (``progress``) and Beam's log records are for ``--verbose`` runs only. The
setting travels to worker processes in the environment (``VERBOSE_ENV``); the worker processes the
DirectRunner starts inherit a silenced stderr (``workers_silenced``). A note (``note``: what the run
could not do as asked, such as a server that ignores Range requests) is taken by the unit that made
it (``take_notes``), travels in its checkpoint, and the main process prints each once.
"""

from __future__ import annotations

import contextlib
import logging
import os
import sys
import time
from collections.abc import Iterator
from typing import TextIO

VERBOSE_ENV = "TAPVID3D_VERBOSE"
# Loggers that speak on a worker: Beam's own, and the GCP client's import warning.
NOISY_LOGGERS = ("apache_beam", "root", "apitools", "google", "urllib3", "distributed", "numba")


# The notes this process made since the last unit took them, in order, each once.
_notes: dict[str, None] = {}


def note(text: str) -> None:
    """Leave ``text`` (one line) for the user: the unit being annotated takes it (``take_notes``)."""
    _notes[text] = None


def take_notes() -> tuple[str, ...]:
    """The notes made since the last call, in order; forgotten here."""
    taken = tuple(_notes)
    _notes.clear()
    return taken


def verbose() -> bool:
    return os.environ.get(VERBOSE_ENV) == "1"


def set_verbose(on: bool) -> None:
    """Make this process, and the worker processes it starts, verbose or quiet."""
    os.environ[VERBOSE_ENV] = "1" if on else "0"


def progress(message: str) -> None:
    """One timestamped line on stderr, in a ``--verbose`` run only."""
    if verbose():
        print(f"{time.strftime('%H:%M:%S')} {message}", file=sys.stderr, flush=True)


def quiet_worker_logs() -> None:
    """Beam's and its clients' loggers at WARNING (INFO with ``--verbose``) in this process."""
    level = logging.INFO if verbose() else logging.WARNING
    for name in NOISY_LOGGERS:
        logging.getLogger(name).setLevel(level)


@contextlib.contextmanager
def workers_silenced() -> Iterator[TextIO]:
    """For the ``with`` block, file descriptor 2 goes to /dev/null (unless ``--verbose``): worker
    processes started meanwhile inherit it, so Beam's harness lines and a worker's log stay out of
    the user's terminal. Yields the stream the main process reports on: the real stderr."""
    if verbose() or not _has_descriptor(sys.stderr):
        yield sys.stderr
        return
    sys.stderr.flush()
    saved = os.dup(2)
    devnull = os.open(os.devnull, os.O_WRONLY)
    report = os.fdopen(os.dup(saved), "w", buffering=1)
    os.dup2(devnull, 2)
    os.close(devnull)
    try:
        yield report
    finally:
        with contextlib.suppress(OSError, ValueError):
            report.flush()
        sys.stderr.flush()
        os.dup2(saved, 2)
        os.close(saved)
        with contextlib.suppress(OSError, ValueError):
            report.close()


def _has_descriptor(stream) -> bool:
    try:
        stream.fileno()
    except (AttributeError, OSError, ValueError):
        return False
    return True
