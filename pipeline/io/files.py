"""Atomic writes, bounded reads and safe deletes: local files through the os module, others (GCS, S3,
HDFS) and folder listings through Beam's FileSystems.

A file is written to a hidden temporary beside it, ``.<name>.partial-<host>-<pid>-<random>``,
then moved into place: ``os.replace`` on a local disk (atomic, no moment without the file),
the filesystem's rename elsewhere (object stores overwrite in one step). The writer's host and
process id in the temporary's name let a later run tell an abandoned temporary (its process is
gone) from a live one of a concurrent run, which it must leave alone.
"""

from __future__ import annotations

import errno
import os
import socket
import time
import uuid
from typing import TYPE_CHECKING

from pipeline.core.errors import InputError

if TYPE_CHECKING:
    from apache_beam.io.filesystems import FileSystems

PARTIAL = ".partial-"
# Longest file name written; the temporary adds its prefix and suffix to it (255 is the usual limit).
MAX_NAME_BYTES = 180
# A temporary written from another machine counts as abandoned once this old.
REMOTE_GRACE_SECONDS = 3600.0


def filesystems() -> type[FileSystems]:
    """Beam's FileSystems, imported on first use: importing Beam takes about a second, which a command
    that writes only local files (``write_atomic``, ``remove_quietly``) does not pay."""
    from apache_beam.io.filesystems import FileSystems

    return FileSystems


def is_local(path: str) -> bool:
    return "://" not in path


def exists(path: str) -> bool:
    """Whether the file (or folder) exists, on a local disk or any Beam filesystem."""
    return os.path.exists(path) if is_local(path) else filesystems().exists(path)


def temporary_path(path: str) -> str:
    """The hidden temporary a write of ``path`` goes through, unique to this process and call."""
    folder, _, name = path.rpartition("/")
    temporary = f".{name}{PARTIAL}{writer_host()}-{os.getpid()}-{uuid.uuid4().hex[:12]}"
    return f"{folder}/{temporary}" if folder else temporary


def check_name_length(path: str) -> None:
    """Raise OSError(ENAMETOOLONG) naming the file when its name is longer than MAX_NAME_BYTES."""
    name = path.rpartition("/")[2]
    if len(name.encode()) > MAX_NAME_BYTES:
        raise OSError(
            errno.ENAMETOOLONG, f"file name is {len(name.encode())} bytes, at most {MAX_NAME_BYTES}", name
        )


def write_atomic(path: str, data: bytes) -> None:
    """Write ``data`` to ``path`` through a hidden temporary and an atomic replace.

    A crash leaves either the old file, the new file, or a hidden ``.partial-`` file that no
    reader lists; never a truncated ``path``.
    """
    check_name_length(path)
    temporary = temporary_path(path)
    try:
        if is_local(path):
            os.makedirs(os.path.dirname(path) or ".", exist_ok=True)
            with open(temporary, "wb") as out:
                out.write(data)
            os.replace(temporary, path)
        else:
            from apache_beam.io.filesystem import CompressionTypes

            with filesystems().create(temporary, compression_type=CompressionTypes.UNCOMPRESSED) as out:
                out.write(data)
            filesystems().rename([temporary], [path])
    except OSError as error:
        remove_quietly([temporary])
        # Name the file (or the folder) the caller asked for, not the hidden temporary.
        named = os.path.dirname(path) if error.filename == temporary else error.filename
        raise OSError(error.errno, error.strerror, named) from error
    except BaseException:
        remove_quietly([temporary])
        raise


def open_binary(path: str):
    """A seekable binary stream of the file (for readers that stream: Parquet, zip)."""
    if is_local(path):
        return open(path, "rb")
    from apache_beam.io.filesystem import CompressionTypes

    return filesystems().open(path, compression_type=CompressionTypes.UNCOMPRESSED)


def read_input(path: str, max_bytes: int | None = None) -> bytes:
    """``read_bytes`` for a unit's input: InputError ``missing file <path>`` or ``cannot read <path>:
    <cause>`` instead of each filesystem's own exception."""
    try:
        return read_bytes(path, max_bytes)
    except Exception as error:  # noqa: BLE001 - any filesystem's not-found becomes InputError
        if not exists(path):
            raise InputError(f"missing file {path}") from error
        raise InputError(f"cannot read {path}: {error}") from error


def read_bytes(path: str, max_bytes: int | None = None) -> bytes:
    """The file's bytes; with ``max_bytes``, OSError(EFBIG) before reading a larger file."""
    if max_bytes is not None:
        size = file_size(path)
        if size is not None and size > max_bytes:
            raise OSError(errno.EFBIG, f"{size} bytes, more than the {max_bytes} read", path)
    with open_binary(path) as handle:
        data = handle.read() if max_bytes is None else handle.read(max_bytes + 1)
    if max_bytes is not None and len(data) > max_bytes:
        raise OSError(errno.EFBIG, f"more than the {max_bytes} bytes read", path)
    return data


def file_size(path: str) -> int | None:
    """Size in bytes, or None when the file does not exist."""
    if is_local(path):
        return os.path.getsize(path) if os.path.isfile(path) else None
    matches = filesystems().match([path])[0].metadata_list
    return matches[0].size_in_bytes if matches else None


def list_files(pattern: str) -> list[str]:
    """Paths matching a glob, sorted; hidden partial files never match ``*.npz``."""
    result = filesystems().match([pattern])[0]
    return sorted(m.path for m in result.metadata_list)


def move_file(path: str, target: str) -> None:
    """Rename the file ``path`` to ``target``, replacing any file there: in one step on a local disk,
    by the filesystem's rename elsewhere (an object store's target appears whole)."""
    if is_local(target):
        os.replace(path, target)
    else:
        filesystems().rename([path], [target])


def remove_quietly(paths: list[str]) -> int:
    """Delete each path that exists; one already gone (another process's clean-up) is no error.
    Returns how many were deleted here."""
    removed = 0
    for path in paths:
        try:
            if is_local(path):
                os.remove(path)
            else:
                filesystems().delete([path])
            removed += 1
        except (FileNotFoundError, NotADirectoryError):  # gone, or its folder never was one
            continue
        except OSError:  # Beam's BeamIOError is an IOError
            if is_local(path) or filesystems().exists(path):
                raise
    return removed


def writer_pid(path: str, marker: str = PARTIAL) -> int | None:
    """The process id of the temporary's writer when it ran on this host, else None (``marker``: what
    precedes the writer in the name)."""
    writer = path.rpartition(marker)[2].rsplit("-", 2)
    if len(writer) == 3 and writer[0] == writer_host() and writer[1].isdigit():
        return int(writer[1])
    return None


def is_abandoned(path: str, modified: float, now: float | None = None, marker: str = PARTIAL) -> bool:
    """Whether a temporary's writer is gone: on this host, its process no longer exists; from
    another host (or a name without a writer), it is older than REMOTE_GRACE_SECONDS."""
    pid = writer_pid(path, marker)
    if pid is not None:
        return not _process_alive(pid)
    return (time.time() if now is None else now) - modified > REMOTE_GRACE_SECONDS


def remove_abandoned(patterns: list[str], include_own: bool = False) -> int:
    """Delete the hidden temporaries matching ``patterns`` (globs) whose writer is gone
    (``is_abandoned``); a concurrent writer's live ones stay. ``include_own`` also deletes this
    process's (it is stopping). Returns how many went."""
    now = time.time()
    doomed = [
        match.path
        for result in filesystems().match(patterns)
        for match in result.metadata_list
        if is_abandoned(match.path, match.last_updated_in_seconds, now)
        or (include_own and writer_pid(match.path) == os.getpid())
    ]
    return remove_quietly(doomed)


def writer_host() -> str:
    """This host's name as temporaries carry it ('-' separates the name's fields)."""
    return socket.gethostname().replace("-", "_")


def _process_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True
