"""The golden fixtures in ``tests/fixtures/``: what each sample run and the sample release run make.

``sample_runs/<source>.json``: a plain run on the source's sample (DriveTrack and Panoptic Studio
given no ``--input``: their embedded sample worlds; ADT on the real excerpt), its command-line
arguments (``OUT`` for the output folder), per clip its frame count and track count, the sha256 of
each clip's bytes per sample input (``sha256``: the input's digest -> clip -> sha256), and the
versions of the libraries that decide those bytes. A sample world is written by ray casting
(open3d's Embree), whose last bits depend on the CPU's instruction set: the world one machine writes
may differ from another's, and with it every clip's bytes (the pipeline's own arithmetic does not:
the same world gives the same bytes on every CPU). So the hashes are kept per input, each machine's
``--write`` adding its own, and a fresh run's are compared with those of the input it read.

``sample_release.json``: per source, the release run of the samples' splits file (what ``make
demo`` runs) and each release clip's verdict, with its track count when written.
``tests/run/test_golden.py`` compares a fresh run with them.

A change that alters clip bytes updates the fixtures in the same commit::

    python -m tests.support.golden            # run everything, print what differs (exit 1 if anything)
    python -m tests.support.golden --write    # ... and record it

``--source`` limits both to some sources (the others' records are kept). Without the ADT excerpt,
ADT is left as recorded. docs/testing.md describes the fixtures.
"""

from __future__ import annotations

import concurrent.futures
import hashlib
import importlib.metadata
import json
import os
import shutil
import subprocess
import sys
import tempfile

import pipeline.clips
from pipeline.adt.sample.excerpt import EXCERPT_SETTINGS, SHARED_EXCERPT, excerpt_path
from pipeline.commandline import StrictParser
from pipeline.export.layout import sample_folder
from pipeline.io.files import write_atomic
from pipeline.runner.splits import SAMPLE_RELEASE
from tests.support.cli import REPO

FIXTURES = os.path.join(REPO, "tests", "fixtures")
SOURCES = ("drivetrack", "pstudio", "adt")
SAMPLED = ("drivetrack", "pstudio")  # the sources with an embedded sample world
REGENERATE = "python -m tests.support.golden --write"
OUT = "OUT"  # the output folder in a recorded command
RELEASE_FILE = os.path.relpath(SAMPLE_RELEASE, REPO)
# The libraries whose versions decide clip bytes: the arithmetic, the JPEG encoder, the compiled
# kernels; the synthetic worlds' mesh ray casting; ADT's reader.
LIBRARIES = ("numpy", "opencv-python-headless", "scipy", "numba")
SOURCE_LIBRARIES = {
    "drivetrack": ("open3d", "trimesh"),
    "pstudio": ("open3d", "trimesh"),
    "adt": ("projectaria-tools",),
}


def sample_path(source: str) -> str:
    return os.path.join(FIXTURES, "sample_runs", f"{source}.json")


RELEASE_PATH = os.path.join(FIXTURES, "sample_release.json")


def _input(source: str) -> list[str]:
    settings = [part for setting in EXCERPT_SETTINGS for part in ("--set", setting)]
    return ["--input", SHARED_EXCERPT, *settings] if source == "adt" else []


def sample_args(source: str) -> list[str]:
    """The arguments of ``python -m pipeline.run`` for the source's sample run."""
    return ["--source", source, "--output", OUT, *_input(source)]


def release_args(source: str) -> list[str]:
    """The arguments of ``python -m pipeline.run`` for the source's sample release run (``make demo``)."""
    return ["--source", source, "--output", OUT, *_input(source), "--release", RELEASE_FILE]


def concrete(args: list[str], out: str) -> list[str]:
    """``args`` with ``OUT`` as ``out`` and the repository's paths absolute (the excerpt: $ADT_EXCERPT)."""
    paths = {OUT: out, SHARED_EXCERPT: excerpt_path() or SHARED_EXCERPT, RELEASE_FILE: SAMPLE_RELEASE}
    return [paths.get(arg, arg) for arg in args]


def versions(source: str) -> dict[str, str | None]:
    """Installed version of each library that decides the source's clip bytes (None: not installed)."""
    found: dict[str, str | None] = {}
    for name in (*LIBRARIES, *SOURCE_LIBRARIES[source]):
        try:
            found[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            found[name] = None
    return found


def python_version() -> str:
    return f"{sys.version_info.major}.{sys.version_info.minor}"


def clips_of(out: str, source: str) -> tuple[dict[str, dict], dict[str, str]]:
    """(clip file name -> frames and tracks, clip file name -> sha256), for every clip of ``source`` a
    run wrote in ``out``."""
    folder = os.path.join(out, source)
    counts, hashes = {}, {}
    for name in sorted(os.listdir(folder)) if os.path.isdir(folder) else []:
        if name.endswith(".npz"):
            path = os.path.join(folder, name)
            clip = pipeline.clips.open(path)
            with open(path, "rb") as handle:
                hashes[name] = hashlib.sha256(handle.read()).hexdigest()
            counts[name] = {"frames": clip.num_frames, "tracks": clip.num_tracks}
    return counts, hashes


def input_digest(out: str, source: str) -> str:
    """16 hex digits of sha256 over the files of the input the run in ``out`` read (its provenance's
    ``input``), by path relative to it; hidden files (a sample's completion marker) aside."""
    with open(os.path.join(out, f"run_{source}.json")) as handle:
        root = json.load(handle)["input"]
    digest = hashlib.sha256()
    for folder, names, files in sorted(os.walk(root)):
        names.sort()
        for name in sorted(file for file in files if not file.startswith(".")):
            path = os.path.join(folder, name)
            with open(path, "rb") as handle:
                content = hashlib.sha256(handle.read()).hexdigest()
            digest.update(f"{os.path.relpath(path, root)}\0{content}\0".encode())
    return digest.hexdigest()[:16]


def sample_record(out: str, source: str) -> dict:
    """What ``sample_runs/<source>.json`` holds for the run in ``out`` (its hashes under its input's
    digest)."""
    counts, hashes = clips_of(out, source)
    return {
        "args": sample_args(source),
        "clips": counts,
        "sha256": {input_digest(out, source): hashes},
        "python": python_version(),
        "versions": versions(source),
    }


def merged(old: dict | None, new: dict) -> dict:
    """``new``, keeping ``old``'s hashes of other inputs when they were made with the same Python and
    library versions and the same clips (another machine's sample world)."""
    if old is None or (old.get("python"), old.get("versions"), old.get("clips")) != (
        new["python"],
        new["versions"],
        new["clips"],
    ):
        return new
    return new | {"sha256": old.get("sha256", {}) | new["sha256"]}


def verdicts_of(out: str, source: str) -> dict[str, dict]:
    """Release clip -> status, and tracks when written, from ``<out>/release_<source>.jsonl``."""
    found = {}
    with open(os.path.join(out, f"release_{source}.jsonl")) as handle:
        for row in map(json.loads, handle):
            found[row["clip"]] = {"status": row["status"]}
            if row["status"] == "written":
                found[row["clip"]]["tracks"] = row["tracks"]
    return found


def release_record(out: str, source: str) -> dict:
    """What ``sample_release.json`` holds for ``source``'s release run in ``out``."""
    return {"args": release_args(source), "clips": verdicts_of(out, source)}


def read(path: str) -> dict | None:
    if not os.path.exists(path):
        return None
    with open(path) as handle:
        return json.load(handle)


def dumps(record: dict) -> str:
    """The fixtures' one formatting: sorted keys, two-space indents, a final newline."""
    return json.dumps(record, indent=2, sort_keys=True) + "\n"


def changes(old: dict | None, new: dict, what: str) -> list[str]:
    """One line per difference between two records (sample or release): clips added, removed or
    changed, and any other field."""
    if old is None:
        return [f"{what}: new, {len(new['clips'])} clip(s)"]
    lines = []
    for name in sorted(set(old["clips"]) | set(new["clips"])):
        before, after = old["clips"].get(name), new["clips"].get(name)
        if before is None:
            lines.append(f"{what}: clip {name} added {_brief(after)}")
        elif after is None:
            lines.append(f"{what}: clip {name} removed (was {_brief(before)})")
        elif before != after:
            fields = sorted(key for key in set(before) | set(after) if before.get(key) != after.get(key))
            diff = ", ".join(f"{key} {_short(before.get(key))} -> {_short(after.get(key))}" for key in fields)
            lines.append(f"{what}: clip {name} changed: {diff}")
    for key in sorted((set(old) | set(new)) - {"clips"}):
        before, after = old.get(key), new.get(key)
        if isinstance(before, dict) and isinstance(after, dict):  # versions, hashes: one line per entry
            for name in sorted(set(before) | set(after)):
                if before.get(name) != after.get(name):
                    was, now = (_brief_hashes(value.get(name)) for value in (before, after))
                    lines.append(f"{what}: {key} {name} {was} -> {now}")
        elif before != after:
            lines.append(f"{what}: {key} {before} -> {after}")
    return lines


def _brief_hashes(value):
    """An entry of ``versions`` as it is, one of ``sha256`` (clip -> hash) as its clips' short hashes."""
    if isinstance(value, dict):
        return (
            "{" + ", ".join(f"{name[-24:]}: {_short(digest)}" for name, digest in sorted(value.items())) + "}"
        )
    return value


def _brief(entry: dict) -> str:
    return ", ".join(f"{key} {_short(value)}" for key, value in sorted(entry.items()))


def _short(value):
    return value[:12] if isinstance(value, str) and len(value) == 64 else value


def run(args: list[str], out: str) -> None:
    """``python -m pipeline.run`` with ``args`` into ``out``, as a user runs it; SystemExit on failure."""
    command = [sys.executable, "-m", "pipeline.run", *concrete(args, out)]
    done = subprocess.run(command, cwd=REPO, capture_output=True, text=True, timeout=1800)
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(command)} exited {done.returncode}:\n{done.stderr[-3000:]}")


def regenerate(source: str, scratch: str) -> tuple[dict, dict]:
    """(sample record, release record) of ``source`` from fresh runs under ``scratch``. The release
    run finds the sample world its sample run wrote, as a second run without ``--input`` does."""
    plain, release = os.path.join(scratch, f"sample_{source}"), os.path.join(scratch, f"release_{source}")
    run(sample_args(source), plain)
    if source in SAMPLED:
        shutil.copytree(sample_folder(plain, source), sample_folder(release, source))
    run(release_args(source), release)
    return sample_record(plain, source), release_record(release, source)


def main(argv: list[str] | None = None) -> int:
    parser = StrictParser(
        prog="python -m tests.support.golden",
        description="Rerun every sample run and the sample release run; print what differs from "
        "tests/fixtures/ (exit 1 when anything does), and with --write record it.",
    )
    parser.add_argument("--write", action="store_true", help="write the fixtures (atomically)")
    parser.add_argument(
        "--source", action="append", choices=SOURCES, help="only this source (repeatable; default: all)"
    )
    args = parser.parse_args(argv)
    chosen = [source for source in SOURCES if source in (args.source or SOURCES)]
    if "adt" in chosen and excerpt_path() is None:
        print(f"adt: no excerpt at {SHARED_EXCERPT} (or $ADT_EXCERPT): its fixtures are kept as they are")
        chosen.remove("adt")
    scratch = tempfile.mkdtemp(prefix="golden-")
    try:
        print(f"running {', '.join(chosen)} (sample and sample release runs) in {scratch}", flush=True)
        with concurrent.futures.ThreadPoolExecutor(max(1, min(len(chosen), os.cpu_count() or 1))) as pool:
            futures = {source: pool.submit(regenerate, source, scratch) for source in chosen}
            made = {source: future.result() for source, future in futures.items()}
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    lines, writes = [], {}
    for source, (sample, _) in made.items():
        recorded = read(sample_path(source))
        sample = merged(recorded, sample)
        lines += changes(recorded, sample, f"sample_runs/{source}.json")
        writes[sample_path(source)] = dumps(sample)
    old_release = read(RELEASE_PATH) or {}
    release = dict(old_release) | {source: record for source, (_, record) in made.items()}
    for source in chosen:
        lines += changes(old_release.get(source), release[source], f"sample_release.json {source}")
    writes[RELEASE_PATH] = dumps(release)
    print("\n".join(lines) if lines else "no change: the fixtures hold what the runs make")
    if args.write:
        for path, text in writes.items():
            if not os.path.exists(path) or open(path).read() != text:
                write_atomic(path, text.encode())
                print(f"wrote {os.path.relpath(path, REPO)}")
        return 0
    if lines:
        print(f"to record this: {REGENERATE}")
    return 1 if lines else 0


if __name__ == "__main__":
    sys.exit(main())
