"""A local HTTP file server with faults on demand, for the tests of everything that goes over HTTP and
for the benchmarks that read over it (``benchmarks/compare_server.py``).

``serve(folder)`` runs a server on 127.0.0.1 (any free port) in a daemon thread for the ``with``
block, serving the files under ``folder`` at ``<base_url>/<relative path>`` (a query string is
ignored: tests put tokens there). It answers Range requests (``bytes=a-b``, ``a-``, ``-n``) with 206,
unless ``ranges=False`` (then it answers every request with the whole file, 200).

``server.fail(path, *actions)`` queues faults for one file, each used by one request: an HTTP status
(``"500"``, ``"429"``, ``"404"``), ``"truncate"`` (the full Content-Length, half the body, then the
connection is closed), ``"short"`` / ``"long"`` (no Content-Length; half the body, or the body and 10
more bytes, then the connection is closed), ``"drop"`` (the connection closed without an answer),
``"trickle"`` (1 KiB of the body every ``trickle_s`` seconds), ``"redirect:<url>"`` (a 302 to that
URL), ``"html"`` (200 with an HTML error page), or the protocol faults of a ranged answer:
``"range_off"`` (a Content-Range one byte past the range asked, and that body), ``"length_off"``
(the range asked, a Content-Length one byte short of it), ``"endless"`` (the range's Content-Range,
no Content-Length, and a body that never ends). ``latency_s`` delays every answer.
``server.stop()`` takes the server away (connections are then refused);
``server.requests(path)`` counts the requests for a file, ``server.sent(path)`` the body bytes sent
for it, ``server.most_at_once()`` the most requests it answered at one time, ``server.reset()``
forgets counts and unused faults. A ``"ok"`` in a fault queue answers one request normally.
"""

from __future__ import annotations

import collections
import contextlib
import http.server
import pathlib
import re
import sys
import threading
import time
import urllib.parse
from collections.abc import Iterator

_RANGE = re.compile(r"bytes=(\d*)-(\d*)")


class _Server(http.server.ThreadingHTTPServer):
    daemon_threads = True

    def __init__(self, folder: pathlib.Path, ranges: bool, trickle_s: float, latency_s: float):
        super().__init__(("127.0.0.1", 0), _Handler)
        self.folder = folder.resolve()
        self.ranges = ranges
        self.trickle_s = trickle_s
        self.latency_s = latency_s
        self.lock = threading.Lock()
        self.faults: dict[str, collections.deque[str]] = collections.defaultdict(collections.deque)
        self.counts: collections.Counter[str] = collections.Counter()
        self.bytes_sent: collections.Counter[str] = collections.Counter()
        self.in_flight = 0
        self.most_in_flight = 0

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
        with self.server.lock:
            self.server.in_flight += 1
            self.server.most_in_flight = max(self.server.most_in_flight, self.server.in_flight)
        try:
            self._answer()
        finally:
            with self.server.lock:
                self.server.in_flight -= 1

    def _answer(self):
        name = urllib.parse.unquote(urllib.parse.urlsplit(self.path).path).lstrip("/")
        with self.server.lock:
            self.server.counts[name] += 1
            queue = self.server.faults[name]
            action = queue.popleft() if queue else None
        path = (self.server.folder / name).resolve()
        time.sleep(self.server.latency_s)
        if action == "drop":
            self.close_connection = True
        elif action is not None and action.isdigit():
            self.send_error(int(action))
        elif action is not None and action.startswith("redirect:"):
            self.send_response(302)
            self.send_header("Location", action.split(":", 1)[1])
            self.send_header("Content-Length", "0")
            self.end_headers()
        elif action == "html":
            self._html()
        elif self.server.folder not in path.parents or not path.is_file():
            self.send_error(404)
        else:
            self._send(name, path.read_bytes(), action)

    def _send(self, name: str, data: bytes, action: str | None) -> None:
        first, last = 0, len(data) - 1
        wanted = _RANGE.fullmatch(self.headers.get("Range", "").strip()) if self.server.ranges else None
        if wanted and (wanted[1] or wanted[2]):
            if wanted[1]:
                first, last = int(wanted[1]), min(int(wanted[2] or last), last)
            else:
                first = max(0, len(data) - int(wanted[2]))
            if first > last:
                self.send_error(416)
                return
            if action == "range_off":
                first, last = first + 1, min(last + 1, len(data) - 1)
            self.send_response(206)
            self.send_header("Content-Range", f"bytes {first}-{last}/{len(data)}")
        else:
            self.send_response(200)
        if self.server.ranges:
            self.send_header("Accept-Ranges", "bytes")
        body = data[first : last + 1]
        self.send_header("Content-Type", "application/octet-stream")
        if action in ("short", "long", "endless"):  # the body ends where the connection does
            self.send_header("Connection", "close")
        else:
            self.send_header("Content-Length", str(len(body) - (action == "length_off")))
        self.end_headers()
        if action == "endless":
            self._endless(name, body)
            return
        cut = {"truncate": body[: len(body) // 2], "short": body[: len(body) // 2], "long": body + bytes(10)}
        body = cut.get(action, body)
        if action == "trickle":
            self._trickle(name, body)
            return
        self.wfile.write(body)
        with self.server.lock:
            self.server.bytes_sent[name] += len(body)
        self.close_connection = action in cut

    def _html(self) -> None:
        page = b"<!DOCTYPE html><html><body><h1>Service unavailable</h1></body></html>"
        self.send_response(200)
        self.send_header("Content-Type", "text/html")
        self.send_header("Content-Length", str(len(page)))
        self.end_headers()
        self.wfile.write(page)

    def _endless(self, name: str, body: bytes) -> None:
        """``body``, then zeros until the client hangs up (counted in ``sent``)."""
        self.close_connection = True
        with contextlib.suppress(ConnectionError):
            self.wfile.write(body)
            while True:
                self.wfile.write(bytes(64 << 10))
                with self.server.lock:
                    self.server.bytes_sent[name] += 64 << 10

    def _trickle(self, name: str, body: bytes) -> None:
        for start in range(0, len(body), 1024):
            self.wfile.write(body[start : start + 1024])
            self.wfile.flush()
            with self.server.lock:
                self.server.bytes_sent[name] += len(body[start : start + 1024])
            time.sleep(self.server.trickle_s)


class FileServer:
    """The running server: its base URL, fault queues, request and byte counts."""

    def __init__(
        self, folder: pathlib.Path, ranges: bool = True, trickle_s: float = 1.0, latency_s: float = 0.0
    ):
        self._server = _Server(pathlib.Path(folder), ranges, trickle_s, latency_s)
        self.folder = self._server.folder
        self.base_url = f"http://127.0.0.1:{self._server.server_address[1]}"
        self._thread = threading.Thread(target=self._server.serve_forever, args=(0.05,), daemon=True)
        self._thread.start()
        self._stopped = False

    def fail(self, path: str, *actions: str) -> None:
        """Queue ``actions`` for the next requests of ``path`` (relative to the folder), one each."""
        with self._server.lock:
            self._server.faults[path].extend(actions)

    def requests(self, path: str) -> int:
        with self._server.lock:
            return self._server.counts[path]

    def most_at_once(self) -> int:
        """The most requests the server was answering at one time since the start (or ``reset``)."""
        with self._server.lock:
            return self._server.most_in_flight

    def sent(self, path: str) -> int:
        """Body bytes sent for ``path`` so far."""
        with self._server.lock:
            return self._server.bytes_sent[path]

    def reset(self) -> None:
        """Forget the counts and the faults not used yet."""
        with self._server.lock:
            self._server.counts.clear()
            self._server.bytes_sent.clear()
            self._server.faults.clear()
            self._server.most_in_flight = 0

    def stop(self) -> None:
        """Take the server away: its port no longer accepts connections."""
        if not self._stopped:
            self._stopped = True
            self._server.shutdown()
            self._server.server_close()
            self._thread.join(5)


@contextlib.contextmanager
def serve(
    folder: pathlib.Path, ranges: bool = True, trickle_s: float = 1.0, latency_s: float = 0.0
) -> Iterator[FileServer]:
    """A ``FileServer`` for the files of ``folder`` during the ``with`` block."""
    server = FileServer(folder, ranges, trickle_s, latency_s)
    try:
        yield server
    finally:
        server.stop()
