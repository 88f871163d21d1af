"""Shared fixtures: the sample driving and studio worlds, written once into a versioned cache
beside the repository and reused by every later session.

The cache is ``<repo>/.cache/samples/<name>-<version>`` (or ``$TAPVID3D_SAMPLE_CACHE/<name>-<version>``);
``<version>`` hashes the generators' source (every module of a ``pipeline/<source>/sample/``), the versions of
the libraries that encode and ray cast the files, and ``CACHE_LAYOUT``, so editing a generator or
upgrading them writes a new folder. Each folder is written by ``write_once`` (a hidden staging
folder renamed into place) under a file lock, so racing sessions write it once and never see it
half-written. The cached folders are shared: tests read them, and copy them before changing
anything (``split_copy``, ``pstudio_links``). ``rm -rf .cache/samples`` drops old versions.
"""

from __future__ import annotations

import collections
import fcntl
import functools
import hashlib
import importlib
import importlib.metadata
import json
import os
import pathlib
import shutil
import subprocess
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np
import pytest

from pipeline.io.write_once import write_once
from tests.support.cli import REPO, run_in_process, run_pipeline_timed

if TYPE_CHECKING:
    from pipeline.drivetrack.sample.driving_world import DrivingWorld
    from pipeline.pstudio.sample.studio_world import StudioWorld

# The sample writers and the libraries they use are imported when a fixture first writes or reads a
# sample, not here: pytest's main process imports this file before it starts the workers.
SAMPLE_CACHE = os.environ.get("TAPVID3D_SAMPLE_CACHE") or os.path.join(REPO, ".cache", "samples")
CACHE_LAYOUT = "1"  # bump when what the fixtures below keep in a cache folder changes
# The module whose SAMPLE_VERSION a run without --input marks its written sample world with, per source.
SAMPLE_WRITERS = {
    "drivetrack": "pipeline.drivetrack.sample.waymo_world",
    "pstudio": "pipeline.pstudio.sample.dynamic3dgs_files",
}
# The distributions that encode and ray cast the samples' files.
SAMPLE_LIBRARIES = ("numpy", "opencv-python-headless", "open3d", "pyarrow", "scipy", "trimesh")


# The files that take longest (ten seconds and more each, most for few tests), longest first: xdist
# hands out whole files (``--dist loadfile``) in the order of the collection (``--no-loadscope-reorder``),
# so these start early and the workers finish together, on the many short files after them.
LONG_FILES_FIRST = (
    "tests/run/test_command_lines.py",
    "tests/drivetrack/test_bad_input.py",
    "tests/audit/test_page.py",
    "tests/drivetrack/test_truth.py",
    "tests/run/test_closed_output.py",
    "tests/bench/test_toy_bench.py",
    "tests/run/test_dask_runner.py",
    "tests/export/test_shards.py",
    "tests/docs/test_adding_a_source.py",
    "tests/run/test_release.py",
    "tests/io/test_remote_storage.py",
    "tests/adt/test_download_faults.py",
    "tests/run/test_queries_from.py",
    "tests/run/test_resume.py",
    "tests/run/test_bad_output.py",
    "tests/drivetrack/test_refined_visibility.py",
    "tests/audit/test_release_reference.py",
    "tests/export/test_depth_export.py",
    "tests/adt/test_fetched.py",
    "tests/drivetrack/test_camera_model.py",
    "tests/audit/test_sweep.py",
    "tests/drivetrack/test_reanchor.py",
)


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """``LONG_FILES_FIRST`` in its order, then the other files, most tests first (xdist's own order)."""
    missing = [name for name in LONG_FILES_FIRST if not os.path.exists(os.path.join(REPO, name))]
    if missing:
        raise pytest.UsageError(f"LONG_FILES_FIRST names files that do not exist: {', '.join(missing)}")
    counts = collections.Counter(item.nodeid.split("::")[0] for item in items)
    rank = {name: position for position, name in enumerate(LONG_FILES_FIRST)}
    order = {name: (rank.get(name, len(rank)), -counts[name], name) for name in counts}
    items.sort(key=lambda item: order[item.nodeid.split("::")[0]])


def sample_version(sources: tuple[str, ...] = ()) -> str:
    """12 hex digits of sha256 over the generators' source (and ``sources``, more files a sample's
    writer reads), the libraries' versions and the layout."""
    digest = hashlib.sha256(f"layout {CACHE_LAYOUT}\0".encode())
    generators = sorted(pathlib.Path(REPO, "pipeline").glob("*/sample/*.py"))
    for path in generators + [pathlib.Path(source) for source in sources]:
        digest.update(path.name.encode() + b"\0" + path.read_bytes() + b"\0")
    for library in SAMPLE_LIBRARIES:
        digest.update(f"{library} {importlib.metadata.version(library)}\0".encode())
    return digest.hexdigest()[:12]


def cached_sample(name: str, write, sources: tuple[str, ...] = ()) -> str:
    """``<cache>/<name>-<version>``, made by ``write(staging)`` unless a complete one is there;
    ``sources``: files besides the generators whose content the sample depends on."""
    version = sample_version(sources)
    folder = os.path.join(SAMPLE_CACHE, f"{name}-{version}")
    if os.path.exists(os.path.join(folder, f".complete-v{version}")):
        return folder
    os.makedirs(SAMPLE_CACHE, exist_ok=True)
    with open(os.path.join(SAMPLE_CACHE, f".{name}-{version}.lock"), "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # a racing session waits for the writer, then reuses its folder
        return write_once(folder, version, write)


def link_tree(source: str, target: str) -> None:
    """``target``: a copy of the folder ``source`` made of hard links (copies across file systems)."""

    def link(src: str, dst: str) -> None:
        try:
            os.link(src, dst)
        except OSError:
            shutil.copy2(src, dst)

    shutil.copytree(source, target, copy_function=link)


@pytest.fixture(scope="session")
def world() -> DrivingWorld:
    from pipeline.drivetrack.sample.driving_world import DrivingWorld

    return DrivingWorld()


@functools.cache
def driving_sample() -> tuple[str, dict]:
    """``sample_split``'s value, written into the cache on first call in this process. The fixtures
    that run on a sample call these when they run on it, not at their setup, so a worker needing
    only the studio world does not wait while another writes the driving one (half a minute)."""
    from pipeline.drivetrack.sample.driving_world import DrivingWorld
    from pipeline.drivetrack.sample.waymo_world import write_split

    def write(staging: str) -> None:
        generated = write_split(os.path.join(staging, "split"), world=DrivingWorld())
        np.save(os.path.join(staging, "points.npy"), np.stack(generated["points"]))

    folder = cached_sample("waymo", write)
    points = np.load(os.path.join(folder, "points.npy"))
    return os.path.join(folder, "split"), {"points": list(points)}


@functools.cache
def studio_sample() -> tuple[str, StudioWorld]:
    """``pstudio_sample``'s value, written into the cache on first call in this process. The world is
    cheap to build (about 10 ms) and deterministic, so a cache hit returns a fresh one equal to the
    one written."""
    from pipeline.pstudio.sample.dynamic3dgs_files import write_sequence
    from pipeline.pstudio.sample.studio_world import StudioWorld

    studio = StudioWorld()
    folder = cached_sample("pstudio", lambda staging: write_sequence(os.path.join(staging, "root"), studio))
    return os.path.join(folder, "root"), studio


# Source -> its sample's input root, written on first call.
SAMPLE_INPUTS: dict[str, Callable[[], str]] = {
    "drivetrack": lambda: driving_sample()[0],
    "pstudio": lambda: studio_sample()[0],
}


@pytest.fixture(scope="session")
def sample_split():
    """(split folder, generator output) for the one-segment sample world (``world``); the folder is the
    shared cache (never write into it: ``split_copy``), the output ``{"points": [40 x [64, 900, 3]]}``."""
    return driving_sample()


@pytest.fixture(scope="session")
def stress_split():
    """``split(name)``: the split folder of a world of ``tests/support/stress_worlds.py`` (one segment,
    ``stress_worlds.SEGMENT``), written once into the shared cache on first use (never write into
    it)."""
    from tests.support import stress_worlds

    def split(name: str) -> str:
        def write(staging: str) -> None:
            stress_worlds.write_stress_split(os.path.join(staging, "split"), name)

        return os.path.join(cached_sample(f"waymo-stress-{name}", write, (stress_worlds.__file__,)), "split")

    return split


@pytest.fixture(scope="session")
def family_split():
    """``split(seed)``: the split folder of the world of ``tests/support/driving_family.py`` drawn
    from ``seed`` (one segment, ``driving_family.SEGMENT``), written once into the shared cache on
    first use (never write into it)."""
    from tests.support import driving_family

    def split(seed: int) -> str:
        def write(staging: str) -> None:
            driving_family.write_family_split(os.path.join(staging, "split"), seed)

        return os.path.join(cached_sample(f"waymo-family-{seed}", write, (driving_family.__file__,)), "split")

    return split


@pytest.fixture
def split_copy(sample_split, tmp_path):
    """A private copy of the sample split that a test may corrupt."""
    target = tmp_path / "split"
    shutil.copytree(sample_split[0], target)
    return str(target)


@pytest.fixture(scope="session")
def pstudio_sample():
    """(root holding data/ and output/, the StudioWorld) for the one-sequence studio sample; the root
    is the shared cache (never write into it: ``pstudio_links``)."""
    return studio_sample()


@pytest.fixture
def pstudio_links(pstudio_sample, tmp_path):
    """A private copy of the studio sample's root made of hard links: a test may add files and
    replace files (remove, then write), but must never write into a file it did not create."""
    root = str(tmp_path / "root")
    link_tree(pstudio_sample[0], root)
    return root


def shared_folder(factory: pytest.TempPathFactory) -> pathlib.Path:
    """A folder of this pytest run that every xdist worker sees (the workers' basetemps share a
    parent made for the run); without xdist, the run's own basetemp."""
    base = factory.getbasetemp()
    return base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base


class ReferenceRuns:
    """``runs(source)``: the output folder of one plain DirectRunner run on that source's sample
    (drivetrack or pstudio), made on first use by ``python -m pipeline.run`` in a subprocess (the
    CLI's end-to-end run, ``runs.result(source)`` its exit code and output) and shared by every
    test that reads a finished run or compares bytes with one. ``runs.multi_processing(source)``:
    the same run on the DirectRunner's multi_processing mode with 2 workers (its folder and result).
    Each run is made once per pytest run, whichever xdist worker asks first (the others wait for
    it under a file lock, then read its folder and result). Never write into a folder: copy it."""

    MULTI_PROCESSING = ("--direct_running_mode=multi_processing", "--direct_num_workers=2")

    def __init__(self, factory: pytest.TempPathFactory, inputs: dict[str, Callable[[], str]]):
        self._shared, self._inputs = shared_folder(factory), inputs
        self._made: dict[str, tuple[str, subprocess.CompletedProcess]] = {}
        self._walls: dict[str, float] = {}

    def __call__(self, source: str) -> str:
        return self._run(source)[0]

    def result(self, source: str) -> subprocess.CompletedProcess:
        """The ``subprocess.CompletedProcess`` of that run."""
        return self._run(source)[1]

    def multi_processing(self, source: str) -> tuple[str, subprocess.CompletedProcess]:
        """(output folder, completed process) of the run on 2 worker processes."""
        return self._run(source, self.MULTI_PROCESSING, "multi_processing")

    def _run(
        self, source: str, options: tuple[str, ...] = (), mode: str = "direct"
    ) -> tuple[str, subprocess.CompletedProcess]:
        name = f"reference_{mode}_{source}"
        if name not in self._made:
            out, record = self._shared / name, self._shared / f"{name}.json"
            with open(self._shared / f".{name}.lock", "w") as lock:
                fcntl.flock(lock, fcntl.LOCK_EX)  # another worker making it: wait, then read it
                if not record.exists():
                    shutil.rmtree(out, ignore_errors=True)  # a worker's run that failed
                    given = ("--input", self._inputs[source](), "--output", str(out), *options)
                    result, wall = run_pipeline_timed(source, *given)
                    assert result.returncode == 0, result.stderr[-3000:]
                    record.write_text(json.dumps([result.args, 0, result.stdout, result.stderr, wall]))
            *completed, self._walls[name] = json.loads(record.read_text())
            self._made[name] = (str(out), subprocess.CompletedProcess(*completed))
        return self._made[name]

    def wall(self, source: str) -> float:
        """Seconds from that run's launch until its last line reached its parent (its own end, the
        interpreter's shutdown left out)."""
        self._run(source)
        return self._walls[f"reference_direct_{source}"]


@pytest.fixture(scope="session")
def reference_run(tmp_path_factory) -> ReferenceRuns:
    return ReferenceRuns(tmp_path_factory, SAMPLE_INPUTS)


class SampleReleaseRuns:
    """``runs(source)``: the ``subprocess.CompletedProcess`` of that source's release run of the samples'
    splits file, the command ``make demo`` runs (``golden.release_args``), made on first use in this
    process, every source into the one folder ``runs.out``. DriveTrack and Panoptic Studio are given
    no ``--input``: their cached sample worlds are linked into the folder as a run without ``--input``
    leaves them (a plain run writes them there once). ADT reads the excerpt (skip first when absent).
    Never write into the folder: copy it."""

    def __init__(self, out: pathlib.Path, samples: dict[str, Callable[[], str]]):
        self.out, self._samples = out, samples
        self._made: dict[str, object] = {}

    def __call__(self, source: str):
        if source not in self._made:
            if source in self._samples:
                folder = os.path.join(self.out, "sample_input", source)
                link_tree(self._samples[source](), folder)
                version = importlib.import_module(SAMPLE_WRITERS[source]).SAMPLE_VERSION
                open(os.path.join(folder, f".complete-v{version}"), "w").close()
            from tests.support import golden

            args = golden.concrete(golden.release_args(source), str(self.out))
            self._made[source] = run_in_process(source, *args[2:])  # after --source <source>
        return self._made[source]


@pytest.fixture(scope="session")
def sample_release_runs(tmp_path_factory) -> SampleReleaseRuns:
    return SampleReleaseRuns(tmp_path_factory.mktemp("sample_release"), SAMPLE_INPUTS)
