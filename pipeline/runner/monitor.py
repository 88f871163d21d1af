"""The main process's view of a running pipeline: one line per unit as its checkpoint appears.

Workers write each unit's record when it is done (``pipeline/runner/stages.py``); the monitor polls the
records folder from a thread of the main process, so it reports the same on every runner and any
number of worker processes. The unit lines are the run's account and go to stdout, each with the
count done, the elapsed time and an estimate of what is left; when stderr is a terminal a live tqdm
bar is drawn there too (then a unit line shown on the same terminal leaves the counting to the bar).
A closed output (``| head``) sets ``pipes.READER_GONE`` and stops the main thread with
KeyboardInterrupt (``_thread.interrupt_main``) so the run ends promptly instead of running on; so
do ``max_failures_in_a_row`` units in a row failing with one cause (``gave_up`` then says why).
"""

from __future__ import annotations

import _thread
import contextlib
import sys
import threading
import time

from apache_beam.io.filesystems import FileSystems
from tqdm import tqdm

from pipeline.core.outcomes import FailureStreak, UnitOutcome
from pipeline.export.layout import checkpoint_path
from pipeline.pipes import READER_GONE
from pipeline.runner.ledger import UnitLedger


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
    """Reports the units of a run (``names``) as their checkpoints, stamped with the ledger's run, appear: a
    line each on ``lines`` (default stdout), a live bar on ``bar_stream`` when it is a terminal, and
    each note a unit brings (``UnitOutcome.notes``) once, on ``bar_stream``.
    Once ``max_failures_in_a_row`` units in a row (0: no limit) failed with one cause
    (``failure_cause``), ``gave_up`` says so and the main thread is stopped."""

    def __init__(
        self,
        ledger: UnitLedger,
        names: list[str],
        started: float,
        bar_stream=None,
        lines=None,
        max_failures_in_a_row: int = 0,
    ):
        self.ledger, self.started = ledger, started
        self.lines = lines if lines is not None else sys.stdout
        bar_stream = bar_stream if bar_stream is not None else sys.stderr
        self.paths = {checkpoint_path(ledger.output, ledger.source, name): name for name in names}
        self.pattern = f"{ledger.output}/units/{ledger.source}/*.json"
        self.seen: dict[str, float] = {}
        self.done: dict[str, UnitOutcome] = {}
        self.closed = False
        self.streak = FailureStreak(max_failures_in_a_row, "units")
        self.notes: dict[str, None] = {}
        self._notes_stream = bar_stream
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.bar = (
            tqdm(total=len(names), file=bar_stream, unit="unit", dynamic_ncols=True)
            if _is_terminal(bar_stream)
            else None
        )
        # A line shown on the bar's terminal leaves the counting to the bar.
        self.counted = self.bar is None or not _is_terminal(self.lines)

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
        interval = 0.5 if "://" not in self.ledger.output else 5.0  # an object store is listed less often
        while not self._stop.wait(interval):
            self.poll()
            if self.closed or self.gave_up:
                _thread.interrupt_main()
                return

    def poll(self) -> None:
        """Report each unit whose checkpoint of this run appeared or changed since the last look."""
        for match in FileSystems.match([self.pattern])[0].metadata_list:
            name = self.paths.get(match.path)
            if (
                name is None
                or name in self.done
                or self.seen.get(match.path) == match.last_updated_in_seconds
            ):
                continue
            self.seen[match.path] = match.last_updated_in_seconds
            found = self.ledger.read(name)
            if found is not None and found.run == self.ledger.run:
                self.done[name] = found.outcome
                self._note(found.outcome)
                self._say(self.done[name])
                self._count(self.done[name])

    def _count(self, outcome: UnitOutcome) -> None:
        """Follow the units failing alike in a row; give up at the limit."""
        if outcome.failed:
            self.streak.failed(outcome.failures[0].error)
        elif not outcome.resumed:
            self.streak.succeeded()

    @property
    def gave_up(self) -> str:
        """Why the run gives up (units failing alike in a row), "" while it does not."""
        return self.streak.gave_up

    def _note(self, outcome: UnitOutcome) -> None:
        for text in outcome.notes:
            if text not in self.notes and not self.closed:
                self.notes[text] = None
                with contextlib.suppress(BrokenPipeError, ValueError):
                    print(f"note: {text}", file=self._notes_stream, flush=True)

    def _say(self, outcome: UnitOutcome) -> None:
        if self.closed:
            return
        line = describe(outcome)
        if self.counted:
            line = f"[{len(self.done)}/{len(self.paths)}] {line}; {self.timing()}"
        try:
            if self.bar is not None:
                self.bar.clear()  # the line takes the bar's place on a shared terminal
            print(line, file=self.lines, flush=True)
            if self.bar is not None:
                self.bar.update(1)
                self.bar.refresh()
        except (BrokenPipeError, ValueError):  # ValueError: the stream was closed
            self.closed = True
            READER_GONE.set()

    def timing(self) -> str:
        """Elapsed time and, from the units annotated so far (resumed ones cost nothing), an estimate
        of what is left."""
        elapsed = time.monotonic() - self.started
        made = [outcome for outcome in self.done.values() if not outcome.resumed]
        left = len(self.paths) - len(self.done)
        if not made or not left:
            return f"elapsed {clock(elapsed)}"
        return f"elapsed {clock(elapsed)}, about {clock(elapsed / len(made) * left)} left"


def _is_terminal(stream) -> bool:
    return getattr(stream, "isatty", lambda: False)()
