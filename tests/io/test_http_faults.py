"""The project's HTTP client against a server that answers wrongly (benchmarks/file_server.py, on
127.0.0.1): a protocol error fails at once, naming what was asked and what came back; an endless body
is read no further than the range; a transient fault is retried and says so coherently; a cancelled
transfer ends in its retry wait. Every case reads a small clip's queries as ``--queries-from`` does:
its directory (the last 4 KiB), then the member."""

from __future__ import annotations

import re
import threading
import time

import numpy as np
import pytest

from benchmarks.file_server import serve
from pipeline.export.npz_writer import encode_npz
from pipeline.io.clip_reader import ReadLimits, read_clip_file
from pipeline.io.http import TAIL_BYTES, HttpClient, HttpError
from pipeline.io.npz_reader import NpzError
from pipeline.settings.run_config import HttpConfig

TOKEN = "tok-SECRET-51d0"
NAME = "toy/clip.npz"
# Retries without waits: a fault retried shows in the request count, not in the test's time.
QUICK = HttpConfig(retries=3, backoff_s=0.0)


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    """(server, the clip's bytes): a clip of 200 queries (its queries member past the last 4 KiB)."""
    folder = tmp_path_factory.mktemp("served")
    (folder / "toy").mkdir()
    rng = np.random.default_rng(0)
    members = {
        "queries_xyt": rng.random((200, 3)),
        "tracks_XYZ": rng.random((4, 200, 3)),
        "visibility": np.ones((4, 200), bool),
    }
    data = encode_npz(members)
    assert len(data) > 4 * TAIL_BYTES
    (folder / NAME).write_bytes(data)
    with serve(folder) as server:
        yield server, members


def read_queries(server, config: HttpConfig = QUICK, client: HttpClient | None = None) -> np.ndarray:
    url = f"{server.base_url}/{NAME}?token={TOKEN}"
    return read_clip_file(url, keys=("queries_xyt",), client=client or HttpClient(config))["queries_xyt"]


def refused(server, *faults: str) -> HttpError:
    """The error of reading the clip with ``faults`` queued for its requests (``ok``: no fault)."""
    server.reset()
    server.fail(NAME, *faults)
    with pytest.raises(HttpError) as caught:
        read_queries(server)
    assert TOKEN not in str(caught.value) and TOKEN not in caught.value.url
    return caught.value


@pytest.mark.parametrize(
    ("faults", "message"),
    [
        (("range_off",), "asked for the last 4096 bytes, got Content-Range 'bytes "),
        (("length_off",), "asked for the last 4096 bytes, got Content-Range 'bytes "),
        (("ok", "range_off"), "asked for bytes "),
        (("ok", "length_off"), "with Content-Length "),
        (("416",), "HTTP 416 (range not satisfiable) to a request of the last 4096 bytes"),
    ],
)
def test_an_answer_that_is_not_the_range_asked_fails_at_once(served, faults, message):
    error = refused(served[0], *faults)
    assert error.kind == "protocol"
    assert message in str(error)
    assert served[0].requests(NAME) == len(faults)  # never retried as if transient


def test_an_endless_body_is_read_no_further_than_its_range(served):
    server = served[0]
    server.reset()
    server.fail(NAME, "endless")
    client = HttpClient(QUICK)
    with pytest.raises(HttpError) as caught:
        read_queries(server, client=client)
    assert caught.value.kind == "protocol"
    assert str(caught.value).startswith("the body runs past the 4,096 bytes of bytes ")
    assert client.fetched <= TAIL_BYTES + 1  # the range, and the one byte that proved it goes on
    assert server.requests(NAME) == 1


def test_a_body_cut_short_is_retried_from_where_it_stopped_and_then_says_how_much_came(served):
    server, members = served
    server.reset()
    read_queries(server)
    plain = server.requests(NAME)  # the directory, the member's header, its data
    server.reset()
    server.fail(NAME, "ok", "truncate")
    np.testing.assert_array_equal(read_queries(server), members["queries_xyt"])
    assert server.requests(NAME) == plain + 1  # the request cut short, then its rest
    error = refused(server, "ok", *["truncate"] * 4)
    assert error.kind == "truncated"
    cause = str(error)
    assert cause.startswith("truncated: ") and cause.endswith("after 4 tries")
    # what came and what was asked, consistently: 'N of the M bytes of bytes a-b received'
    got, asked, first, last = (int(x.replace(",", "")) for x in _numbers(cause)[:4])
    assert got < asked == last - first + 1


def _numbers(text: str) -> list[str]:
    return re.findall(r"\d[\d,]*", text)


def test_an_html_error_page_and_a_redirect_elsewhere_are_one_line_each(served):
    server = served[0]
    server.reset()
    server.fail(NAME, "html")
    with pytest.raises(NpzError, match="not an .npz archive"):
        read_queries(server)
    assert refused(server, "redirect:ftp://example.invalid/x").kind == "unsupported"
    loop = f"redirect:{server.base_url}/{NAME}"
    assert str(refused(server, *[loop] * 40)) == "too many redirects"


def test_a_server_that_ignores_range_gets_one_note_and_the_size_bound(served, tmp_path):
    folder = tmp_path / "whole"
    (folder / "toy").mkdir(parents=True)
    data = encode_npz({"queries_xyt": np.zeros((5, 3))})
    (folder / NAME).write_bytes(data)
    notes: list[str] = []
    with serve(folder, ranges=False) as whole:
        client = HttpClient(QUICK, notes.append)
        for _ in range(2):
            read_clip_file(f"{whole.base_url}/{NAME}", keys=("queries_xyt",), client=client)
        url = f"{whole.base_url}/{NAME}?token={TOKEN}"
        with pytest.raises(HttpError) as caught:
            read_clip_file(url, ReadLimits(max_file_bytes=len(data) - 1), ("queries_xyt",), client)
    assert notes == [
        f"{whole.base_url}: the server ignores Range requests; reading whole files from it "
        "(at most 4,294,967,296 bytes each)"
    ]
    assert caught.value.kind == "too_large"


def test_a_cancelled_transfer_ends_in_its_retry_wait(served):
    server = served[0]
    server.reset()
    server.fail(NAME, *["503"] * 10)
    client = HttpClient(HttpConfig(retries=5, backoff_s=30.0))
    threading.Timer(0.5, client.cancel.set).start()
    started = time.monotonic()
    with pytest.raises(HttpError) as caught:
        read_queries(server, client=client)
    assert caught.value.kind == "cancelled"
    assert time.monotonic() - started < 10  # the 60 s wait before the third try was cut short


def test_a_resumed_download_answered_with_another_range_fails_at_once(served, tmp_path):
    """ADT's streamed download: a body cut short is resumed by a Range request; an answer naming
    another range is a protocol error, not a third try."""
    server, _ = served
    server.reset()
    server.fail(NAME, "truncate", "range_off")
    size = len((server.folder / NAME).read_bytes())
    with open(tmp_path / "file", "wb") as out, pytest.raises(HttpError) as caught:
        HttpClient(QUICK).download(f"{server.base_url}/{NAME}", out, size)
    assert caught.value.kind == "protocol"
    assert str(caught.value).startswith(f"asked for bytes {size // 2}-{size - 1}, got Content-Range 'bytes ")
    assert server.requests(NAME) == 2
