"""A source's groups through ``python -m pipeline.run`` on Beam's DirectRunner (``--beam``), as a
user runs them: the whole command with 1 and then N worker processes (``multi_processing``,
single-threaded, not pinned), its speed-up and its serial start.

Input: the entry's ``beam_input(setup, folder, groups)`` makes, in a fresh folder of the run's
scratch space, an input of ``GROUPS_PER_WORKER`` x N distinct groups, each the size of the setup's
unit, out of the setup's own input by links (no bytes copied), and returns the ``pipeline.run``
arguments that select them; the units' own settings (``UnitSetup.overrides``) follow as ``--set``.

Serial start: what no worker count shortens, the time from the command's start until its first
unit starts work (Beam's and the workers' start-up, listing the units) plus the time after its last
unit ends (finishing the run: manifests, provenance, Beam's shutdown). Measured from the run's own
checkpoints: each unit's (``<output>/units/<source>/*.json``) is written as the unit ends (its
mtime) and records the seconds the unit took from its start (``seconds``), so the first unit
started at min(mtime - seconds) and the last ended at max(mtime), on the same clock as the
command's start and end (``time.time``).
"""

from __future__ import annotations

import dataclasses
import glob
import json
import os
import shutil
import subprocess
import sys
import time

from benchmarks.entry import entry
from benchmarks.processes import single_threaded_env
from pipeline.core.benchmark import UnitSetup

GROUPS_PER_WORKER = 4


@dataclasses.dataclass
class BeamRun:
    """One ``pipeline.run`` command: ``workers`` worker processes, its wall time, its serial start
    (``start_s`` until the first unit started + ``end_s`` after the last one ended) and the units
    it checkpointed."""

    workers: int
    wall_s: float
    start_s: float
    end_s: float
    units: int

    @property
    def serial_s(self) -> float:
        return self.start_s + self.end_s


@dataclasses.dataclass
class BeamRuns:
    """The same ``groups`` groups run by 1 worker (``one``) and by N (``many``)."""

    groups: int
    one: BeamRun
    many: BeamRun


def beam_scaling(setup: UnitSetup, workers: int, scratch: str) -> BeamRuns:
    """``GROUPS_PER_WORKER`` x ``workers`` groups of ``setup``'s source (the entry's
    ``beam_input``, made under ``scratch``) through ``pipeline.run``, with 1 and then ``workers``
    worker processes."""
    groups = GROUPS_PER_WORKER * workers
    folder = os.path.join(scratch, "beam_input")
    os.makedirs(folder)
    arguments = entry(setup.source).beam_input(setup, folder, groups)
    arguments += [word for setting in setup.overrides for word in ("--set", setting)]
    one, many = (
        beam_run(setup.source, arguments, count, os.path.join(scratch, f"beam_w{count}"), groups)
        for count in (1, workers)
    )
    return BeamRuns(groups, one, many)


def beam_run(source: str, arguments: list[str], workers: int, output: str, groups: int) -> BeamRun:
    """``python -m pipeline.run --source source *arguments`` into ``output`` with ``workers``
    worker processes, timed, its output removed once read (full-size clips weigh gigabytes);
    RuntimeError with the end of what it printed when it fails."""
    command = [sys.executable, "-m", "pipeline.run", "--source", source, *arguments]
    command += ["--output", output, "--overwrite", "--runner", "DirectRunner"]
    command += ["--direct_running_mode=multi_processing", f"--direct_num_workers={workers}"]
    print(
        f"running {groups} groups through Beam's DirectRunner (python -m pipeline.run), {workers} worker "
        "process(es) ...",
        flush=True,
    )
    started = time.time()
    done = subprocess.run(command, env=single_threaded_env(), capture_output=True, text=True)
    ended = time.time()
    if done.returncode:
        raise RuntimeError(
            f"{' '.join(command)} exited with {done.returncode}:\n{(done.stdout + done.stderr)[-3000:]}"
        )
    first, last, units = unit_span(output, source)
    shutil.rmtree(output)
    return BeamRun(workers, ended - started, first - started, ended - last, units)


def unit_span(output: str, source: str) -> tuple[float, float, int]:
    """(when the first unit started, when the last one ended, units) of a run's checkpoints under
    ``output`` (``time.time`` seconds): each checkpoint's mtime less the seconds it records, and its
    mtime."""
    starts, ends = [], []
    for path in glob.glob(os.path.join(output, "units", source, "*.json")):
        with open(path) as handle:
            seconds = json.load(handle)["seconds"]
        ends.append(os.stat(path).st_mtime)
        starts.append(ends[-1] - seconds)
    if not ends:
        raise RuntimeError(f"{output}: no unit checkpoint in units/{source}/")
    return min(starts), max(ends), len(ends)
