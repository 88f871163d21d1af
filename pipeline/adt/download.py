"""Fetching one ADT sequence from the download-URLs JSON into a scratch folder, and removing it after.

ADT is about 1.7 TB, so a run fetches one sequence at a time: ``read_url_file`` reads the JSON the
ADT website hands each user (the ``cdn_file`` of projectaria-tools' ``aria_dataset_downloader``),
``plan_download`` picks the data groups of one sequence that hold the files the pipeline reads, and
``fetch_sequence`` downloads, checks and unpacks them into a folder of its own inside a scratch
folder, yields that sequence folder, and deletes it on the way out (normally, on an error or on
Ctrl-C). Nothing is written outside the scratch folder given.

The JSON: ``{"sequences": {name: {group: {"download_url", "filename", "sha1sum",
"file_size_bytes"}}}, "sequence_config": {"main": {"recording", "mps"}, "data_groups": {group:
[files]}}}``. The group ``main_vrs`` is the recording, one plain file saved under the
name ``main.recording``; every other group is a zip unpacked into the sequence folder, the library's MPS
groups into ``<main.mps>/<eye_gaze|slam|hand_tracking>/``. Which group holds which file is read
with projectaria-tools' own ``load_data_groups_from_cdn`` (and its MPS folders).

projectaria-tools' ``DatasetDownloader`` is not used to fetch: it downloads into the system's
temporary folder (outside any scratch folder), checks free space on ``/`` instead of its target,
retries 429 and 5xx answers only for ``https://`` URLs, reports failures as a printed line and a
boolean, and draws progress bars. Here the project's HTTP client (``pipeline.io.http``) fetches
both schemes under the run's ``http`` settings, every failure is an ``InputError`` of one line
``<sequence>: data group <group>: <cause>``, the SHA-1 is taken while the body streams (no second
read of a multi-GB file), and only the needed members of a zip are written. Download URLs are
never put in messages (they may carry access tokens).
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import math
import os
import posixpath
import re
import shutil
import tempfile
import zipfile
from collections.abc import Iterable, Iterator, Mapping
from fractions import Fraction
from typing import TypeVar

from projectaria_tools.tools.dataset_downloader.dataset_downloader import MPS_DATA_TYPE_TO_SAVE_PATH
from projectaria_tools.tools.dataset_downloader.dataset_downloader_utils import load_data_groups_from_cdn

from pipeline.core.errors import InputError
from pipeline.core.progress import progress
from pipeline.core.sizes import format_bytes
from pipeline.io.files import PARTIAL, is_abandoned, writer_host
from pipeline.io.http import HttpClient, HttpError
from pipeline.settings.run_config import HttpConfig

T = TypeVar("T")

RECORDING_GROUP = "main_vrs"
MAX_URL_FILE_BYTES = 64 << 20
# What the scratch estimate assumes a zip's needed files unpack to, per byte of the zip: a VRS file
# holds compressed images and depth and shrinks by under 5% in a zip (the real excerpt's); any other
# (CSV, JSON) text, which deflate shrinks 2 to 14 times on the excerpt. A zip whose needed files
# declare more than that is refused before anything is unpacked.
UNPACK_RATIOS = {".vrs": Fraction("1.1")}
TEXT_UNPACK_RATIO = Fraction(20)
CHUNK_BYTES = 1 << 20
# A fetch's folder in the scratch folder: recognisably ours, named for its host and process, so that
# a later run reclaims a folder a killed run left (``reclaim_scratch``) and never another's.
FETCH_FOLDER = ".adt-fetch"
_SHA1 = re.compile(r"[0-9a-fA-F]{40}")


@dataclasses.dataclass(frozen=True)
class GroupEntry:
    """One data group of one sequence in the URLs JSON (``url`` is '' when none is given)."""

    url: str
    filename: str
    sha1: str
    size: int


@dataclasses.dataclass(frozen=True)
class UrlFile:
    """A read URLs JSON: its sequences, their groups' entries, and each group's files as paths
    relative to the sequence folder (the library's MPS groups' under ``<main.mps>/<kind>/``)."""

    path: str
    sequences: tuple[str, ...]
    entries: Mapping[str, Mapping[str, GroupEntry]]
    groups: Mapping[str, tuple[str, ...]]
    recording: str
    mps_folder: str


@dataclasses.dataclass(frozen=True)
class GroupDownload:
    """One group to fetch: ``files`` are the needed files it holds (the only ones unpacked), as
    paths in the sequence folder; a zip's members are those paths relative to ``folder``."""

    name: str
    url: str
    filename: str
    sha1: str
    size: int
    files: tuple[str, ...]
    folder: str
    is_recording: bool

    @property
    def unpacked(self) -> int:
        """The most its needed files may take once unpacked: the recording's size, or the zip's size
        times the largest ``UNPACK_RATIOS`` of its files' kinds (the estimate, and the cap)."""
        if self.is_recording:
            return self.size
        ratio = max(UNPACK_RATIOS.get(posixpath.splitext(name)[1], TEXT_UNPACK_RATIO) for name in self.files)
        return math.ceil(self.size * ratio)


@dataclasses.dataclass(frozen=True)
class SequenceDownload:
    """The groups of one sequence to fetch, in fetch order: zips largest first, the recording last.

    ``peak_bytes`` is the most the scratch folder holds meanwhile, each zip's needed files taking
    at most ``GroupDownload.unpacked`` (unpacking refuses more) and each zip deleted once unpacked:
    the largest over the zips of (bytes kept from earlier groups + the zip + its files), and the
    total kept.
    """

    sequence: str
    groups: tuple[GroupDownload, ...]
    download_bytes: int
    peak_bytes: int


class _GroupError(Exception):
    """The cause of a group's failure, turned into an ``InputError`` naming sequence and group."""


def _one_line(text: object) -> str:
    return " ".join(str(text).split())


def is_url_file(path: str) -> bool:
    """A local ``.json`` file whose top level holds ``sequences`` and ``sequence_config``."""
    if "://" in path or not path.lower().endswith(".json") or not os.path.isfile(path):
        return False
    try:
        data = _load_json(path)
    except InputError:
        return False
    return "sequences" in data and "sequence_config" in data


def _load_json(path: str) -> dict:
    try:
        with open(path, "rb") as handle:
            raw = handle.read(MAX_URL_FILE_BYTES + 1)
    except OSError as error:
        raise InputError(f"{path}: cannot read the ADT URL file: {error.strerror}") from error
    if len(raw) > MAX_URL_FILE_BYTES:
        raise InputError(f"{path}: larger than {format_bytes(MAX_URL_FILE_BYTES)}, not an ADT URL file")
    try:
        data = json.loads(raw)
    except (ValueError, RecursionError) as error:
        raise InputError(f"{path}: not JSON ({_one_line(error)})") from error
    if not isinstance(data, dict):
        raise InputError(f"{path}: the top level is a {type(data).__name__}, not an object")
    return data


def _need(path: str, where: str, value: object, kind: type[T]) -> T:
    """``value`` when it is a ``kind`` (a bool is no int); InputError naming ``where`` otherwise."""
    if not isinstance(value, kind) or isinstance(value, bool):
        raise InputError(f"{path}: {where} must be a {kind.__name__}, not {type(value).__name__}")
    return value


def _safe_relative(path: str, where: str, name: object) -> str:
    """A relative path with no '..', no empty part and no backslash (file names of a sequence)."""
    text = _need(path, where, name, str)
    parts = text.split("/")
    if text.startswith("/") or "\\" in text or "\0" in text or any(p in ("", ".", "..") for p in parts):
        raise InputError(f"{path}: {where}: {text!r} is not a plain relative file name")
    return text


def read_url_file(path: str) -> UrlFile:
    """Read and check an ADT URLs JSON (at most ``MAX_URL_FILE_BYTES``); problems raise one line."""
    data = _load_json(path)
    for key in ("sequences", "sequence_config"):
        if key not in data:
            raise InputError(f"{path}: no '{key}' key, not an ADT URL file")
    sequences = _need(path, "'sequences'", data["sequences"], dict)
    config = _need(path, "'sequence_config'", data["sequence_config"], dict)
    main = _need(path, "'sequence_config/main'", config.get("main"), dict)
    _need(path, "'sequence_config/data_groups'", config.get("data_groups"), dict)
    recording = _safe_relative(path, "'sequence_config/main/recording'", main.get("recording"))
    mps = _need(path, "'sequence_config/main/mps'", main.get("mps"), str)
    entries = {
        str(name): _read_entries(path, f"'sequences/{name}'", groups) for name, groups in sequences.items()
    }
    groups = _data_groups(path, mps)
    return UrlFile(path, tuple(entries), entries, groups, recording, mps)


def _read_entries(path: str, where: str, groups: object) -> dict[str, GroupEntry]:
    named = _need(path, where, groups, dict)
    return {str(group): _read_entry(path, f"{where[:-1]}/{group}'", entry) for group, entry in named.items()}


def _read_entry(path: str, where: str, entry: object) -> GroupEntry:
    fields = _need(path, where, entry, dict)
    if "download_url" not in fields:
        raise InputError(f"{path}: {where} has no 'download_url'")
    if not fields["download_url"]:  # the library skips such a group: it is not available
        return GroupEntry("", "", "", 0)
    url = _need(path, f"{where[:-1]}/download_url'", fields["download_url"], str)
    if not url.startswith(("http://", "https://")):
        raise InputError(f"{path}: {where}: the download URL is not http:// or https://")
    sha1, size = fields.get("sha1sum"), fields.get("file_size_bytes")
    if not isinstance(sha1, str) or not _SHA1.fullmatch(sha1):
        raise InputError(f"{path}: {where}: 'sha1sum' must be 40 hex digits, not {sha1!r}")
    if isinstance(size, str) and size.isdigit():
        size = int(size)
    if not isinstance(size, int) or isinstance(size, bool) or size < 0:
        raise InputError(f"{path}: {where}: 'file_size_bytes' must be a byte count, not {size!r}")
    filename = _need(path, f"{where[:-1]}/filename'", fields.get("filename", ""), str)
    return GroupEntry(url, filename, sha1.lower(), size)


def _data_groups(path: str, mps_folder: str) -> dict[str, tuple[str, ...]]:
    """Group -> files from projectaria-tools' parsing (the recording a str there), MPS files under
    the folder the library moves them to."""
    try:
        groups = load_data_groups_from_cdn(path)
    except Exception as error:  # the library raises bare Exceptions and KeyErrors
        raise InputError(f"{path}: {_one_line(error) or type(error).__name__}") from error
    out = {}
    for group, files in groups.items():
        where = f"'sequence_config/data_groups/{group}'"
        names = _need(path, where, [files] if isinstance(files, str) else files, list)
        folder = _group_folder(mps_folder, group)
        out[str(group)] = tuple(
            _safe_relative(path, where, posixpath.join(folder, name) if folder else name) for name in names
        )
    return out


def _group_folder(mps_folder: str, group: str) -> str:
    """Where a group's zip is unpacked in the sequence folder: '' (the folder itself), or for the
    library's MPS groups its ``mps/<kind>`` with ``mps`` renamed to ``main.mps`` as it does."""
    save = MPS_DATA_TYPE_TO_SAVE_PATH.get(group)
    return posixpath.join(mps_folder, posixpath.relpath(save, "mps")) if save else ""


def _check_sequence_name(sequence: str) -> None:
    """A sequence's name becomes its folder's name (clip names derive from it): one plain name."""
    if sequence in ("", ".", "..") or any(c in sequence for c in "/\\\0"):
        raise InputError(f"{sequence!r}: not a plain folder name, cannot be a sequence folder")


def plan_download(url_file: UrlFile, sequence: str, needed_files: Iterable[str]) -> SequenceDownload:
    """The groups of ``sequence`` holding at least one of ``needed_files`` (paths in the sequence
    folder), and only those; each file comes from the first group listing it that the sequence
    has. A needed file in no group, or only in groups the sequence lacks, raises ``InputError``."""
    _check_sequence_name(sequence)
    if sequence not in url_file.entries:
        raise InputError(f"{url_file.path}: no sequence {sequence!r} in it")
    chosen: dict[str, list[str]] = {}
    for name in dict.fromkeys(needed_files):
        chosen.setdefault(_holder(url_file, sequence, name), []).append(name)
    groups = [_group_download(url_file, sequence, group, files) for group, files in chosen.items()]
    groups.sort(key=lambda g: (g.is_recording, -g.size))
    return SequenceDownload(sequence, tuple(groups), sum(g.size for g in groups), _peak_bytes(groups))


def _holder(url_file: UrlFile, sequence: str, name: str) -> str:
    holders = [group for group, files in url_file.groups.items() if name in files]
    if not holders:
        raise InputError(f"{sequence}: {name} is in no data group of {url_file.path}")
    for group in holders:
        entry = url_file.entries[sequence].get(group)
        if entry is not None and entry.url:
            return group
    raise InputError(
        f"{sequence}: data group {' or '.join(holders)} (holding {name}) has no download URL "
        f"for this sequence in {url_file.path}"
    )


def _group_download(url_file: UrlFile, sequence: str, group: str, files: list[str]) -> GroupDownload:
    entry = url_file.entries[sequence][group]
    folder, recording = _group_folder(url_file.mps_folder, group), group == RECORDING_GROUP
    return GroupDownload(
        group, entry.url, entry.filename, entry.sha1, entry.size, tuple(files), folder, recording
    )


def _peak_bytes(groups: Iterable[GroupDownload]) -> int:
    kept = peak = 0
    for group in groups:
        peak = max(peak, kept + group.unpacked + (0 if group.is_recording else group.size))
        kept += group.unpacked
    return max(peak, kept)


@contextlib.contextmanager
def fetch_sequence(
    download: SequenceDownload, scratch_dir: str, http: HttpConfig | None = None
) -> Iterator[str]:
    """Fetch ``download`` into ``<scratch_dir>/<unique folder>/<sequence>`` and yield that folder.

    Each group's body is streamed to a file in the unique folder by the project's HTTP client
    (``pipeline.io.http``: retries, resumed bodies, a deadline and a stall rule per file, as ``http``
    says) and checked (Content-Length, ``file_size_bytes``, SHA-1); a zip's needed members are
    unpacked (a zip with an absolute or '..' member, or declaring absurd unpacked sizes, is refused)
    and the zip deleted; the recording is renamed to ``main.recording``. Failures raise
    ``InputError`` ``<sequence>: data group <group>: <cause>``. On the way out, however it ends, the
    unique folder is deleted, leaving ``scratch_dir`` as it was (created when missing).
    """
    _check_sequence_name(download.sequence)
    os.makedirs(scratch_dir, exist_ok=True)
    reclaimed = reclaim_scratch(scratch_dir)
    if reclaimed:
        left = f"{format_bytes(reclaimed)} left in {scratch_dir} by a killed run"
        progress(f"{download.sequence}: reclaimed {left}")
    _check_free_space(download, scratch_dir)
    prefix = f"{FETCH_FOLDER}{PARTIAL}{writer_host()}-{os.getpid()}-"
    workdir = tempfile.mkdtemp(prefix=prefix, dir=scratch_dir)
    try:
        folder = os.path.join(workdir, download.sequence)
        os.mkdir(folder)
        with HttpClient(http) as client:
            for index, group in enumerate(download.groups):
                try:
                    _fetch_group(client, group, f"{folder}.download-{index}", folder)
                except _GroupError as error:
                    raise InputError(f"{download.sequence}: data group {group.name}: {error}") from error
        yield folder
    finally:
        shutil.rmtree(workdir, ignore_errors=True)


def reclaim_scratch(scratch_dir: str) -> int:
    """Delete the fetch folders (``FETCH_FOLDER``) whose process is gone (killed, or on another host
    long ago: ``pipeline.io.files.is_abandoned``) from ``scratch_dir``, nothing else; the bytes freed."""
    freed = 0
    with os.scandir(scratch_dir) as entries:
        found = [entry for entry in entries if entry.name.startswith(FETCH_FOLDER + PARTIAL)]
    for entry in found:
        if entry.is_dir(follow_symlinks=False) and is_abandoned(entry.path, entry.stat().st_mtime):
            size = _tree_bytes(entry.path)
            shutil.rmtree(entry.path, ignore_errors=True)
            freed += size if not os.path.exists(entry.path) else 0
    return freed


def _tree_bytes(folder: str) -> int:
    return sum(
        os.lstat(os.path.join(root, name)).st_size for root, _, names in os.walk(folder) for name in names
    )


def _check_free_space(download: SequenceDownload, scratch_dir: str) -> None:
    free = shutil.disk_usage(scratch_dir).free
    if free < download.peak_bytes:
        raise InputError(
            f"{download.sequence}: fetching it needs up to {format_bytes(download.peak_bytes)} in "
            f"{scratch_dir}, which has {format_bytes(free)} free"
        )


def _fetch_group(client: HttpClient, group: GroupDownload, path: str, folder: str) -> None:
    try:
        with open(path, "wb") as out:
            digest = client.download(group.url, out, group.size)
        if digest != group.sha1:
            raise _GroupError(f"sha1 mismatch (expected {group.sha1}, got {digest})")
        if group.is_recording:
            os.replace(path, os.path.join(folder, group.files[0]))
        else:
            _unpack(path, group, folder)
            os.remove(path)
    except HttpError as error:
        raise _GroupError(str(error)) from error
    except OSError as error:
        raise _GroupError(f"cannot write {error.filename or path}: {error.strerror}") from error


def _unpack(path: str, group: GroupDownload, folder: str) -> None:
    """Write the zip's members for ``group.files`` into ``folder`` after checking every member's name and
    what the needed ones declare."""
    try:
        with zipfile.ZipFile(path) as archive:
            _check_names(archive.infolist())
            members = {info.filename: info for info in archive.infolist()}
            wanted = {}
            for name in group.files:
                member = posixpath.relpath(name, group.folder) if group.folder else name
                if member not in members or members[member].is_dir():
                    raise _GroupError(f"the zip holds no {member}")
                wanted[name] = members[member]
            _check_unpacked(wanted, group)
            for name, info in wanted.items():
                target = os.path.join(folder, *name.split("/"))
                os.makedirs(os.path.dirname(target), exist_ok=True)
                with archive.open(info) as source, open(target, "wb") as out:
                    shutil.copyfileobj(source, out, CHUNK_BYTES)  # at most the size it declares
    except (zipfile.BadZipFile, zipfile.LargeZipFile, NotImplementedError, RuntimeError, EOFError) as error:
        raise _GroupError(f"cannot unpack the zip: {_one_line(error) or type(error).__name__}") from error


def _check_names(members: Iterable[zipfile.ZipInfo]) -> None:
    """Refuse a member named by an absolute path or with '..'."""
    for info in members:
        name = info.filename
        if name.startswith(("/", "\\")) or re.match(r"[A-Za-z]:", name) or ".." in re.split(r"[/\\]", name):
            raise _GroupError(f"unsafe member {name!r} in the zip (absolute or with '..'), refused")


def _check_unpacked(wanted: dict[str, zipfile.ZipInfo], group: GroupDownload) -> None:
    """Refuse the zip when its needed members declare more than the scratch estimate allows them."""
    declared = sum(info.file_size for info in wanted.values())
    if declared > group.unpacked:
        largest = max(wanted, key=lambda name: wanted[name].file_size)
        raise _GroupError(
            f"its needed files unpack to {format_bytes(declared)} ({largest}: "
            f"{format_bytes(wanted[largest].file_size)}), more than the {format_bytes(group.unpacked)} "
            f"the scratch estimate allows a {format_bytes(group.size)} zip of them; refused"
        )
