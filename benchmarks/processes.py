"""Running benchmark units, each in a fresh ``python -m benchmarks.worker`` process: single-threaded
(``THREAD_ENV``: numba, OpenMP, BLAS, Arrow and OpenCV pools at one thread) and bound to one CPU of
its own (unless ``pin`` is off), so that one worker is one core and the 1-vs-N-worker comparison is
fair. The parent reaps each process with ``os.wait4`` for its CPU time; its peak resident memory is
the process's own high-water mark (``VmHWM``, read by the worker at its end; see ``peak_rss``)."""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
import tempfile
import time

# One thread per worker process: numba (pstudio's renderer), OpenMP (numba's omp layer, open3d),
# BLAS, Arrow's CPU pool (it reads OMP_NUM_THREADS) and OpenCV's pool.
THREAD_ENV = {
    "NUMBA_NUM_THREADS": "1",
    "OMP_NUM_THREADS": "1",
    "OPENBLAS_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
    "VECLIB_MAXIMUM_THREADS": "1",
    "NUMEXPR_NUM_THREADS": "1",
    "OPENCV_FOR_THREADS_NUM": "1",
}
# The folder holding the ``benchmarks`` package, so that the worker imports it from any cwd.
_ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def single_threaded_env() -> dict[str, str]:
    """This process's environment with ``THREAD_ENV`` and ``benchmarks`` importable."""
    path = os.pathsep.join(p for p in (_ROOT, os.environ.get("PYTHONPATH")) if p)
    return dict(os.environ, **THREAD_ENV, PYTHONPATH=path)


def peak_rss() -> int | None:
    """This process's own peak resident memory in bytes (VmHWM: the high-water mark of its
    address space since exec), or None off Linux.

    Not ``ru_maxrss``: on Linux a child's ru_maxrss (RUSAGE_SELF in it, or RUSAGE_CHILDREN /
    wait4 in its parent) starts from its parent's high-water mark, which exec carries over, so a
    parent that once held gigabytes (e.g. after writing the inputs) inflates every child's figure."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return None


@dataclasses.dataclass
class UnitRun:
    result: dict  # what the worker returned (``benchmarks.worker.run``)
    wall_s: float  # the whole process: interpreter start, imports, work
    cpu_s: float  # user + system CPU of the whole process
    max_rss: int  # bytes: the process's own peak resident memory


def _spawn(spec: dict, workdir: str) -> tuple[subprocess.Popen, str]:
    handle, result_path = tempfile.mkstemp(prefix="unit-", suffix=".json", dir=workdir)
    os.close(handle)
    log = open(result_path[: -len(".json")] + ".log", "w")
    command = [sys.executable, "-m", "benchmarks.worker", json.dumps(spec), result_path]
    process = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT, env=single_threaded_env())
    log.close()
    return process, result_path


def run_processes(
    specs: list[dict], workers: int, workdir: str, pin: bool = True
) -> tuple[list[UnitRun], float]:
    """Run one fresh process per spec, at most ``workers`` at a time; returns each process's
    figures (in spec order) and the wall time of the whole set. With ``pin`` (and enough CPUs),
    each running process is bound to a CPU of its own (``sched_setaffinity``), so a library that
    starts threads anyway (projectaria-tools' re-rendering does) cannot use more than one core."""
    pending = list(enumerate(specs))
    running: dict[int, tuple[int, subprocess.Popen, str, float, int | None]] = {}
    runs: list[UnitRun | None] = [None] * len(specs)
    cpus = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else []
    free = cpus[:workers] if pin and len(cpus) >= workers else [None] * workers
    started = time.perf_counter()
    while pending or running:
        while pending and len(running) < workers:
            index, spec = pending.pop(0)
            cpu = free.pop(0)
            process, path = _spawn(dict(spec, cpu=cpu), workdir)
            running[process.pid] = (index, process, path, time.perf_counter(), cpu)
        pid, status, usage = os.wait4(-1, 0)
        if pid not in running:
            continue
        index, process, path, begun, cpu = running.pop(pid)
        free.append(cpu)
        process.returncode = os.waitstatus_to_exitcode(status)
        log_path = path[: -len(".json")] + ".log"
        if process.returncode != 0:
            for _, other, *_ in running.values():  # stop the other units this call started
                other.kill()
                other.wait()
            with open(log_path) as f:
                tail = f.read()[-3000:]
            raise RuntimeError(f"benchmark unit process failed (exit {process.returncode}):\n{tail}")
        with open(path) as f:
            result = json.load(f)
        os.remove(path)
        os.remove(log_path)
        peak = result.get("peak_rss") or usage.ru_maxrss * 1024  # see peak_rss()
        runs[index] = UnitRun(result, time.perf_counter() - begun, usage.ru_utime + usage.ru_stime, peak)
    return runs, time.perf_counter() - started
