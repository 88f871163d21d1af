"""How every ``python -m pipeline...`` command ends when its output goes away (``| head``), Ctrl-C or
SIGTERM stops it: quietly, with the shell's statuses (141 for a closed output, 130 for Ctrl-C, 143
for SIGTERM), no traceback. SIGTERM (a cluster's scheduler, ``kill``, a container stopping) stops the
command as Ctrl-C does: a KeyboardInterrupt in the main thread, so every clean-up that Ctrl-C runs
(temporaries, a download's scratch folder) runs; ``TERMINATED`` says which of the two it was.

Python ignores SIGPIPE, so a write to a pipe whose reader exited raises BrokenPipeError, perhaps
only at the interpreter's last flush; and a command printing nothing for a while (a long run) would
not notice at all. ``run_command`` covers both: a watcher thread (``watch_output_pipes``) stops the
main thread as soon as the reader of stdout or stderr goes away, and a BrokenPipeError anywhere,
the last flush included, ends the command with 141, its streams pointed at /dev/null.
"""

from __future__ import annotations

import _thread
import contextlib
import os
import select
import signal
import stat
import sys
import threading
from collections.abc import Callable
from typing import NoReturn

# Statuses a command ends with at once (its other threads left as they are): Ctrl-C, a closed
# output, and a run that stopped itself (``pipeline.run``: units failing alike).
STOPPED, INTERRUPTED, OUTPUT_CLOSED, SIGTERM_STATUS = 4, 130, 141, 143
# Set once SIGTERM arrived: the KeyboardInterrupt that stops the command is its, not a Ctrl-C's.
TERMINATED = threading.Event()
# Set once the reader of the command's stdout or stderr is gone (a closed pipe).
READER_GONE = threading.Event()
# Set (under the lock) once the command has ended: the watcher then leaves the main thread alone.
_FINISHED = threading.Event()
_FINISHING = threading.Lock()


def watch_output_pipes(interval_s: float = 0.5) -> None:
    """From a daemon thread, stop the main thread (KeyboardInterrupt, with ``READER_GONE`` set) as
    soon as the reader of the command's stdout or stderr pipe goes away, even while nothing is being
    printed (Linux reports a pipe whose reader closed as POLLERR on its write end)."""
    pipes = [fd for fd in (1, 2) if _is_pipe(fd)]
    if not pipes:
        return
    poller = select.poll()
    for fd in pipes:
        poller.register(fd, select.POLLERR | select.POLLHUP)

    def watch() -> None:
        while not poller.poll(interval_s * 1000):
            pass
        READER_GONE.set()
        with _FINISHING:
            if not _FINISHED.is_set():
                _thread.interrupt_main()

    threading.Thread(target=watch, name="output-watch", daemon=True).start()


def _is_pipe(fd: int) -> bool:
    try:
        return stat.S_ISFIFO(os.fstat(fd).st_mode)
    except OSError:
        return False


def silence_output() -> None:
    """Point stdout and stderr at /dev/null: their reader is gone, and a late flush must not fail."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    for stream in (sys.stdout, sys.stderr):
        try:
            os.dup2(devnull, stream.fileno())
        except (OSError, ValueError, AttributeError):
            continue
    os.close(devnull)


def _flush() -> None:
    for stream in (sys.stdout, sys.stderr):
        stream.flush()


def stop_on_sigterm() -> None:
    """From now on, SIGTERM stops the main thread as Ctrl-C does (``TERMINATED`` set)."""

    def terminate(signum, frame) -> None:
        TERMINATED.set()
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, terminate)


def interrupted_status() -> tuple[int, str]:
    """The status and the word for a command stopped by a KeyboardInterrupt: 143 ``terminated`` after
    SIGTERM, else 130 ``interrupted`` (Ctrl-C)."""
    return (SIGTERM_STATUS, "terminated") if TERMINATED.is_set() else (INTERRUPTED, "interrupted")


def _ending(main: Callable[[], int]) -> int:
    """``main()``'s status, flushed; 141 for a closed output, 130 for Ctrl-C, 143 for SIGTERM."""
    try:
        watch_output_pipes()
        stop_on_sigterm()
        status = main()
        _flush()
        return status
    except BrokenPipeError:
        return OUTPUT_CLOSED
    except KeyboardInterrupt:
        if READER_GONE.is_set():
            return OUTPUT_CLOSED
        status, word = interrupted_status()
        with contextlib.suppress(OSError):
            print(word, file=sys.stderr)
        return status


def run_command(main: Callable[[], int], stop: Callable[[], None] | None = None) -> NoReturn:
    """``sys.exit(main())`` for a command: a closed output ends it with 141, Ctrl-C with 130 and
    SIGTERM with 143 (one line on stderr), without a traceback. ``stop`` runs before such an exit
    (``pipeline.run`` kills its worker processes), which then happens at once, without waiting for
    other threads."""
    try:
        status = _ending(main)
        with _FINISHING:
            _FINISHED.set()
    except KeyboardInterrupt:  # the watcher's, sent while the command was ending
        status = OUTPUT_CLOSED
        _FINISHED.set()
    if status not in (STOPPED, INTERRUPTED, OUTPUT_CLOSED, SIGTERM_STATUS):
        sys.exit(status)
    if status == OUTPUT_CLOSED or READER_GONE.is_set():
        silence_output()
    with contextlib.suppress(OSError, ValueError):
        _flush()
    if stop is not None:
        stop()
    os._exit(status)
