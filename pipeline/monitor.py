"""The main process's view of a running pipeline: one line per unit as its record appears.

Workers write each unit's record when it is done (``pipeline/unit.py``); the monitor polls the
records folder from a thread of the main process, so it reports the same on every runner and any
number of worker processes. On a terminal it draws a live tqdm bar and writes the unit lines above
it; piped, it prints plain lines, each with the count done, the elapsed time and an estimate of
what is left. A closed output (``| head``) sets ``OUTPUT_CLOSED`` and stops the main thread with
KeyboardInterrupt (``_thread.interrupt_main``) so the run ends promptly instead of running on.
"""

from __future__ import annotations

import _thread
import os
import select
import stat
import sys
import threading
import time

from apache_beam.io.filesystems import FileSystems
from tqdm import tqdm

from pipeline.core.outcomes import UnitOutcome
from pipeline.export.layout import unit_record_path
from pipeline.resume import outcome_of, read_unit_record

# Set when a report could not be written because the reader went away (a closed pipe).
OUTPUT_CLOSED = threading.Event()


def watch_output_pipes(interval_s: float = 0.5) -> None:
    """From a daemon thread, stop the main thread (KeyboardInterrupt, with ``OUTPUT_CLOSED`` set) as
    soon as the reader of the command's stdout or stderr pipe goes away (``| head``), even while
    nothing is being printed (Linux reports a pipe whose reader closed as POLLERR on its write end)."""
    pipes = [fd for fd in (1, 2) if _is_pipe(fd)]
    if not pipes:
        return
    poller = select.poll()
    for fd in pipes:
        poller.register(fd, select.POLLERR | select.POLLHUP)

    def watch() -> None:
        while not poller.poll(interval_s * 1000):
            pass
        OUTPUT_CLOSED.set()
        _thread.interrupt_main()

    threading.Thread(target=watch, name="output-watch", daemon=True).start()


def _is_pipe(fd: int) -> bool:
    try:
        return stat.S_ISFIFO(os.fstat(fd).st_mode)
    except OSError:
        return False


def clock(seconds: float) -> str:
    """``seconds`` as h:mm:ss (or m:ss)."""
    minutes, secs = divmod(int(round(seconds)), 60)
    hours, minutes = divmod(minutes, 60)
    return f"{hours}:{minutes:02d}:{secs:02d}" if hours else f"{minutes}:{secs:02d}"


def describe(outcome: UnitOutcome) -> str:
    """What became of a unit, in a few words."""
    if outcome.resumed:
        return f"unit {outcome.name}: finished by an earlier run with these settings; skipped"
    if outcome.failed:
        first = outcome.failures[0]
        more = f" (and {len(outcome.failures) - 1} more)" if len(outcome.failures) > 1 else ""
        return f"unit {outcome.name} FAILED: {first.error}{more}"
    return (
        f"unit {outcome.name}: {outcome.clips_written} of {len(outcome.reports)} clip(s) written, "
        f"{outcome.tracks_written} tracks ({outcome.seconds:.1f} s)"
    )


class RunMonitor:
    """Reports the units of a run (``names``) as their records, stamped with ``run_id``, appear."""

    def __init__(self, output: str, source: str, names: list[str], run_id: str, started: float, stream=None):
        self.output, self.source, self.run_id, self.started = output, source, run_id, started
        self.stream = stream if stream is not None else sys.stderr
        self.paths = {unit_record_path(output, source, name): name for name in names}
        self.pattern = f"{output}/units/{source}/*.json"
        self.seen: dict[str, float] = {}
        self.done: dict[str, UnitOutcome] = {}
        self.closed = False
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        interactive = getattr(self.stream, "isatty", lambda: False)()
        self.bar = (
            tqdm(total=len(names), file=self.stream, unit="unit", dynamic_ncols=True) if interactive else None
        )

    def __enter__(self) -> RunMonitor:
        self._thread = threading.Thread(target=self._watch, name="run-monitor", daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        if not self.closed:
            self.poll()  # the units finished since the last look
        if self.bar is not None:
            self.bar.close()

    def _watch(self) -> None:
        interval = 0.5 if "://" not in self.output else 5.0  # an object store is listed less often
        while not self._stop.wait(interval):
            self.poll()
            if self.closed:
                _thread.interrupt_main()
                return

    def poll(self) -> None:
        """Report each unit whose record of this run appeared or changed since the last look."""
        for match in FileSystems.match([self.pattern])[0].metadata_list:
            name = self.paths.get(match.path)
            if (
                name is None
                or name in self.done
                or self.seen.get(match.path) == match.last_updated_in_seconds
            ):
                continue
            self.seen[match.path] = match.last_updated_in_seconds
            record = read_unit_record(self.output, self.source, name)
            if record is not None and record["run"] == self.run_id:
                self.done[name] = outcome_of(record)
                self._say(self.done[name])

    def _say(self, outcome: UnitOutcome) -> None:
        if self.closed:
            return
        try:
            if self.bar is not None:
                self.bar.write(describe(outcome), file=self.stream)
                self.bar.update(1)
            else:
                print(
                    f"[{len(self.done)}/{len(self.paths)}] {describe(outcome)}; {self.timing()}",
                    file=self.stream,
                    flush=True,
                )
        except (BrokenPipeError, ValueError):  # ValueError: the stream was closed
            self.closed = True
            OUTPUT_CLOSED.set()

    def timing(self) -> str:
        """Elapsed time and, from the units annotated so far (resumed ones cost nothing), an estimate
        of what is left."""
        elapsed = time.monotonic() - self.started
        made = [outcome for outcome in self.done.values() if not outcome.resumed]
        left = len(self.paths) - len(self.done)
        if not made or not left:
            return f"elapsed {clock(elapsed)}"
        return f"elapsed {clock(elapsed)}, about {clock(elapsed / len(made) * left)} left"
