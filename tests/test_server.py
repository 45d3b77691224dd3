"""Read timeouts of a live server: a late request head closes the connection, a late body
is a 408 problem, and a prompt client on a kept-alive connection is unaffected."""

from __future__ import annotations

import json
import re
import socket
import time
from collections.abc import Iterator

import pytest
from service_fixtures import ROOT, TWO_LINK, serving

from app.main import create_app
from app.server import PROTOCOL
from app.settings import Settings, get_settings

TIMEOUT = 0.5
DYNAMICS = json.dumps({"robot": TWO_LINK, "states": [{"q": [0.0, 0.0], "dq": [0.0, 0.0]}]})


@pytest.fixture(scope="module")
def port(tmp_path_factory) -> Iterator[int]:
    with pytest.MonkeyPatch.context() as env:
        env.setenv("UNDERTOW_READ_TIMEOUT", str(TIMEOUT))  # the protocol's setting
        get_settings.cache_clear()
        settings = Settings(db_path=str(tmp_path_factory.mktemp("server") / "jobs.sqlite3"),
                            workers=1, instance="test", read_timeout=TIMEOUT)
        with serving(create_app(settings)) as port:
            yield port
    get_settings.cache_clear()


def connect(port: int) -> socket.socket:
    return socket.create_connection(("127.0.0.1", port), timeout=30)


def closed_after(sock: socket.socket) -> float:
    """Seconds until the server closes the connection (reading and discarding)."""
    start = time.monotonic()
    while sock.recv(65536):
        pass
    return time.monotonic() - start


def response(sock: socket.socket) -> tuple[str, bytes]:
    """The status line and body of one response (read by its Content-Length)."""
    data = b""
    while b"\r\n\r\n" not in data:
        data += sock.recv(65536)
    head, _, body = data.partition(b"\r\n\r\n")
    lines = head.decode().split("\r\n")
    length = next(int(line.split(":")[1]) for line in lines
                  if line.lower().startswith("content-length:"))
    while len(body) < length:
        body += sock.recv(65536)
    return lines[0], body


def request(path: str, body: str = "") -> bytes:
    return (f"POST {path} HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n"
            f"Content-Length: {len(body)}\r\n\r\n{body}").encode()


@pytest.mark.parametrize("sent", [b"", b"GET /healthz HTTP/1.1\r\nHost: x\r\n"])
def test_a_request_head_that_does_not_arrive_closes_the_connection(port, sent):
    with connect(port) as sock:
        sock.sendall(sent)
        assert closed_after(sock) < 25  # the socket itself would wait 30 s


def test_a_head_sent_a_line_at_a_time_is_closed_too(port):
    with connect(port) as sock:
        for line in (b"GET /healthz HTTP/1.1\r\n", b"Host: x\r\n", b"X-A: 1\r\n", b"X-B: 2\r\n"):
            try:
                sock.sendall(line)
            except OSError:
                break  # already closed
            time.sleep(TIMEOUT / 2)
        assert closed_after(sock) < 25


def test_a_body_that_does_not_arrive_is_408(port):
    with connect(port) as sock:
        sock.sendall(request("/v1/dynamics", DYNAMICS)[:-10])
        status, body = response(sock)
    assert status.startswith("HTTP/1.1 408 ")
    assert json.loads(body)["detail"] == (
        f"the request body did not arrive within {TIMEOUT:g} s (UNDERTOW_READ_TIMEOUT)")


def test_a_prompt_client_keeps_its_connection(port):
    with connect(port) as sock:
        for _ in range(3):
            sock.sendall(request("/v1/dynamics", DYNAMICS))
            status, _ = response(sock)
            assert status == "HTTP/1.1 200 OK"
            time.sleep(TIMEOUT / 2)


@pytest.mark.parametrize("path", ["Makefile", "Dockerfile", "docs/deploy.md"])
def test_every_way_of_serving_uses_the_protocol(path):
    text = (ROOT / path).read_text()
    assert f"--http {PROTOCOL}" in text or f'"--http", "{PROTOCOL}"' in text


def head(path: str, extra: int) -> bytes:
    """A GET request whose head carries a header field of `extra` bytes."""
    return f"GET {path} HTTP/1.1\r\nHost: x\r\nX-Big: {'a' * extra}\r\n\r\n".encode()


@pytest.mark.parametrize("piece", [None, 1000])
def test_a_head_over_16_kib_is_431_however_it_arrives(port, piece):
    """h11 bounds only an incomplete head: 70 KB sent at once were served."""
    sent = head("/healthz", 20 * 1024)
    with connect(port) as sock:
        for start in range(0, len(sent), piece or len(sent)):
            sock.sendall(sent[start:start + (piece or len(sent))])
        status, body = response(sock)
        assert closed_after(sock) < 25
    assert status == "HTTP/1.1 431 Request Header Fields Too Large"
    problem = json.loads(body)
    assert (problem["type"], problem["status"], problem["instance"]) == (
        "urn:undertow:problem:head-too-large", 431, "/healthz")
    assert problem["detail"] == ("the request head (request line and header fields) exceeds "
                                 "16384 bytes")


def test_a_head_within_16_kib_is_served_and_a_pipelined_one_over_it_is_not(port):
    with connect(port) as sock:
        sock.sendall(head("/healthz", 15 * 1024) + head("/healthz", 20 * 1024))
        received = b""
        while chunk := sock.recv(65536):  # until the server closes the connection
            received += chunk
    statuses = re.findall(rb"HTTP/1.1 \d{3} [^\r]*", received)
    assert statuses == [b"HTTP/1.1 200 OK", b"HTTP/1.1 431 Request Header Fields Too Large"]
