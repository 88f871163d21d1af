"""A real ADT sequence folder served the way the ADT website's download-URLs JSON describes it.

``write_layout(source, sequence, folder, base_url)`` writes into ``folder`` one file per data group
(the recording as a plain ``.vrs``, every other group a zip of its files) and ``urls.json``
pointing at ``base_url`` with their real SHA-1s and sizes. ``serve(folder)`` runs an HTTP server
on 127.0.0.1 (any free port) in a daemon thread for the ``with`` block; ``server.fail(filename,
*actions)`` queues faults for one file, each used by one request: an HTTP status (``"500"``,
``"429"``, ...), ``"truncate"`` (the full Content-Length, half the body, then the connection is
closed), ``"short"`` / ``"long"`` (no Content-Length; half the body, or the body and 10 more
bytes, then the connection is closed) or ``"drop"`` (the connection closed without an answer);
``server.stop()`` takes the server away (connections are then refused);
``server.requests(filename)`` counts the requests for a file, ``server.reset()`` forgets them.
"""

from __future__ import annotations

import collections
import contextlib
import dataclasses
import hashlib
import http.server
import json
import pathlib
import sys
import threading
import urllib.parse
import zipfile
from collections.abc import Iterator, Mapping

RECORDING = "video.vrs"
# The excerpt's files by data group, as ADT ships them: the recording alone, the ground truth,
# depth and segmentation (each with and without the wearer's body), the synthetic rendering.
GROUPS = {
    "main_groundtruth": (
        "2d_bounding_box.csv",
        "2d_bounding_box_with_skeleton.csv",
        "3d_bounding_box.csv",
        "Skeleton_T.json",
        "aria_trajectory.csv",
        "eyegaze.csv",
        "instances.json",
        "metadata.json",
        "scene_objects.csv",
        "skeleton_aria_association.json",
    ),
    "depth": ("depth_images.vrs", "depth_images_with_skeleton.vrs"),
    "segmentation": ("segmentations.vrs", "segmentations_with_skeleton.vrs"),
    "synthetic": ("synthetic_video.vrs",),
}
# projectaria-tools' own MPS groups (listed by the library, not by data_groups) and the folder of
# the sequence their zip's top-level members come from.
MPS_GROUPS = {"mps_eye_gaze": "mps/eye_gaze"}


def entry_of(path: pathlib.Path, base_url: str) -> dict:
    """The URLs-JSON entry of a served file: URL, name, SHA-1 and size of its bytes."""
    data = path.read_bytes()
    return {
        "download_url": f"{base_url}/{urllib.parse.quote(path.name)}",
        "filename": path.name,
        "sha1sum": hashlib.sha1(data).hexdigest(),
        "file_size_bytes": len(data),
    }


def write_zip(path: pathlib.Path, members: Mapping[str, bytes]) -> pathlib.Path:
    """A zip of ``members`` (name -> bytes) at ``path``, deflated as ADT's are."""
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED, compresslevel=1) as archive:
        for name, data in members.items():
            archive.writestr(zipfile.ZipInfo(name, (2023, 5, 30, 14, 9, 26)), data, zipfile.ZIP_DEFLATED)
    return path


@dataclasses.dataclass
class Layout:
    """The served files of one sequence and its URLs JSON (``data``, written at ``url_file``)."""

    folder: pathlib.Path
    sequence: str
    base_url: str
    data: dict

    @property
    def url_file(self) -> pathlib.Path:
        return self.folder / "urls.json"

    def entry(self, group: str) -> dict:
        return self.data["sequences"][self.sequence][group]

    def filename(self, group: str) -> str:
        return self.entry(group)["filename"]

    def variant(self, name: str, group: str, entry: dict | None = None, **fields) -> pathlib.Path:
        """A copy of the URLs JSON, ``<name>.json``, whose ``group`` entry is ``entry`` (None: the
        group removed from the sequence) updated with ``fields``."""
        data = json.loads(json.dumps(self.data))
        groups = data["sequences"][self.sequence]
        if entry is None and not fields:
            del groups[group]
        else:
            groups[group] = {**(entry or groups[group]), **fields}
        path = self.folder / f"{name}.json"
        path.write_text(json.dumps(data, indent=1))
        return path

    def add_zip(self, name: str, members: Mapping[str, bytes]) -> dict:
        """Serve a zip of ``members`` as ``name``; its URLs-JSON entry."""
        return entry_of(write_zip(self.folder / name, members), self.base_url)


def write_layout(
    source: pathlib.Path, sequence: str, folder: pathlib.Path, base_url: str, mps: bool = True
) -> Layout:
    """Lay the sequence folder ``source`` out in ``folder`` as the URLs JSON describes it: the
    recording ``<sequence>_main_recording.vrs``, a zip ``<sequence>_<group>.zip`` per group (MPS
    eye gaze too when ``mps``), and ``urls.json`` with their URLs under ``base_url``."""
    recording = folder / f"{sequence}_main_recording.vrs"
    recording.write_bytes((source / RECORDING).read_bytes())
    entries = {"main_vrs": entry_of(recording, base_url)}
    zips = {group: {name: (source / name).read_bytes() for name in names} for group, names in GROUPS.items()}
    if mps:
        zips.update(
            {g: {p.name: p.read_bytes() for p in (source / f).iterdir()} for g, f in MPS_GROUPS.items()}
        )
    for group, members in zips.items():
        entries[group] = entry_of(write_zip(folder / f"{sequence}_{group}.zip", members), base_url)
    config = {
        "main": {"recording": RECORDING, "mps": "mps" if mps else "None"},
        "data_groups": {group: list(names) for group, names in GROUPS.items()},
    }
    layout = Layout(folder, sequence, base_url, {"sequences": {sequence: entries}, "sequence_config": config})
    layout.url_file.write_text(json.dumps(layout.data, indent=1))
    return layout


class _Server(http.server.ThreadingHTTPServer):
    daemon_threads = True

    def __init__(self, folder: pathlib.Path):
        super().__init__(("127.0.0.1", 0), _Handler)
        self.folder = folder
        self.lock = threading.Lock()
        self.faults: dict[str, collections.deque[str]] = collections.defaultdict(collections.deque)
        self.counts: collections.Counter[str] = collections.Counter()

    def handle_error(self, request, client_address):
        """A client that hangs up early (it refused a body) is no error of the server's."""
        if not isinstance(sys.exc_info()[1], ConnectionError):
            super().handle_error(request, client_address)


class _Handler(http.server.BaseHTTPRequestHandler):
    server: _Server
    protocol_version = "HTTP/1.1"

    def log_message(self, format, *args):  # quiet
        pass

    def do_GET(self):
        name = urllib.parse.unquote(urllib.parse.urlsplit(self.path).path).lstrip("/")
        with self.server.lock:
            self.server.counts[name] += 1
            queue = self.server.faults[name]
            action = queue.popleft() if queue else None
        path = self.server.folder / name
        if action == "drop":
            self.close_connection = True
        elif action is not None and action.isdigit():
            self.send_error(int(action))
        elif "/" in name or not path.is_file():
            self.send_error(404)
        else:
            self._send(path.read_bytes(), action)

    def _send(self, data: bytes, action: str | None) -> None:
        self.send_response(200)
        self.send_header("Content-Type", "application/octet-stream")
        if action in ("short", "long"):  # the body ends where the connection does
            self.send_header("Connection", "close")
        else:
            self.send_header("Content-Length", str(len(data)))
        self.end_headers()
        body = {"truncate": data[: len(data) // 2], "short": data[: len(data) // 2], "long": data + bytes(10)}
        self.wfile.write(body.get(action, data))
        self.close_connection = action in body


class AdtServer:
    """The running server: its base URL, fault queues and request counts."""

    def __init__(self, folder: pathlib.Path):
        self._server = _Server(pathlib.Path(folder))
        self.base_url = f"http://127.0.0.1:{self._server.server_address[1]}"
        self._thread = threading.Thread(target=self._server.serve_forever, args=(0.05,), daemon=True)
        self._thread.start()
        self._stopped = False

    def fail(self, filename: str, *actions: str) -> None:
        """Queue ``actions`` for the next requests of ``filename``, one each."""
        with self._server.lock:
            self._server.faults[filename].extend(actions)

    def requests(self, filename: str) -> int:
        with self._server.lock:
            return self._server.counts[filename]

    def reset(self) -> None:
        """Forget the counts and the faults not used yet."""
        with self._server.lock:
            self._server.counts.clear()
            self._server.faults.clear()

    def stop(self) -> None:
        """Take the server away: its port no longer accepts connections."""
        if not self._stopped:
            self._stopped = True
            self._server.shutdown()
            self._server.server_close()
            self._thread.join(5)


@contextlib.contextmanager
def serve(folder: pathlib.Path) -> Iterator[AdtServer]:
    """An ``AdtServer`` for the files of ``folder`` during the ``with`` block."""
    server = AdtServer(folder)
    try:
        yield server
    finally:
        server.stop()
