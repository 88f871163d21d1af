"""The project's one HTTP client: ranged reads of remote files (``open_remote``), bounded whole reads,
and streamed downloads (``HttpClient.download``), all under one policy (``HttpConfig``).

- **Retries.** A request that fails with 429, 500, 502, 503 or 504, a lost connection or a read
  timeout is retried ``retries`` times: no wait before the first retry, ``backoff_s`` x 2^(n-1) s
  before the n-th. A body cut short is resumed from where it stopped (a Range request) when the
  server takes ranges, else fetched again.
- **A refusing host is left alone.** A refused connection fails its request at once, and every
  request to that host in the next ``REFUSED_PAUSE_S`` seconds fails at once too, without knocking.
- **One deadline per file, and a stall rule.** Every request and wait for one file shares its
  ``FileClock``: the file fails once ``deadline_s`` has passed, or when fewer than
  ``stall_bytes_per_s`` x ``stall_s`` bytes arrived in the last ``stall_s`` seconds.
- **No URL's query string is ever shown.** Errors (``HttpError``) hold the cause without the URL, and
  ``shown(url)`` (scheme, host, path) is what messages and records may name: a query string can
  carry an access token.

Built on requests (and its urllib3), the client the project already used, rather than fsspec's HTTP
filesystem: that one needs aiohttp and an event loop thread in every process, retries nothing, fails
a ranged read when a server ignores Range, and puts the whole URL (token included) in its exceptions;
the part of it used here, a seekable file over Range requests, is ``RemoteFile`` below (an
``io.RawIOBase`` that keeps what it fetched, and fetches a zip member's span in one request).
"""

from __future__ import annotations

import collections
import dataclasses
import hashlib
import io
import re
import threading
import time
import urllib.parse
from collections.abc import Callable
from typing import BinaryIO

import requests
import urllib3

from pipeline.core.progress import note
from pipeline.settings.run_config import HttpConfig

RETRY_STATUSES = frozenset({429, 500, 502, 503, 504})
NOT_FOUND = frozenset({404, 410})
CONNECT_TIMEOUT_S = 10.0
REFUSED_PAUSE_S = 60.0
CHUNK_BYTES = 1 << 20
# A ranged file's first request asks for its last TAIL_BYTES (a zip's directory is at its end).
TAIL_BYTES = 4 << 10
_CONTENT_RANGE = re.compile(r"bytes (\d+)-(\d+)/(\d+|\*)")
_URL = re.compile(r"\b[A-Za-z][A-Za-z0-9+.-]*://[^\s'\"<>]+")


def is_http(path: str) -> bool:
    return path.startswith(("http://", "https://"))


def shown(url: str) -> str:
    """``url`` as messages and records may show it: no user name or password, query string or
    fragment."""
    try:
        parts = urllib.parse.urlsplit(url)
    except ValueError:
        return "<a malformed URL>"
    host = parts.netloc.rpartition("@")[2]
    return urllib.parse.urlunsplit((parts.scheme, host, parts.path, "", ""))


def join(base: str, relative: str) -> str:
    """``base`` (a URL whose query string, such as a token, is kept) with ``relative`` appended to its
    path: ``join("https://h/b?t=1", "adt/c.npz") == "https://h/b/adt/c.npz?t=1"``."""
    parts = urllib.parse.urlsplit(base)
    path = f"{parts.path.rstrip('/')}/{relative.lstrip('/')}"
    return urllib.parse.urlunsplit((parts.scheme, parts.netloc, path, parts.query, parts.fragment))


def scrub(text: str) -> str:
    """``text`` with every URL in it ``shown``: for messages of other libraries' exceptions."""
    return _URL.sub(lambda match: shown(match[0]), text)


def one_line(text: object) -> str:
    return " ".join(scrub(str(text)).split())


class HttpError(Exception):
    """A transfer that failed for good. ``str()`` is the cause in one line, without the URL; ``url``
    is the URL as it may be shown; ``kind`` one of not_found, refused, unreachable, status,
    timed_out, broken, truncated, size, too_large, stalled, deadline, unsupported, protocol (the
    server answered something other than what was asked: never retried), cancelled; ``status`` the
    last HTTP status, if any."""

    def __init__(self, cause: str, url: str, kind: str, status: int | None = None):
        super().__init__(cause)
        self.url = shown(url)
        self.kind = kind
        self.status = status


class _Retry(Exception):
    """One try failed in a way another try may mend; ``kind`` as HttpError's."""

    def __init__(self, cause: str, kind: str, status: int | None = None):
        super().__init__(cause)
        self.kind = kind
        self.status = status


class FileClock:
    """One file's time: its deadline and its stall rule, over every request and wait made for it.

    ``got(n)`` counts bytes received; ``check()`` raises HttpError (kind deadline or stalled) once
    the file is out of time, or (kind cancelled) once ``cancel`` is set; ``read_timeout()`` bounds one
    socket read so that a silent connection is noticed in time; ``wait(s)`` sleeps between tries
    (Ctrl-C or ``cancel`` ends it)."""

    def __init__(
        self,
        config: HttpConfig,
        url: str,
        clock: Callable[[], float] = time.monotonic,
        cancel: threading.Event | None = None,
    ):
        self.config, self.url, self._clock = config, url, clock
        self.cancel = cancel or threading.Event()
        self.start = clock()
        self.received = 0
        self._samples: collections.deque[tuple[float, int]] = collections.deque([(self.start, 0)])

    def got(self, count: int) -> None:
        self.received += count
        now = self._clock()
        self._samples.append((now, self.received))
        while len(self._samples) > 2 and self._samples[1][0] <= now - self.config.stall_s:
            self._samples.popleft()
        self.check(now)

    def check(self, now: float | None = None) -> None:
        if self.cancel.is_set():
            raise HttpError("cancelled", self.url, "cancelled")
        now = self._clock() if now is None else now
        config = self.config
        if now - self.start > config.deadline_s:
            raise self._deadline()
        if config.stall_bytes_per_s and now - self.start >= config.stall_s:
            since = now - config.stall_s
            before = max((count for at, count in self._samples if at <= since), default=0)
            recent = self.received - before
            if recent < config.stall_bytes_per_s * config.stall_s:
                raise HttpError(
                    f"stalled: {recent:,} bytes in the last {config.stall_s:g} s, below "
                    f"{config.stall_bytes_per_s:,} bytes/s",
                    self.url,
                    "stalled",
                )

    def read_timeout(self) -> float:
        """A socket read's timeout: until the stall rule or the deadline could next fail the file."""
        left = self.config.deadline_s - (self._clock() - self.start)
        return max(0.05, min(self.config.stall_s, left))

    def wait(self, seconds: float) -> None:
        """Sleep ``seconds`` before another try; HttpError (deadline) instead of waiting past it."""
        if self._clock() + seconds - self.start > self.config.deadline_s:
            raise self._deadline()
        self.cancel.wait(seconds)
        self.check()

    def _deadline(self) -> HttpError:
        return HttpError(
            f"deadline: not done after {self.config.deadline_s:g} s ({self.received:,} bytes received)",
            self.url,
            "deadline",
        )


# host -> when it refused a connection (time.monotonic()), per process.
_refused: dict[str, float] = {}
_refused_lock = threading.Lock()


def _host(url: str) -> str:
    try:
        return urllib.parse.urlsplit(url).netloc.rpartition("@")[2].lower()
    except ValueError:
        return ""


class HttpClient:
    """A requests session under ``HttpConfig``; ``fetched`` counts the body bytes received, ``note``
    receives the one-line notes a transfer makes (a server that ignores Range), and once ``cancel``
    is set every transfer ends at its next read or wait (HttpError, kind cancelled)."""

    def __init__(
        self,
        config: HttpConfig | None = None,
        note: Callable[[str], None] | None = None,
        cancel: threading.Event | None = None,
    ):
        self.config = config or HttpConfig()
        self.cancel = cancel or threading.Event()
        self.session = requests.Session()
        self.fetched = 0
        self.note = note or (lambda text: None)
        self._noted: set[str] = set()

    def close(self) -> None:
        self.session.close()

    def __enter__(self) -> HttpClient:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def clock(self, url: str) -> FileClock:
        return FileClock(self.config, url, cancel=self.cancel)

    def get(self, url: str, clock: FileClock, headers: dict[str, str] | None = None) -> requests.Response:
        """An open, streaming answer (200 or 206) to a GET of ``url``, tried as ``HttpConfig`` says;
        HttpError when every try failed or the answer is final (404, 403, ...)."""
        tries = 0
        while True:
            tries += 1
            try:
                return self._answer(url, clock, headers or {})
            except _Retry as failure:
                problem = failure
            self.retry_or_fail(url, clock, tries, problem)

    def retry_or_fail(self, url: str, clock: FileClock, tries: int, failure: _Retry) -> None:
        """After the ``tries``-th try failed with ``failure``: wait for the next, or raise HttpError.
        Callers call it outside their ``except`` block, so that a Ctrl-C in the wait is a plain one,
        not an error raised while handling another."""
        if tries > self.config.retries:
            after = f" after {tries} tries" if tries > 1 else ""
            raise HttpError(f"{failure}{after}", url, failure.kind, failure.status) from None
        clock.wait(self.config.wait_before(tries))

    def _answer(self, url: str, clock: FileClock, headers: dict[str, str]) -> requests.Response:
        host = _host(url)
        with _refused_lock:
            since = _refused.get(host)
        if since is not None and time.monotonic() - since < REFUSED_PAUSE_S:
            raise HttpError(
                f"connection refused (the host refused {time.monotonic() - since:.0f} s ago; "
                f"not asked again within {REFUSED_PAUSE_S:g} s)",
                url,
                "refused",
            )
        clock.check()
        try:
            response = self.session.get(
                url,
                headers={"Accept-Encoding": "identity", **headers},
                stream=True,
                timeout=(min(CONNECT_TIMEOUT_S, clock.read_timeout()), clock.read_timeout()),
            )
        except (requests.exceptions.InvalidSchema, requests.exceptions.MissingSchema) as error:
            scheme = _scheme_named(str(error))
            raise HttpError(f"unsupported URL scheme{scheme}", url, "unsupported") from None
        except (requests.exceptions.InvalidURL, requests.exceptions.InvalidHeader, ValueError) as error:
            raise HttpError(f"not a usable URL ({_first_words(error)})", url, "unsupported") from None
        except requests.exceptions.TooManyRedirects:
            raise HttpError("too many redirects", url, "unsupported") from None
        except requests.RequestException as error:
            kind, cause = _failure(error)
            if kind == "refused":
                with _refused_lock:
                    _refused[host] = time.monotonic()
                raise HttpError(cause, url, kind) from None
            raise _Retry(cause, kind) from None
        status = response.status_code
        if status in (200, 206):
            return response
        response.close()
        if status in RETRY_STATUSES:
            raise _Retry(f"HTTP {status}", "status", status)
        if status == 416:
            raise HttpError(
                f"HTTP 416 (range not satisfiable) to a request of {_asked(headers)}", url, "protocol", 416
            )
        kind = "not_found" if status in NOT_FOUND else "status"
        raise HttpError(f"HTTP {status}", url, kind, status)

    def body(
        self,
        response: requests.Response,
        clock: FileClock,
        sink: Callable[[bytes], None],
        expected: ExpectedBody | None = None,
    ) -> int:
        """Stream the body of ``response`` into ``sink``; the bytes it held. With ``expected``, at most
        its length is read: a body that goes on past it is HttpError (kind protocol), read no further.
        _Retry (broken) when the connection is lost or a read times out before the body ends."""
        got = 0
        left = None if expected is None else expected.length
        try:
            while left is None or left > 0:
                # At most one socket read (bounded by the read timeout) per chunk: the file's clock sees
                # every arrival, so a trickle is caught by the stall rule in time.
                chunk = self._read(response, CHUNK_BYTES if left is None else min(CHUNK_BYTES, left))
                if not chunk:
                    break
                got += len(chunk)
                self.fetched += len(chunk)
                clock.got(len(chunk))
                sink(chunk)
                if left is not None:
                    left -= len(chunk)
            if expected is not None and left == 0 and not expected.declared and self._read(response, 1):
                raise HttpError(
                    f"the body runs past the {expected.length:,} bytes of {expected.asked} (no "
                    "Content-Length); stopped reading there",
                    response.url,
                    "protocol",
                    response.status_code,
                )
        finally:
            response.close()
        return got

    @staticmethod
    def _read(response: requests.Response, count: int) -> bytes:
        try:
            return response.raw.read1(count, decode_content=True)
        except (requests.RequestException, urllib3.exceptions.HTTPError, ConnectionError) as error:
            raise _Retry(_failure(error)[1], "broken") from None

    def read_range(self, url: str, clock: FileClock, start: int, stop: int, size: int | None = None) -> bytes:
        """Bytes [start, stop) of the file at ``url`` (``size`` bytes, when known) by Range requests: a
        body cut short is asked for again from where it stopped; an answer that is not the range asked
        for (``check_partial``) fails at once."""
        parts: list[bytes] = []
        tries = 0
        while True:
            tries += 1
            first = start + sum(len(part) for part in parts)
            try:
                response = self._answer(url, clock, {"Range": f"bytes={first}-{stop - 1}"})
                expected = check_partial(response, url, first, stop - 1, size)
                try:
                    self.body(response, clock, parts.append, expected)
                except _Retry as lost:
                    raise _Retry(short(parts, start, stop, f" ({lost})"), "truncated") from None
                if start + sum(len(part) for part in parts) == stop:
                    return b"".join(parts)
                raise _Retry(short(parts, start, stop), "truncated")
            except _Retry as failure:
                problem = failure
            self.retry_or_fail(url, clock, tries, problem)

    def download(self, url: str, out: BinaryIO, size: int) -> str:
        """Stream the file at ``url`` (``size`` bytes) into the empty file ``out``; its SHA-1 (hex),
        taken as the body streams. A body cut short is resumed by a Range request from where it
        stopped, or fetched again when the server answers with the whole file. HttpError when a
        Content-Length or the body disagrees with ``size``, or as ``get`` says."""
        clock = self.clock(url)
        digest, tries = hashlib.sha1(), 0
        while True:
            tries += 1
            got = out.tell()  # what earlier tries wrote
            try:
                response = self._answer(url, clock, {"Range": f"bytes={got}-"} if got else {})
                if got and response.status_code == 206:
                    check_partial(response, url, got, size - 1, size)
                elif got:  # the whole file again: start over
                    out.seek(0)
                    out.truncate()
                    digest, got = hashlib.sha1(), 0
                elif response.status_code == 206:
                    response.close()
                    raise HttpError("asked for the whole file, got HTTP 206", url, "protocol", 206)
                declared = response.headers.get("Content-Length")
                if declared is not None and declared.strip() != str(size - got):
                    response.close()
                    raise HttpError(
                        f"size mismatch: Content-Length {declared.strip()}, {size - got} bytes expected",
                        url,
                        "size",
                    )
                self._download_body(url, response, clock, out, digest, got, size)
                return digest.hexdigest()
            except _Retry as failure:
                problem = failure
            self.retry_or_fail(url, clock, tries, problem)

    def _download_body(self, url, response, clock, out: BinaryIO, digest, got: int, size: int) -> None:
        """``download``'s body from byte ``got`` on, to byte ``size`` (else _Retry)."""
        held = [got]

        def keep(chunk: bytes) -> None:
            held[0] += len(chunk)
            if held[0] > size:
                raise HttpError(f"too long: more than the {size} bytes expected", url, "size")
            digest.update(chunk)
            out.write(chunk)

        try:
            self.body(response, clock, keep)
        except _Retry as lost:
            raise _Retry(f"truncated: got {held[0]} of {size} bytes ({lost})", "truncated") from None
        if held[0] < size:
            raise _Retry(f"truncated: got {held[0]} of {size} bytes", "truncated")

    def note_once(self, key: str, text: str) -> None:
        if key not in self._noted:
            self._noted.add(key)
            self.note(text)


_shared: dict[tuple[HttpConfig, int], HttpClient] = {}


def shared_client(config: HttpConfig | None = None) -> HttpClient:
    """This process's (and thread's) client under ``config``, made on first use: a worker's clips
    share its connections; its notes go to the unit being annotated (``pipeline.core.progress.note``)."""
    key = (config or HttpConfig(), threading.get_ident())
    if key not in _shared:
        _shared[key] = HttpClient(key[0], note)
    return _shared[key]


def short(parts: list[bytes], start: int, stop: int, cause: str = "") -> str:
    """The cause of a body that ended before bytes [start, stop) were all in ``parts``."""
    got = sum(len(part) for part in parts)
    return f"truncated: {got:,} of the {stop - start:,} bytes of bytes {start}-{stop - 1} received{cause}"


@dataclasses.dataclass(frozen=True)
class ExpectedBody:
    """What a 206 answer's body must hold: ``length`` bytes, of the range ``asked`` (as messages name
    it), of a file of ``total`` bytes (None when the answer gave no size); ``declared``: the answer
    gave that length in its Content-Length."""

    length: int
    asked: str
    declared: bool
    total: int | None


def _asked(headers: dict[str, str]) -> str:
    """A request's Range header as messages name it: ``bytes 10-19``, ``the last 4096 bytes``."""
    wanted = headers.get("Range", "").removeprefix("bytes=")
    if not wanted:
        return "the whole file"
    if wanted.startswith("-"):
        return f"the last {wanted[1:]} bytes"
    return f"bytes {wanted}"


def check_partial(
    response: requests.Response, url: str, first: int | None, last: int, size: int | None
) -> ExpectedBody:
    """The body a 206 answer to a request of bytes ``first``-``last`` must hold (``first`` None: the
    last ``last`` bytes, a suffix request), checked against the answer's headers. HttpError (kind
    protocol), naming what was asked and what came back, when the status is not 206, the
    Content-Range is missing or not the range asked (or names a size other than ``size``, when
    known), or the Content-Length disagrees with it; the response is then closed."""
    asked = f"the last {last} bytes" if first is None else f"bytes {first}-{last}"
    header = response.headers.get("Content-Range", "").strip()
    match = _CONTENT_RANGE.fullmatch(header)
    declared = response.headers.get("Content-Length")
    if response.status_code != 206:
        problem = f"HTTP {response.status_code}"
    elif match is None:
        problem = f"HTTP 206 with Content-Range {header!r}" if header else "HTTP 206 without a Content-Range"
    else:
        got_first, got_last = int(match[1]), int(match[2])
        total = None if match[3] == "*" else int(match[3])
        length = got_last - got_first + 1
        if first is None:
            right = total is not None and got_last == total - 1 and length == min(last, total)
        else:
            right = (got_first, got_last) == (first, last) and (size is None or total in (None, size))
        if not right:
            problem = f"Content-Range {header!r}"
        elif declared is not None and declared.strip() != str(length):
            problem = f"Content-Range {header!r} with Content-Length {declared.strip()}"
        else:
            return ExpectedBody(length, f"bytes {got_first}-{got_last}", declared is not None, total)
    response.close()
    raise HttpError(f"asked for {asked}, got {problem}", url, "protocol", response.status_code)


def _scheme_named(text: str) -> str:
    match = re.search(r"'([A-Za-z][A-Za-z0-9+.-]*)://", text)
    return f" {match[1]}://" if match else ""


def _first_words(error: BaseException) -> str:
    """An exception's text without anything URL-like, shortened."""
    text = re.sub(r"\S*://\S*", "", scrub(str(error)))
    return " ".join(text.split())[:80] or type(error).__name__


# Short causes of a failed request, the first whose exception is in its chain (most specific first).
_CAUSES = (
    (ConnectionRefusedError, "refused", "connection refused"),
    (urllib3.exceptions.NameResolutionError, "unreachable", "host not found"),
    ((urllib3.exceptions.ConnectTimeoutError, requests.ConnectTimeout), "timed_out", "connection timed out"),
    (
        (urllib3.exceptions.ReadTimeoutError, requests.ReadTimeout, TimeoutError),
        "timed_out",
        "read timed out",
    ),
    (urllib3.exceptions.NewConnectionError, "unreachable", "cannot connect"),
    (
        (urllib3.exceptions.ProtocolError, requests.exceptions.ChunkedEncodingError, ConnectionError),
        "broken",
        "connection broken",
    ),
)


def _failure(error: BaseException) -> tuple[str, str]:
    """(kind, short cause) of a failed request or read."""
    chain = _chain(error)
    for kinds, kind, text in _CAUSES:
        if any(isinstance(seen, kinds) for seen in chain):
            return kind, text
    return "broken", one_line(error) or type(error).__name__


def _chain(error: BaseException) -> list[BaseException]:
    """The exceptions wrapped by ``error``: its arguments, cause, context, ``reason`` (bounded)."""
    found: list[BaseException] = []
    queue = [error]
    while queue and len(found) < 32:
        seen = queue.pop(0)
        if any(seen is other for other in found):
            continue
        found.append(seen)
        inner = [*getattr(seen, "args", ()), seen.__cause__, seen.__context__, getattr(seen, "reason", None)]
        queue.extend(e for e in inner if isinstance(e, BaseException))
    return found


class RemoteFile(io.RawIOBase):
    """A file at an HTTP URL read by Range requests: seekable, its ``size`` known. Every byte fetched
    is kept (``segments``: start -> bytes, never overlapping), so a byte is fetched once however the
    reader seeks; ``prefetch(start, stop)`` fetches a span in one request (a zip member: its local
    header and data), and a read of bytes not kept fetches exactly those. ``fetched`` counts the
    bytes received for it."""

    def __init__(self, client: HttpClient, url: str, clock: FileClock, size: int, tail: bytes):
        self.client, self.url, self.clock, self.size = client, url, clock, size
        self.segments: dict[int, bytes] = {size - len(tail): tail} if tail else {}
        self.position = 0
        self.fetched = len(tail)

    def readable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return True

    def tell(self) -> int:
        return self.position

    def seek(self, offset: int, whence: int = io.SEEK_SET) -> int:
        base = {io.SEEK_SET: 0, io.SEEK_CUR: self.position, io.SEEK_END: self.size}[whence]
        if base + offset < 0:
            raise OSError(f"seek to {base + offset}, before the start")
        self.position = base + offset
        return self.position

    def prefetch(self, start: int, stop: int) -> None:
        """Fetch the bytes of [start, stop) not kept yet, one request per gap."""
        start, stop = max(0, start), min(stop, self.size)
        for gap_start, gap_stop in self._gaps(start, stop):
            data = self.client.read_range(self.url, self.clock, gap_start, gap_stop, self.size)
            self.fetched += len(data)
            self.segments[gap_start] = data

    def _gaps(self, start: int, stop: int) -> list[tuple[int, int]]:
        gaps, at = [], start
        for first in sorted(self.segments):
            last = first + len(self.segments[first])
            if last <= at or first >= stop:
                continue
            if first > at:
                gaps.append((at, first))
            at = max(at, last)
        if at < stop:
            gaps.append((at, stop))
        return gaps

    def readinto(self, buffer) -> int:
        count = max(0, min(len(buffer), self.size - self.position))
        if not count:
            return 0
        start, stop = self.position, self.position + count
        self.prefetch(start, stop)
        view = memoryview(buffer)
        for first in sorted(self.segments):
            data = self.segments[first]
            low, high = max(start, first), min(stop, first + len(data))
            if low < high:
                view[low - start : high - start] = data[low - first : high - first]
        self.position = stop
        return count


def open_remote(client: HttpClient, url: str, max_bytes: int) -> RemoteFile | io.BytesIO:
    """A seekable binary file of the HTTP(S) URL, read by Range requests (its first request fetches the
    last ``TAIL_BYTES``, where a zip keeps its directory). A server that ignores Range gets one note
    and the whole file is read, when it is at most ``max_bytes``. HttpError (kind not_found for 404
    and 410, too_large, protocol for an answer that is not the range asked) when it cannot be
    opened. The file's ``fetched`` counts its bytes received."""
    clock = client.clock(url)
    tries = 0
    while True:
        tries += 1
        try:
            response = client.get(url, clock, {"Range": f"bytes=-{TAIL_BYTES}"})
            if response.status_code == 200:
                return _whole(client, url, clock, response, max_bytes)
            expected = check_partial(response, url, None, TAIL_BYTES, None)
            total = expected.total
            assert total is not None  # check_partial refuses a suffix's answer without its size
            first = total - expected.length
            tail: list[bytes] = []
            try:
                client.body(response, clock, tail.append, expected)
            except _Retry as lost:
                raise _Retry(short(tail, first, total, f" ({lost})"), "truncated") from None
            data = b"".join(tail)
            if len(data) != expected.length:
                raise _Retry(short(tail, first, total), "truncated")
            return RemoteFile(client, url, clock, total, data)
        except _Retry as failure:
            problem = failure
        client.retry_or_fail(url, clock, tries, problem)


def _whole(
    client: HttpClient, url: str, clock: FileClock, response: requests.Response, max_bytes: int
) -> io.BytesIO:
    """The whole body of a 200 answer to a Range request, read within ``max_bytes``."""
    client.note_once(_host(url), ignores_range_note(url, max_bytes))
    declared = response.headers.get("Content-Length", "")
    if declared.strip().isdigit() and int(declared) > max_bytes:
        response.close()
        raise HttpError(f"{int(declared):,} bytes, more than the {max_bytes:,} read", url, "too_large")
    parts: list[bytes] = []
    received = [0]

    def keep(chunk: bytes) -> None:
        received[0] += len(chunk)
        if received[0] > max_bytes:
            raise HttpError(f"more than the {max_bytes:,} bytes read", url, "too_large")
        parts.append(chunk)

    client.body(response, clock, keep)
    if declared.strip().isdigit() and received[0] != int(declared):
        raise _Retry(f"truncated: {received[0]:,} of the {int(declared):,} bytes received", "truncated")
    whole = io.BytesIO(b"".join(parts))
    whole.fetched = received[0]  # type: ignore[attr-defined]
    return whole


def ignores_range_note(url: str, max_bytes: int) -> str:
    """The one note a host that ignores Range requests gets."""
    parts = urllib.parse.urlsplit(shown(url))
    return (
        f"{parts.scheme}://{parts.netloc}: the server ignores Range requests; reading whole files from it "
        f"(at most {max_bytes:,} bytes each)"
    )
