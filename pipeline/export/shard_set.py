"""A folder's Parquet shards as one set, ``<prefix>-SSSSS-of-NNNNN.parquet``: complete when it holds
every index below its count, and replaced by a new set without ever looking complete in between.

A new set is written into a hidden staging folder inside the shards' folder
(``.<prefix>.staging-<host>-<pid>-<random>``), then ``publish`` deletes the folder's old shards of the
prefix, index 0 first, and moves the new ones in, the last index last: a reader finds the old set
whole, or a set missing an index (which ``shard_files`` refuses), or the new set whole; never a
mix. A staging folder whose writer is gone (a killed write) is deleted by the next write.
"""

from __future__ import annotations

import os
import re
import shutil
import uuid

from pipeline.io.files import (
    file_size,
    filesystems,
    is_abandoned,
    is_local,
    list_files,
    move_file,
    remove_quietly,
    writer_host,
)

SHARD_NAME = re.compile(r"(?P<prefix>[^/]+)-(?P<index>\d{5,})-of-(?P<count>\d{5,})\.parquet")
STAGING = ".staging-"
SUFFIX = ".parquet"


def shard_name(prefix: str, index: int, count: int) -> str:
    """The file name of shard ``index`` of ``count`` (Beam's ``-SSSSS-of-NNNNN`` template)."""
    return f"{prefix}-{index:05d}-of-{count:05d}{SUFFIX}"


def _key(path: str) -> tuple[str, int, int] | None:
    """(prefix, count, index) of a shard's path, None for another name."""
    match = SHARD_NAME.fullmatch(path.rpartition("/")[2])
    if match is None:
        return None
    return match["prefix"], int(match["count"]), int(match["index"])


def _sort_key(path: str) -> tuple[str, int, int]:
    return _key(path) or ("", 0, 0)


def folder_files(folder: str) -> list[str]:
    """The ``*.parquet`` files directly in ``folder`` (hidden ones, ``.`` or ``_`` first, left out as
    pyarrow's datasets leave them), by name."""
    found = list_files(f"{folder.rstrip('/')}/*{SUFFIX}")
    return sorted(path for path in found if not path.rpartition("/")[2].startswith((".", "_")))


def shard_paths(folder: str, prefix: str) -> list[str]:
    """The shards of ``prefix`` in ``folder`` (any count), by count, then index."""
    paths = [path for path in folder_files(folder) if (_key(path) or ("",))[0] == prefix]
    return sorted(paths, key=_sort_key)


def set_problems(paths: list[str]) -> list[str]:
    """How the shard sets among ``paths`` fall short: per prefix, one count and every index below it.
    Files of other names are no set's."""
    found: dict[str, dict[int, set[int]]] = {}
    for path in paths:
        key = _key(path)
        if key is not None:
            found.setdefault(key[0], {}).setdefault(key[1], set()).add(key[2])
    problems = []
    for prefix, counts in sorted(found.items()):
        if len(counts) > 1:
            shown = ", ".join(f"{count:05d}" for count in sorted(counts))
            problems.append(f"shards {prefix}-*: sets of {shown} shards side by side")
            continue
        count, indices = next(iter(counts.items()))
        missing = ", ".join(f"{index:05d}" for index in sorted(set(range(count)) - indices))
        if missing:
            problems.append(f"shards {prefix}-*-of-{count:05d}: missing {missing}")
    return problems


def shard_files(path: str) -> list[str]:
    """The Parquet files a reader of ``path`` reads: the file itself, or the folder's ``*.parquet``
    by name. ValueError when a folder holds none, or its shards are not whole sets (a write cut short:
    rerun it)."""
    if file_size(path) is not None:
        return [path]
    paths = folder_files(path)
    if not paths:
        raise ValueError(f"{path}: no Parquet shards (neither a .parquet file nor a folder of them)")
    problems = set_problems(paths)
    if problems:
        raise ValueError(f"{path}: {problems[0]} (a write was cut short: rerun it)")
    return paths


def staging_folder(folder: str, prefix: str) -> str:
    """A new staging folder's path in ``folder``, its writer's host and process in the name."""
    return f"{folder}/.{prefix}{STAGING}{writer_host()}-{os.getpid()}-{uuid.uuid4().hex[:12]}"


def remove_tree(path: str) -> None:
    """Delete the folder ``path`` and everything in it; nothing when it is gone."""
    if is_local(path):
        shutil.rmtree(path, ignore_errors=True)
        return
    remove_quietly([m.path for m in filesystems().match([f"{path}/**"])[0].metadata_list])


def remove_abandoned_staging(folder: str, prefix: str) -> int:
    """Delete the staging folders of ``prefix`` in ``folder`` whose writer is gone; a live writer's
    stay. Returns how many went."""
    start = f".{prefix}{STAGING}"
    newest: dict[str, float] = {}
    if is_local(folder):
        if not os.path.isdir(folder):
            return 0
        for entry in os.scandir(folder):
            if entry.name.startswith(start) and entry.is_dir():
                newest[entry.path] = entry.stat().st_mtime
    else:
        for match in filesystems().match([f"{folder}/{start}*/**"])[0].metadata_list:
            staging = f"{folder}/{match.path[len(folder) + 1 :].partition('/')[0]}"
            newest[staging] = max(newest.get(staging, 0.0), match.last_updated_in_seconds)
    doomed = [path for path, modified in newest.items() if is_abandoned(path, modified, marker=STAGING)]
    for path in doomed:
        remove_tree(path)
    return len(doomed)


def publish(staged: list[str], folder: str, prefix: str) -> list[str]:
    """Replace the shards of ``prefix`` in ``folder`` with the complete set ``staged`` (files of a
    staging folder): the old ones deleted, index 0 first, then the new ones moved in, the last index
    last. Returns the new shards' paths, by index."""
    remove_quietly(shard_paths(folder, prefix))
    published = []
    for path in sorted(staged, key=_sort_key):
        published.append(f"{folder}/{path.rpartition('/')[2]}")
        move_file(path, published[-1])
    return published
