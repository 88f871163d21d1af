"""Several files written as one result: a reader finds the old set or the new set, never a mix.

A command whose result spans files (``audit compare``: its report and the verdicts it amends; a
run's finish: failures, verdicts, manifests, provenance) writes them with ``write_together``:

1. each file's bytes go to its hidden temporary beside it (``pipeline.io.files.temporary_path``);
2. a journal, ``<folder>/.files.commit-<host>-<pid>-<random>``, listing (temporary, file) pairs, is
   written atomically: the commit point;
3. each temporary is moved onto its file, then the journal is deleted.

A command killed before step 2 leaves the old set and temporaries that the next command's clean-up
reclaims (their writer is gone). One killed during step 3 leaves a journal whose writer is gone:
``complete_commits``, called by every command before it reads or writes such a folder, moves the
journal's remaining temporaries into place, so the new set appears whole. ``output_lock`` keeps two
commands of this host from amending one folder's files at once.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import uuid
from collections.abc import Iterator, Mapping

from pipeline.io.files import (
    PARTIAL,
    exists,
    filesystems,
    is_abandoned,
    is_local,
    list_files,
    move_file,
    read_bytes,
    remove_quietly,
    temporary_path,
    write_atomic,
    writer_host,
)

COMMIT = ".commit-"
JOURNAL_PREFIX = ".files"
MAX_JOURNAL_BYTES = 1 << 20
LOCK_NAME = ".lock"


def journal_path(folder: str) -> str:
    """A new journal's path in ``folder``: its writer's host and process in the name, like a temporary's."""
    return f"{folder}/{JOURNAL_PREFIX}{COMMIT}{writer_host()}-{os.getpid()}-{uuid.uuid4().hex[:12]}"


def write_together(files: Mapping[str, bytes], folder: str) -> None:
    """Write ``files`` (path -> bytes) as one result, its journal in ``folder`` (the module says how).
    OSError when a file cannot be written: then no file of the set has changed, and this call's
    temporaries are gone."""
    pairs: list[tuple[str, str]] = []
    try:
        for path, data in files.items():
            temporary = temporary_path(path)
            pairs.append((temporary, path))
            _write_plain(temporary, data)
        journal = journal_path(folder)
        write_atomic(journal, json.dumps(pairs).encode())
    except BaseException:
        remove_quietly([temporary for temporary, _ in pairs])
        raise
    _move_into_place(pairs)
    remove_quietly([journal])


def reclaim_temporaries(paths: list[str]) -> int:
    """Delete the abandoned temporaries (their writer gone) of each of ``paths`` (a path ending in
    ``COMMIT``: of every journal it begins); how many went."""
    doomed = []
    for path in paths:
        folder, _, name = path.rpartition("/")
        if is_local(path):
            if not os.path.isdir(folder or "."):
                continue
            found = [
                f"{folder}/{entry}"
                for entry in os.listdir(folder or ".")
                if entry.startswith(f".{name}") and PARTIAL in entry[len(name) + 1 :]
            ]
            doomed += [temporary for temporary in found if is_abandoned(temporary, _modified(temporary))]
        else:
            matches = filesystems().match([f"{folder}/.{name}*{PARTIAL}*"])[0].metadata_list
            doomed += [m.path for m in matches if is_abandoned(m.path, m.last_updated_in_seconds)]
    return remove_quietly(doomed)


def complete_commits(folder: str, writable: tuple[str, ...] = ()) -> int:
    """Finish every commit in ``folder`` whose writer is gone (its journal's remaining temporaries
    moved onto their files, the journal deleted); how many. A live writer's journal is left alone; so
    is one naming a file outside ``folder`` and the ``writable`` folders (the command that may write
    there finishes it); an unreadable or forged one is deleted, moving nothing. A journal a killed
    writer never put in place (its own temporary) is deleted too."""
    reclaim_temporaries([journal_path(folder).rpartition(COMMIT)[0] + COMMIT])
    finished = 0
    roots = tuple(root.rstrip("/") + "/" for root in (folder, *writable))
    for journal in _journals(folder):
        if not is_abandoned(journal, _modified(journal), marker=COMMIT):
            continue
        try:
            pairs = _pairs(json.loads(read_bytes(journal, MAX_JOURNAL_BYTES)))
        except (OSError, ValueError):
            pairs = []
        if not all(path.startswith(roots) for _, path in pairs):
            continue
        _move_into_place([(temporary, path) for temporary, path in pairs if exists(temporary)])
        remove_quietly([journal])
        finished += 1
    return finished


def settle(folder: str) -> None:
    """``complete_commits`` for a command that only reads ``folder``: a folder it cannot write (read
    only, say) is read as it is."""
    with contextlib.suppress(OSError):
        complete_commits(folder)


@contextlib.contextmanager
def output_lock(folder: str) -> Iterator[None]:
    """Hold ``<folder>/.lock`` exclusively for the ``with`` block (waiting for another command of this
    host that holds it), where a command reads, amends and writes back a folder's shared files. On a
    remote filesystem there is no lock to take: the block runs as it is."""
    if not is_local(folder):
        yield
        return
    os.makedirs(folder, exist_ok=True)
    with open(os.path.join(folder, LOCK_NAME), "a") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


def _write_plain(path: str, data: bytes) -> None:
    if is_local(path):
        os.makedirs(os.path.dirname(path) or ".", exist_ok=True)
        with open(path, "wb") as out:
            out.write(data)
        return
    from apache_beam.io.filesystem import CompressionTypes

    with filesystems().create(path, compression_type=CompressionTypes.UNCOMPRESSED) as out:
        out.write(data)


def _move_into_place(pairs: list[tuple[str, str]]) -> None:
    for temporary, path in pairs:
        move_file(temporary, path)


def _journals(folder: str) -> list[str]:
    if is_local(folder):
        if not os.path.isdir(folder):
            return []
        names = sorted(os.listdir(folder))
        return [f"{folder}/{name}" for name in names if name.startswith(JOURNAL_PREFIX + COMMIT)]
    return list_files(f"{folder}/{JOURNAL_PREFIX}{COMMIT}*")


def _modified(path: str) -> float:
    if is_local(path):
        try:
            return os.path.getmtime(path)
        except OSError:
            return 0.0
    matches = filesystems().match([path])[0].metadata_list
    return matches[0].last_updated_in_seconds if matches else 0.0


def _pairs(value: object) -> list[tuple[str, str]]:
    """A journal's (temporary, file) pairs, each file's temporary the hidden ``.partial-`` file beside
    it, no ``..`` in a path; ValueError for anything else (a forged journal)."""
    if not isinstance(value, list):
        raise ValueError("not a list of pairs")
    pairs = []
    for pair in value:
        if not (isinstance(pair, list) and len(pair) == 2 and all(isinstance(p, str) for p in pair)):
            raise ValueError("not a pair of paths")
        temporary, path = pair
        directory, _, name = path.rpartition("/")
        beside, _, hidden = temporary.rpartition("/")
        if not (name and beside == directory and hidden.startswith(f".{name}{PARTIAL}")):
            raise ValueError(f"{temporary!r} is not the temporary of {path!r}")
        if ".." in path.split("/"):
            raise ValueError(f"{path!r} climbs out of its folder")
        pairs.append((temporary, path))
    return pairs
